"""Car following in the ego's lane: the intelligent driver model's (IDM) interaction term,
used by the world's cars behind another one that has merged into the ego's lane (the ego's nominal controller behind the
obstacle, ``ego.follow``; the obstacle behind the ego once it has merged,
``after_merge.follows``). Its desired speed is the car's own controller's, so only the
interaction term is taken here (Treiber, Hennecke, Helbing 2000):

    a = a_max (1 - (s* / s)^2),   s* = s0 + v T + v dv / (2 sqrt(a_max b))

with ``s`` the gap between the two collision boxes [m], ``v`` the follower's speed, ``dv``
its closing speed on the car ahead along its own heading [m/s], ``T`` the time gap [s],
``s0`` the gap at standstill [m] and ``b`` a comfortable braking [m/s^2]; the result is at
least minus the follower's maximum braking. World frame, rear-axle poses ``[x, y, theta, v]``.
"""

from __future__ import annotations

import math

import numpy as np

from cdf_mj.config import Ego
from cdf_mj.model.geometry import box_gap
from cdf_mj.model.layout import Layout
from cdf_mj.model.vehicle import CarGeometry

__all__ = ["FOLLOW_HEADING", "ahead_in_lane", "follow_accel", "idm_interaction", "in_lane_ahead", "rss_distance"]


def idm_interaction(gap: float, v: float, v_lead: float, a_max: float, b: float, time_gap: float,
                    min_gap: float, max_brake: float) -> float:
    """The IDM's interaction acceleration [m/s^2] (see the module docstring)."""
    desired = min_gap + max(v, 0.0) * time_gap + v * (v - v_lead) / (2.0 * math.sqrt(a_max * b))
    return max(a_max * (1.0 - (max(desired, 0.0) / max(gap, 1e-3)) ** 2), -max_brake)


def rss_distance(v_r: float, v_f: float, rho: float, a_acc: float, b_min: float, b_max: float) -> float:
    """[m] The RSS longitudinal safe distance behind a car ahead (Shalev-Shwartz, Shammah,
    Shashua 2017): ``[v_r rho + a_acc rho^2 / 2 + (v_r + rho a_acc)^2 / (2 b_min)
    - v_f^2 / (2 b_max)]^+`` with ``v_r`` the rear car's speed and ``v_f`` the front car's
    along the rear car's direction [m/s] (each taken as 0 where negative), ``rho`` the rear
    car's response time [s], ``a_acc`` its largest acceleration during it, ``b_min`` the
    braking it can count on afterwards and ``b_max`` the front car's largest [m/s^2]."""
    v_r, v_f = max(v_r, 0.0), max(v_f, 0.0)
    d = v_r * rho + 0.5 * a_acc * rho ** 2 + (v_r + rho * a_acc) ** 2 / (2.0 * b_min) - v_f ** 2 / (2.0 * b_max)
    return max(d, 0.0)


#: [rad] A car is followed once its heading is within this of the follower's: it has merged.
#: A car still crossing or turning into the lane is a conflict for the planner, not a car
#: to follow (the nominal controller would otherwise brake for every cut-off by itself).
FOLLOW_HEADING = math.radians(30.0)


def in_lane_ahead(layout: Layout, lead: np.ndarray, lead_car: CarGeometry, follower: np.ndarray) -> bool:
    """Whether the car at pose ``lead`` (of dimensions ``lead_car``) is in the ego's lane (a
    corner of its box) and its rear axle further along the ego's route than the car's at
    ``follower``, whatever its heading (the episode's end waits for no such car)."""
    lx, ly, lth = float(lead[0]), float(lead[1]), float(lead[2])
    if not layout.ego_lane.contains_any(lead_car.footprint_one(lx, ly, lth)):
        return False
    route = layout.route_ego
    return bool(route.project_point(lx, ly)[0] > route.project_point(float(follower[0]), float(follower[1]))[0])


def ahead_in_lane(layout: Layout, lead: np.ndarray, lead_car: CarGeometry, follower: np.ndarray,
                  within: float = FOLLOW_HEADING) -> bool:
    """:func:`in_lane_ahead`, and heading the follower's way, within ``within`` [rad]
    (default :data:`FOLLOW_HEADING`: a car that has merged, to follow)."""
    return (math.cos(float(lead[2]) - float(follower[2])) >= math.cos(within) - 1e-12
            and in_lane_ahead(layout, lead, lead_car, follower))


def follow_accel(layout: Layout, follower_car: CarGeometry, follower: np.ndarray, lead_car: CarGeometry,
                 lead: np.ndarray, params: Ego, max_brake: float | None = None) -> float | None:
    """The follower's IDM acceleration [m/s^2] behind the lead car when the lead is ahead of
    it in the ego's lane (:func:`ahead_in_lane`), else None (also for a pose that is not
    finite: a missed measurement). ``params`` gives the time gap, standstill gap and
    comfortable braking (``ego.time_gap``, ``ego.min_gap``, ``ego.comfort_brake``);
    ``max_brake`` [m/s^2] the most it brakes for it (default: the follower car's maximum)."""
    if not (np.isfinite(lead).all() and np.isfinite(follower).all()):
        return None
    if not ahead_in_lane(layout, lead, lead_car, follower):
        return None
    fx, fy, fth, fv = (float(v) for v in follower)
    lx, ly, lth, lv = (float(v) for v in lead)
    gap = box_gap(follower_car.footprint_one(fx, fy, fth), lead_car.footprint_one(lx, ly, lth))
    return idm_interaction(gap, fv, lv * math.cos(lth - fth), follower_car.max_accel, params.comfort_brake,
                           params.time_gap, params.min_gap,
                           follower_car.max_brake if max_brake is None else min(max_brake, follower_car.max_brake))
