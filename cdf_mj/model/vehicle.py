"""A car's dimensions and actuator limits in its own chassis frame, in NumPy only.

The chassis frame has its origin on the rear axle, x forward, y to the left, z up from
the ground. Poses are ``[x, y, theta, v]``: rear-axle position [m] and heading [rad] in
the world frame (x east, y north), speed [m/s] along the heading. :mod:`cdf_mj.sim`
reads one :class:`CarGeometry` per car from the MJCF model
(``Scene.ego.geometry``, ``Scene.layout().ego``); the drivers, the filter and the
planners use it without MuJoCo. ::

    from cdf_mj.model.vehicle import CarGeometry

    car = CarGeometry(wheelbase=2.7, hull_offset=(1.35, 0.0), hull_half=(2.3, 0.9),
                      hull_height=1.5, eye_offset=(1.2, 0.4, 1.2),
                      accel_range=(-4.877, 3.0), steer_range=(-0.6, 0.6))
    car.footprint([0.0, 0.0, 0.0, 0.0])     # (4, 2) corners of the collision box [m]
    car.eye(poses)                          # (N, 3) driver's eye for N poses (N, 4) [m]
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, fields

import numpy as np

from cdf_mj.config import MAX_ACCEL
from cdf_mj.model.geometry import box_corners_one, rotated_corners

__all__ = ["CAR_LENGTH", "CAR_SIZE", "CAR_WIDTH", "CarGeometry", "unit_hint"]

#: [m] the collision box's length of anything that drives on a road, from a 1:40 model
#: (MuJoCo's example car, ``model/car/car.xml``, is 0.2 m long) to a road train; a length
#: outside it is a unit mistake (millimetres, centimetres), not a car.
CAR_LENGTH = (0.05, 30.0)
#: [m] the collision box's width (a 1:40 model to an oversize load).
CAR_WIDTH = (0.02, 10.0)
#: [m] the wheelbase, the box's height and every offset in the chassis frame: at most this.
CAR_SIZE = 30.0


def unit_hint(value: float, high: float, low: float = 0.0) -> str:
    """For a length ``value`` [m] beyond ``high``: the smaller units in which it would lie
    in ``[low, high]``, as ``"; millimetres?"`` to end a message (``""`` for a value within
    twice the bound: too close to tell). Every check of a car's lengths words it so."""
    units = [unit for factor, unit in ((1000.0, "millimetres"), (100.0, "centimetres"))
             if value > 2.0 * high and low <= value / factor <= high]
    return f"; {' or '.join(units)}?" if units else ""


def _box_problem(half: np.ndarray) -> str:
    """What makes a collision box of half sizes ``half`` [m] no car's, or ''."""
    for size, (low, high), word in ((2.0 * float(half[0]), CAR_LENGTH, "long"),
                                    (2.0 * float(half[1]), CAR_WIDTH, "wide")):
        if not low <= size <= high:
            hint = unit_hint(size, high, low) if size > high else "; metres expected"
            return f"makes the box {size:g} m {word}: a car is {low:g}-{high:g} m {word}{hint}"
    return ""


def _range_problem(name: str, most: float) -> str:
    """What makes an actuator range reaching ``most`` (accel [m/s^2], steering [rad]) no
    car's, or ''."""
    if name == "accel_range" and most > MAX_ACCEL:
        hint = "; mm/s^2?" if most / 1000.0 <= MAX_ACCEL else ""
        return f"reaches {most:g} m/s^2: a car's is at most {MAX_ACCEL:g} m/s^2 (about 10 g){hint}"
    if name == "steer_range" and most > math.pi / 2:
        hint = (f"; degrees? Steering angles are radians ({most:g} deg = {math.radians(most):.3g} rad)"
                if most <= 90.0 else "")
        return f"reaches {most:g} rad: a car steers at most pi/2 rad (90 deg){hint}"
    return ""


def _vector(value: Sequence[float] | np.ndarray, size: int) -> np.ndarray | None:
    """``value`` as a read-only float array of shape ``(size,)``, or None if it is not one."""
    try:
        out = np.array(value, dtype=float)
    except (TypeError, ValueError):
        return None
    if out.shape != (size,):
        return None
    out.flags.writeable = False
    return out


def _pair(value: Sequence[float]) -> tuple[float, float] | None:
    """``value`` as a pair of floats, or None if it is not one."""
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        return None
    return lo, hi


@dataclass(frozen=True, eq=False)
class CarGeometry:
    """Dimensions of one car in its chassis frame (origin on the rear axle) and the
    ranges of its two actuators.

    Attributes:
        wheelbase: rear axle to front axle [m], > 0.
        hull_offset: ``(2,)`` centre of the collision box in the chassis frame [m].
        hull_half: ``(2,)`` half length (x) and half width (y) of the collision box [m], > 0.
        hull_height: top of the collision box above the ground [m], > 0.
        eye_offset: ``(3,)`` the driver's eye in the chassis frame [m] (z: height above
            the ground).
        accel_range: ``(maximum braking, maximum acceleration)`` [m/s^2], braking < 0 < accel.
        steer_range: ``(full right, full left)`` steering angle [rad], right < 0 < left.

    Arrays are stored read-only; ValueError (one message listing every bad field) on a
    value that is not finite, of the wrong shape, or out of range. The ranges are those of
    a car in metres, seconds and radians at any scale from a 1:40 model to a road train
    (:data:`CAR_LENGTH`, :data:`CAR_WIDTH`, :data:`CAR_SIZE`, accelerations within
    :data:`cdf_mj.config.MAX_ACCEL`, steering within pi/2 rad); a value outside says which
    unit it looks like (``hull_half=[2300.0, 900.0] makes the box 4600 m long: a car is
    0.05-30 m long; millimetres?``).
    """

    wheelbase: float
    hull_offset: np.ndarray
    hull_half: np.ndarray
    hull_height: float
    eye_offset: np.ndarray
    accel_range: tuple[float, float]
    steer_range: tuple[float, float]

    def __post_init__(self) -> None:
        bad: list[str] = []
        vectors = {"hull_offset": 2, "hull_half": 2, "eye_offset": 3}
        for name, size in vectors.items():
            value = _vector(getattr(self, name), size)
            if value is None or not np.all(np.isfinite(value)):
                bad.append(f"{name}={getattr(self, name)!r} must be {size} finite numbers [m]")
            elif name == "hull_half" and not np.all(value > 0):
                bad.append(f"hull_half={value.tolist()} must be > 0 [m]")
            elif name == "hull_half" and (implausible := _box_problem(value)):
                bad.append(f"hull_half={value.tolist()} {implausible}")
            elif (far := float(np.max(np.abs(value)))) > CAR_SIZE:
                bad.append(f"{name}={value.tolist()} reaches {far:g} m from the rear axle: a car's "
                           f"parts are within {CAR_SIZE:g} m of it{unit_hint(far, CAR_SIZE)}")
            else:
                object.__setattr__(self, name, value)
        for name in ("wheelbase", "hull_height"):
            value = getattr(self, name)
            try:
                number = float(value)
            except (TypeError, ValueError):
                number = math.nan
            if not (math.isfinite(number) and number > 0):
                bad.append(f"{name}={value!r} must be a finite number > 0 [m]")
            elif number > CAR_SIZE:
                bad.append(f"{name}={number:g} m: a car's is at most {CAR_SIZE:g} m"
                           f"{unit_hint(number, CAR_SIZE)}")
            else:
                object.__setattr__(self, name, number)
        for name, unit, sides in (("accel_range", "m/s^2", "braking < 0 < acceleration"),
                                  ("steer_range", "rad", "right < 0 < left")):
            pair = _pair(getattr(self, name))
            if pair is None or not (math.isfinite(pair[0]) and math.isfinite(pair[1])
                                    and pair[0] < 0.0 < pair[1]):
                bad.append(f"{name}={getattr(self, name)!r} must be two finite numbers, "
                           f"{sides} [{unit}]")
            elif implausible := _range_problem(name, max(-pair[0], pair[1])):
                bad.append(f"{name}={pair!r} {implausible}")
            else:
                object.__setattr__(self, name, pair)
        if bad:
            raise ValueError(f"CarGeometry: {'; '.join(bad)}")

    @classmethod
    def ours(cls) -> CarGeometry:
        """Our car, ``models/xml/car.xml``, without reading it: 2.7 m wheelbase, a 4.6 m x
        1.8 m x 1.45 m collision box from 0.95 m behind the rear axle, the eye 1.2 m ahead,
        0.35 m left and 1.2 m up, braking 4.877 m/s^2 (16 ft/s^2), acceleration 3 m/s^2,
        steering +-0.6 rad (tests/test_user_cars.py checks it against the file)."""
        return cls(wheelbase=2.7, hull_offset=np.array([1.35, 0.0]), hull_half=np.array([2.3, 0.9]),
                   hull_height=1.45, eye_offset=np.array([1.2, 0.35, 1.2]),
                   accel_range=(-4.877, 3.0), steer_range=(-0.6, 0.6))

    def to_dict(self) -> dict[str, float | list[float]]:
        """JSON-serialisable view (lists of floats); :meth:`from_dict` reads it back."""
        return {"wheelbase": self.wheelbase, "hull_offset": self.hull_offset.tolist(),
                "hull_half": self.hull_half.tolist(), "hull_height": self.hull_height,
                "eye_offset": self.eye_offset.tolist(), "accel_range": list(self.accel_range),
                "steer_range": list(self.steer_range)}

    @classmethod
    def from_dict(cls, data: dict[str, object]) -> CarGeometry:
        """The geometry of a :meth:`to_dict` dict; ValueError naming a missing or unknown key,
        or (from the constructor) every bad value."""
        keys = ("wheelbase", "hull_offset", "hull_half", "hull_height", "eye_offset",
                "accel_range", "steer_range")
        if not isinstance(data, dict):
            raise ValueError(f"CarGeometry: expected an object with keys {', '.join(keys)}, "
                             f"got {type(data).__name__}")
        missing = [k for k in keys if k not in data]
        unknown = sorted(set(data) - set(keys))
        if missing or unknown:
            raise ValueError(f"CarGeometry: {'missing ' + ', '.join(missing) if missing else ''}"
                             f"{'; ' if missing and unknown else ''}"
                             f"{'unknown ' + ', '.join(unknown) if unknown else ''}")
        return cls(**data)  # type: ignore[arg-type]  # the constructor checks every value

    def padded(self, margin: float) -> CarGeometry:
        """This car with ``margin`` [m] added to each half size of its collision box (a
        safety envelope: the box of a car at :data:`CAR_LENGTH`'s or :data:`CAR_WIDTH`'s
        bound grows past it by ``2 * margin``, so that every car the constructor takes can
        be padded). ValueError unless ``margin`` is a finite number of at most
        :data:`CAR_SIZE` that leaves the box a size (a negative one shrinks it); 0 gives
        this very car."""
        try:
            pad = float(margin)
        except (TypeError, ValueError):
            pad = math.nan
        if not (math.isfinite(pad) and abs(pad) <= CAR_SIZE and np.all(self.hull_half + pad > 0)):
            raise ValueError(f"CarGeometry.padded: margin={margin!r} must be a finite number [m] of at most "
                             f"{CAR_SIZE:g} that leaves the box a size")
        if pad == 0.0:
            return self
        out = object.__new__(CarGeometry)  # every field as checked, but the padded box
        for f in fields(self):
            object.__setattr__(out, f.name, getattr(self, f.name))
        half = self.hull_half + pad
        half.flags.writeable = False
        object.__setattr__(out, "hull_half", half)
        return out

    @property
    def length(self) -> float:
        """Length of the collision box [m]."""
        return 2.0 * float(self.hull_half[0])

    @property
    def width(self) -> float:
        """Width of the collision box [m]."""
        return 2.0 * float(self.hull_half[1])

    @property
    def max_brake(self) -> float:
        """Maximum braking deceleration [m/s^2], positive."""
        return -self.accel_range[0]

    @property
    def max_accel(self) -> float:
        """Maximum acceleration [m/s^2], positive."""
        return self.accel_range[1]

    @property
    def max_steer(self) -> float:
        """Largest steering angle [rad] reachable to both sides, positive."""
        return min(-self.steer_range[0], self.steer_range[1])

    def footprint(self, pose: np.ndarray | Sequence[float]) -> np.ndarray:
        """Corners ``(..., 4, 2)`` [m, world frame] of the collision box for pose(s)
        ``(..., 4)`` ``[x, y, theta, v]``, counter-clockwise."""
        pose = np.asarray(pose, dtype=float)
        c, s = np.cos(pose[..., 2]), np.sin(pose[..., 2])
        ox, oy = self.hull_offset
        return rotated_corners(pose[..., 0] + c * ox - s * oy, pose[..., 1] + s * ox + c * oy, c, s,
                               self.hull_half)

    @functools.cached_property
    def _hull_floats(self) -> tuple[float, float, float, float]:
        """The collision box's offset and half sizes [m] as Python floats (footprint_one's)."""
        ox, oy = self.hull_offset.tolist()
        hx, hy = self.hull_half.tolist()
        return ox, oy, hx, hy

    def footprint_one(self, x: float, y: float, theta: float) -> list[tuple[float, float]]:
        """:meth:`footprint` of one rear-axle pose ``x, y`` [m], ``theta`` [rad] on Python
        floats (the same operations, so the same values, without NumPy's per-call
        overhead: the per-tick calls on one car): four corners ``(x, y)`` [m]."""
        c, s = math.cos(theta), math.sin(theta)
        ox, oy, hx, hy = self._hull_floats
        return box_corners_one(x + c * ox - s * oy, y + s * ox + c * oy, c, s, hx, hy)

    def eye(self, pose: np.ndarray | Sequence[float]) -> np.ndarray:
        """World position(s) ``(..., 3)`` [m] of the driver's eye for pose(s) ``(..., 4)``
        ``[x, y, theta, v]``; z is the eye's height above the ground."""
        pose = np.asarray(pose, dtype=float)
        c, s = np.cos(pose[..., 2]), np.sin(pose[..., 2])
        ex, ey, ez = self.eye_offset
        out = np.empty((*pose.shape[:-1], 3))
        out[..., 0] = pose[..., 0] + c * ex - s * ey
        out[..., 1] = pose[..., 1] + s * ex + c * ey
        out[..., 2] = ez
        return out
