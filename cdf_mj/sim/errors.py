"""What goes wrong with a scene, and where MuJoCo's own warnings go: :class:`SceneError`
(refused, one line listing every problem), :class:`SceneWarning` (loads, may not simulate
well), and MuJoCo's warnings routed to the logger ``cdf_mj.mujoco`` when this module is
imported (:func:`route_mujoco_warnings`). ::

    from cdf_mj.sim.errors import SceneError
"""

from __future__ import annotations

import logging

import mujoco

__all__ = ["MUJOCO_LOGGER", "SceneError", "SceneWarning", "route_mujoco_warnings"]


class SceneError(ValueError):
    """A scene file that cannot be loaded or lacks an element the code needs, or whose
    elements do not mean what the code reads them as."""


class SceneWarning(UserWarning):
    """A scene that loads but may not simulate well (e.g. an explicit integrator)."""


# ---------------------------------------------------------------------- MuJoCo's warnings
#: MuJoCo's own warnings ("XML contains a 'NaN'", "Nan, Inf or huge value in QACC ...") go to
#: this logger at level WARNING instead of stdout and a MUJOCO_LOG.TXT in the working
#: directory. The package's logger "cdf_mj" has a NullHandler, so they show only where the
#: application configures logging (e.g. ``logging.basicConfig()``).
MUJOCO_LOGGER = logging.getLogger("cdf_mj.mujoco")
logging.getLogger("cdf_mj").addHandler(logging.NullHandler())


def _log_mujoco_warning(message: str) -> None:
    MUJOCO_LOGGER.warning("MuJoCo: %s", " ".join(str(message).split()))


def route_mujoco_warnings() -> None:
    """Send MuJoCo's warnings to the logger ``cdf_mj.mujoco`` (:data:`MUJOCO_LOGGER`) rather
    than MuJoCo's default (print ``WARNING: ...`` to stdout and append to ``MUJOCO_LOG.TXT``
    in the working directory). Done when this module is imported; a handler the application
    set with ``mujoco.set_mju_user_warning`` before is kept."""
    if mujoco.get_mju_user_warning() is None:
        mujoco.set_mju_user_warning(_log_mujoco_warning)


route_mujoco_warnings()
