"""Where the package's MJCF files are: ``models/xml`` in a checkout, installed as the
package data of ``cdf_mj.assets`` (wheels and editable installs alike). ::

    from cdf_mj.sim.assets import DEFAULT_SCENE, MODELS_DIR
"""

from __future__ import annotations

import importlib.resources
from pathlib import Path

__all__ = ["CAR_XML", "DEFAULT_SCENE", "MODELS_DIR", "models_dir"]


def models_dir() -> Path:
    """The directory that holds ``scene.xml``, ``car.xml`` and the other MJCF files.

    The installed package ``cdf_mj.assets`` (a wheel copies ``models/xml`` there); failing
    that, ``models/xml`` of the checkout this module sits in (running from a source tree
    without installing). MuJoCo reads files from disk, so the resource must be a real
    directory (it is for every installed wheel, zipped imports aside).
    """
    try:
        root = importlib.resources.files("cdf_mj.assets")
        path = Path(str(root))
        if (path / "scene.xml").is_file():
            return path
    except (ModuleNotFoundError, TypeError):
        pass
    return Path(__file__).resolve().parents[2] / "models" / "xml"


MODELS_DIR = models_dir()
DEFAULT_SCENE = MODELS_DIR / "scene.xml"
CAR_XML = MODELS_DIR / "car.xml"  # one car, no world: placed by <attach> or add_car
