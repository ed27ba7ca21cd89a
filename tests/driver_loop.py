"""A world driver (cdf_mj/scenario/drivers.py, crash_drivers.py) in closed loop with a
scripted ego, without MuJoCo: the driver's own kinematic bicycle integrated at ``DT``
(controls checked against the car's limits, speed >= 0), the ego driving its route at
``EGO_SPEED`` from its nominal start, line of sight scripted by ``sight(t)``."""

from __future__ import annotations

import ast
import dataclasses
import importlib.util
import math
import subprocess
import sys
from collections.abc import Callable

import numpy as np

from cdf_mj.model.modes import LEFT
from cdf_mj.scenario.drivers import WorldDriver

DT = 0.1  # [s]
EGO_SPEED = 13.4  # [m/s]


def never(t: float) -> bool:
    return False


def always(t: float) -> bool:
    return True


@dataclasses.dataclass
class Run:
    t: np.ndarray  # (K,) [s]
    pose: np.ndarray  # (K, 4) the obstacle's pose at the start of each tick
    mode: np.ndarray  # (K,) after its decision
    accel: np.ndarray  # (K,) [m/s^2] as commanded
    ego_s: np.ndarray  # (K,) [m] the ego's rear axle along its route
    looking: np.ndarray  # (K,) it looked on the tick (driver.looking before its control)

    def first(self, mask: np.ndarray) -> float:
        """The first time where ``mask`` holds (inf if never)."""
        hits = np.flatnonzero(mask)
        return float(self.t[hits[0]]) if len(hits) else math.inf


def run(layout, driver: WorldDriver, intent: int = LEFT, *, seed: int = 0, sight: Callable[[float], bool] = never,
        seconds: float = 10.0, ego_shift: float = 0.0, only_looking: bool = False) -> Run:
    """Closed loop of ``driver`` and a scripted ego ``ego_shift`` [m] ahead of its nominal
    start; the driver is shown the ego where ``sight(t)`` (and, with ``only_looking``, only
    on ticks it is ``looking``, as the world shows it)."""
    driver.reset(layout, intent, np.random.default_rng(seed))
    car, route = layout.obstacle, layout.route_ego
    pose = np.array(driver.start, dtype=float)
    s_ego = float(route.project(layout.ego_start[:2])[0]) + ego_shift
    rows = []
    for k in range(round(seconds / DT)):
        t = round(k * DT, 9)
        ahead = route.point_at(s_ego + 1.0) - route.point_at(s_ego)
        ego = np.array([*route.point_at(s_ego), math.atan2(ahead[1], ahead[0]), EGO_SPEED])
        looking = driver.looking
        shown = sight(t) and (looking or not only_looking)
        accel, steer = driver.control(t, pose.copy(), ego if shown else None, DT)
        assert car.accel_range[0] - 1e-12 <= accel <= car.accel_range[1] + 1e-12
        assert abs(steer) <= car.max_steer + 1e-12
        rows.append((t, *pose, driver.mode, accel, s_ego, looking))
        x, y, th, v = pose
        pose = np.array([x + v * DT * math.cos(th), y + v * DT * math.sin(th),
                         th + v * DT / car.wheelbase * math.tan(steer), max(v + accel * DT, 0.0)])
        s_ego += EGO_SPEED * DT
    a = np.array(rows)
    return Run(t=a[:, 0], pose=a[:, 1:5], mode=a[:, 5].astype(int), accel=a[:, 6], ego_s=a[:, 7],
               looking=a[:, 8].astype(bool))


def progress(layout, pose: np.ndarray) -> np.ndarray:
    """[m] the rear axle past its stop position along the side road's direction."""
    x0, y0, th0, _ = layout.obstacle_start
    return (pose[:, 0] - x0) * math.cos(th0) + (pose[:, 1] - y0) * math.sin(th0)


#: What a world driver, written apart from the filter, must not import.
FILTER_MODULES = ("cdf_mj.model.driver", "cdf_mj.model.kernels", "cdf_mj.inference")


def assert_written_apart(module: str, then: str = "") -> None:
    """``module`` (a world driver's) imports none of :data:`FILTER_MODULES`, and importing
    it (then running ``then``) in a fresh interpreter loads none of them either."""
    spec = importlib.util.find_spec(module)
    assert spec is not None and spec.origin is not None, module
    with open(spec.origin, encoding="utf-8") as fh:
        tree = ast.parse(fh.read())
    imported = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    imported |= {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    assert not [m for m in imported if m and m.startswith(FILTER_MODULES)], imported
    code = (f"import sys, {module}\n{then}"
            f"print(sorted(m for m in sys.modules if m.startswith({FILTER_MODULES!r})))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=False)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "[]"
