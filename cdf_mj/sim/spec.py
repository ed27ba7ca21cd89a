"""Place our car in your own ``MjSpec``: :func:`add_car`. ::

    import mujoco
    from cdf_mj.sim.spec import add_car

    spec = mujoco.MjSpec.from_file("my_junction.xml")   # roads, routes, sites, buildings
    add_car(spec, "ego_", pos=(-40.0, -1.85), yaw=0.0)
    add_car(spec, "obstacle_", pos=(-1.85, 8.35), yaw=-1.5708)
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST   # your choice: see below
    model = spec.compile()

:func:`add_car` never changes the spec's options (``spec.option``): they are the whole
model's. Our car needs what ``models/xml/scene.xml`` sets: the ``implicitfast`` (or
``implicit``) integrator, because its speed servo and tyre dampers (gains 1e7 against
1500 kg) are stiff for explicit Euler at the 5 ms timestep (models/xml/README.md), and a timestep
that divides the 0.1 s tick (0.005 s in our scenes). Set them yourself if your model does
not have them; the scene checks (:mod:`cdf_mj.sim.checks`) warn about the integrator.
"""

from __future__ import annotations

import math
from pathlib import Path

import mujoco

from cdf_mj.config import SceneNames
from cdf_mj.sim.assets import CAR_XML
from cdf_mj.sim.checks import SceneError, check_regular_files

__all__ = ["add_car"]


#: Named elements a car file can bring into a spec (MjSpec finder, list), for name clashes.
_CAR_ELEMENT_KINDS = (("body", "bodies"), ("geom", "geoms"), ("site", "sites"), ("joint", "joints"),
                      ("actuator", "actuators"), ("sensor", "sensors"), ("tendon", "tendons"),
                      ("camera", "cameras"), ("light", "lights"), ("material", "materials"),
                      ("mesh", "meshes"), ("texture", "textures"))


def add_car(spec: mujoco.MjSpec, prefix: str, pos: tuple[float, float] = (0.0, 0.0),
            yaw: float = 0.0, paint: tuple[float, float, float, float] = (0.8, 0.8, 0.8, 1.0),
            car_file: str | Path = CAR_XML) -> mujoco.MjsBody:
    """Place our car (``models/xml/car.xml``) in your ``MjSpec`` and return its chassis.

    The car is attached to the worldbody at rear-axle position ``pos`` [m] (world x, y;
    z = 0 is the ground) with heading ``yaw`` [rad] from the world x axis, and every name
    in it gets ``prefix`` (``chassis`` becomes ``<prefix>chassis``, and so on; see
    :class:`cdf_mj.config.SceneNames`). A material ``<prefix>paint`` of colour ``paint``
    (RGBA) is added unless the spec has one. The spec's options (integrator, timestep) are
    left as they are: our car needs ``implicitfast`` or ``implicit`` (module docstring).

    SceneError, before anything is added to ``spec``, if the car file cannot be read or has
    no ``chassis`` body, or if any prefixed name of the car is already in the spec;
    ValueError for a pose that is not two finite numbers and a finite yaw.
    """
    if not prefix:
        raise SceneError("add_car: prefix must be a non-empty string (e.g. 'ego_')")
    chassis = SceneNames().chassis
    try:
        x, y = (float(v) for v in pos)
    except (TypeError, ValueError):
        raise ValueError(f"add_car: pos must be (x, y) in metres, got {pos!r}") from None
    if not all(math.isfinite(v) for v in (x, y, float(yaw))):
        raise ValueError(f"add_car: pose must be finite, got pos={pos}, yaw={yaw}")
    check_regular_files(car_file)  # a FIFO would block MuJoCo
    try:
        car = mujoco.MjSpec.from_file(str(car_file))
    except ValueError as exc:
        raise SceneError(f"add_car: cannot read car file {car_file}: "
                         f"{' '.join(str(exc).split())}") from None
    if car.body(chassis) is None:
        raise SceneError(f"add_car: car file {car_file} has no body '{chassis}'")
    clashes = [f"{kind} '{prefix}{element.name}'" for kind, plural in _CAR_ELEMENT_KINDS
               for element in getattr(car, plural)
               if element.name and element.name != "world"
               and getattr(spec, kind)(prefix + element.name) is not None]
    if clashes:
        more = f" and {len(clashes) - 6} more" if len(clashes) > 6 else ""
        raise SceneError(f"add_car: the spec already has {', '.join(clashes[:6])}{more}; "
                         "choose another prefix")
    if spec.material(prefix + "paint") is None:
        spec.add_material(name=prefix + "paint", rgba=list(paint))
    frame = spec.worldbody.add_frame(pos=[x, y, 0.0],
                                     quat=[math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])
    return frame.attach_body(car.body(chassis), prefix, "")
