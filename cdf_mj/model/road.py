"""The road's words, one definition each: in the ego's lane, ahead in it, the gap between two
cars, the intelligent driver model (IDM), the RSS safe distance, the heading a car is
followed within, and car following. Every caller asks here: the world's measurement and
the episode's end, the ego's and the obstacle's car following, the layered rule's follow
layer, the reactive planner, the driver families, the sensor, the monitor and the safety
metrics. ::

    from cdf_mj.model.road import in_lane, in_lane_ahead, car_gap, idm, rss_distance

    in_lane(layout, car.footprint_one(x, y, theta))                  # its box meets the ego's lane
    in_lane_ahead(layout, lead, lead_car, follower, follower_car, within=FOLLOW_HEADING)
    car_gap(ego_car, ego_pose, lead_car, lead_pose)                  # [m] bumper to bumper
    rss_distance(v_r, v_f, rho, a_acc, b_min, b_max)                 # [m]

One definition each, used by every caller. *In the lane*: the car's collision box meets the
lane's box (a crossing car longer than the lane is wide straddles it with no corner inside,
and is in it). *Ahead*: the car's box centre is further along the ego's route than the
other's (rear axles would order two cars of different lengths wrongly when they are
nearly level). Until version 0.3 the world's measurement, the sensor, the monitor, the
episode's end and car following asked for a corner inside the lane and compared rear
axles, while the safety metrics used these; the older readings stay as ``by="corner"``
and ``by="axle"`` for comparison. Choosing one changed no record: 13 424 episodes of
``scripts/record_identity.py`` (every planner and every preset on held-out seeds, the
1000-seed reproduction, Gymnasium trajectories) came out byte-identical.

Where callers ask different questions, the difference is an explicit argument:

============== ============================ ===============================================
word           variant                      caller, and why
============== ============================ ===============================================
in_lane        ``by="overlap"`` (default)   every caller: the world's measurement
                                            (``obstacle_in_lane``), the sensor's noisy flag,
                                            the monitor, the episode's end, car following,
                                            the safety metrics
               ``by="corner"``              the reading of version 0.3 (a corner inside)
ahead          ``by="centre"`` (default)    every caller that asks which car is in front:
                                            the episode's end, car following, the layered
                                            rule's follow layer, the safety metrics
               ``by="axle"``                the reading of version 0.3 (rear axles)
               ``by="extent"``              the reactive planner: the lead's box reaches
                                            the follower's tail (its front-most corner is
                                            at or past the follower's rearmost, along the
                                            route): a car level with the ego, or just
                                            behind its front, is still ahead of its tail
                                            (its trigger, not an order of two cars)
in_lane_ahead  ``within=None``              the episode's end (``timing.until_clear``): a
                                            car in the lane ahead, whatever its heading
               ``within=FOLLOW_HEADING``    car following (:func:`follow_accel`): a car
                                            heading the follower's way (it has merged)
               ``within=pi/2``              the layered rule's follow layer (its
                                            ``FOLLOW_WITHIN``): any car not coming back
idm            ``v0=None``,                 car following and the layered rule: the
               ``s_star="total"``,          interaction term only (the car's own
               ``gap_floor=1e-3``,          controller holds its speed), desired gap
               ``max_brake=...``            ``[s0 + max(v, 0) T + v dv / 2 sqrt(ab)]^+``,
                                            braking at most ``max_brake``
               ``v0=...``,                  the driver families: the full IDM with its
               ``s_star="dynamic"``,        free-road term, desired gap
               ``gap_floor=0.05``           ``s0 + [v T + v dv / 2 sqrt(ab)]^+``
                                            (Treiber's), unclamped (the family clips the
                                            result to its car's limits)
============== ============================ ===============================================

World frame (x east, y north), metres, seconds, radians; poses are rear-axle
``[x, y, theta, v]``; "the ego's route" is ``layout.route_ego`` and "the lane"
``layout.ego_lane``. The functions run every tick on Python floats; the IDM and RSS
distance give, bit for bit, what their callers computed before they were moved here
(``cdf_mj.model.following``, the drivers' ``idm_accel``, the safety metrics' own).
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Sequence
from typing import Literal, TypeAlias

import numpy as np

from cdf_mj.config import Ego
from cdf_mj.model.geometry import box_gap
from cdf_mj.model.layout import Layout
from cdf_mj.model.vehicle import CarGeometry

__all__ = ["FOLLOW_HEADING", "IDM_DELTA", "AheadBy", "InLaneBy", "Pose", "SStar", "ahead", "car_gap", "follow_accel",
           "heading_within", "idm", "in_lane", "in_lane_ahead", "route_arc", "rss_distance"]

#: A rear-axle pose ``[x m, y m, theta rad, v m/s]`` (world frame).
Pose: TypeAlias = np.ndarray | Sequence[float]
#: How a car's box is in the lane: ``"corner"`` a corner inside it, ``"overlap"`` the boxes meet.
InLaneBy: TypeAlias = Literal["corner", "overlap"]
#: What of two cars is compared along the route: ``"axle"`` their rear axles, ``"centre"`` their box
#: centres, ``"extent"`` the lead's front-most corner against the follower's rearmost.
AheadBy: TypeAlias = Literal["axle", "centre", "extent"]
#: The IDM's desired gap: ``"total"`` floored at 0 as a whole, ``"dynamic"`` ``s0`` plus its floored speed terms.
SStar: TypeAlias = Literal["total", "dynamic"]

#: [rad] A car is followed once its heading is within this of the follower's: it has merged.
#: A car still crossing or turning into the lane is a conflict for the planner, not a car
#: to follow (the nominal controller would otherwise brake for every cut-off by itself).
FOLLOW_HEADING = math.radians(30.0)
#: [1] The IDM's free-road acceleration exponent (Treiber, Hennecke, Helbing 2000).
IDM_DELTA = 4.0

_LANE_CORNERS: weakref.WeakKeyDictionary[Layout, np.ndarray] = weakref.WeakKeyDictionary()


def _lane_corners(layout: Layout) -> np.ndarray:
    """The ego lane's corners ``(4, 2)`` [m], computed once per layout."""
    corners = _LANE_CORNERS.get(layout)
    if corners is None:
        corners = _LANE_CORNERS[layout] = layout.ego_lane.corners()
    return corners


# ------------------------------------------------------------------------------ where a car is
def in_lane(layout: Layout, box: np.ndarray | Sequence[tuple[float, float]], *, by: InLaneBy = "overlap") -> bool:
    """Whether a car's collision box (its corners ``(4, 2)`` [m], e.g.
    ``car.footprint_one(x, y, theta)``) is in the ego's lane: the two boxes meet (their
    :func:`~cdf_mj.model.geometry.box_gap` is 0, touching included); ``by="corner"``, the
    reading of version 0.3: a corner of it inside the lane, boundary included."""
    if by == "overlap":
        return box_gap(box, _lane_corners(layout)) == 0.0
    if by == "corner":
        return layout.ego_lane.contains_any(box)
    raise ValueError(f"in_lane: by={by!r} must be 'corner' or 'overlap'")


def route_arc(layout: Layout, pose: Pose, car: CarGeometry | None = None) -> float:
    """[m] The arc length along the ego's route of the point nearest to the rear axle at
    ``pose``, or, with ``car``, to the centre of its collision box."""
    x, y = float(pose[0]), float(pose[1])
    if car is not None:
        theta = float(pose[2])
        c, s = math.cos(theta), math.sin(theta)
        ox, oy = float(car.hull_offset[0]), float(car.hull_offset[1])
        x, y = x + c * ox - s * oy, y + s * ox + c * oy
    return layout.route_ego.project_point(x, y)[0]


def _corner_arcs(layout: Layout, pose: Pose, car: CarGeometry) -> list[float]:
    """[m] The arc lengths along the ego's route of the points nearest to the corners of
    the car's collision box at ``pose``."""
    route = layout.route_ego
    box = car.footprint_one(float(pose[0]), float(pose[1]), float(pose[2]))
    return [route.project_point(float(x), float(y))[0] for x, y in box]


def ahead(layout: Layout, lead: Pose, lead_car: CarGeometry, follower: Pose, follower_car: CarGeometry | None,
          *, by: AheadBy = "centre") -> bool:
    """Whether the car at ``lead`` is further along the ego's route than the one at
    ``follower`` (:func:`route_arc`): their box centres; ``by="extent"`` whether the lead's
    box reaches the follower's tail, the front-most of its corners at or past the rearmost
    of the follower's (``follower_car`` needed for both); ``by="axle"``, the reading of
    version 0.3: their rear axles (``follower_car`` may be None). Where it is, and its
    heading, are not asked."""
    if by == "centre":
        if follower_car is None:
            raise ValueError("ahead: by='centre' needs follower_car (the follower's box centre)")
        return route_arc(layout, lead, lead_car) > route_arc(layout, follower, follower_car)
    if by == "axle":
        return route_arc(layout, lead) > route_arc(layout, follower)
    if by == "extent":
        if follower_car is None:
            raise ValueError("ahead: by='extent' needs follower_car (the follower's rearmost corner)")
        return max(_corner_arcs(layout, lead, lead_car)) >= min(_corner_arcs(layout, follower, follower_car))
    raise ValueError(f"ahead: by={by!r} must be 'axle', 'centre' or 'extent'")


def heading_within(theta_lead: float, theta_follower: float, within: float = FOLLOW_HEADING) -> bool:
    """Whether two headings [rad] differ by at most ``within`` [rad] (1e-12 of slack on
    the cosine): the lead heads the follower's way."""
    return math.cos(float(theta_lead) - float(theta_follower)) >= math.cos(within) - 1e-12


def in_lane_ahead(layout: Layout, lead: Pose, lead_car: CarGeometry, follower: Pose,
                  follower_car: CarGeometry | None, *, lane: InLaneBy = "overlap", by: AheadBy = "centre",
                  within: float | None = None) -> bool:
    """Whether the car at ``lead`` (of dimensions ``lead_car``) is in the ego's lane
    (:func:`in_lane` ``by=lane``) and :func:`ahead` of the car at ``follower`` (``by``),
    and, unless ``within`` is None, heading its way within ``within`` [rad]
    (:func:`heading_within`; :data:`FOLLOW_HEADING`: a car that has merged, to follow)."""
    if within is not None and not heading_within(lead[2], follower[2], within):
        return False
    lx, ly, lth = float(lead[0]), float(lead[1]), float(lead[2])
    if not in_lane(layout, lead_car.footprint_one(lx, ly, lth), by=lane):
        return False
    return ahead(layout, lead, lead_car, follower, follower_car, by=by)


def car_gap(car_a: CarGeometry, pose_a: Pose, car_b: CarGeometry, pose_b: Pose) -> float:
    """[m] The distance between the collision boxes of two cars at their poses (0 when they
    touch): :func:`~cdf_mj.model.geometry.box_gap` of their footprints, in this order."""
    return box_gap(car_a.footprint_one(float(pose_a[0]), float(pose_a[1]), float(pose_a[2])),
                   car_b.footprint_one(float(pose_b[0]), float(pose_b[1]), float(pose_b[2])))


# ------------------------------------------------------------------------------ how a car follows
def idm(v: float, v_lead: float, gap: float, *, a_max: float, b: float, time_gap: float, min_gap: float,
        s_star: SStar, gap_floor: float, v0: float | None = None, delta: float = IDM_DELTA,
        max_brake: float | None = None) -> float:
    """The intelligent driver model's acceleration [m/s^2] (Treiber, Hennecke, Helbing 2000)
    of a car at speed ``v`` [m/s] behind a car ``gap`` [m] ahead (bumper to bumper; ``inf``:
    none, free road) at speed ``v_lead`` [m/s] along the follower's heading::

        a = a_max [1 - (v / v0)^delta - (s* / max(gap, gap_floor))^2]

    ``a_max`` its largest and ``b`` its comfortable acceleration [m/s^2], ``time_gap`` T [s],
    ``min_gap`` s0 [m]. The variants (see the module docstring for who uses which):
    ``v0`` [m/s] None leaves the free-road term out (the interaction term only);
    ``s_star="total"`` takes ``s* = [s0 + max(v, 0) T + v (v - v_lead) / (2 sqrt(a_max b))]^+``,
    ``"dynamic"`` ``s* = s0 + [v T + v (v - v_lead) / (2 sqrt(a_max b))]^+``; the gap is at
    least ``gap_floor`` [m]; the result at least ``-max_brake`` [m/s^2] unless it is None."""
    free = 1.0 if v0 is None else 1.0 - (max(v, 0.0) / max(v0, 1e-6)) ** delta
    if gap == math.inf:
        acc = free
    else:
        root = 2.0 * math.sqrt(a_max * b)
        if s_star == "total":
            desired = max(min_gap + max(v, 0.0) * time_gap + v * (v - v_lead) / root, 0.0)
        elif s_star == "dynamic":
            desired = min_gap + max(0.0, v * time_gap + v * (v - v_lead) / root)
        else:
            raise ValueError(f"idm: s_star={s_star!r} must be 'total' or 'dynamic'")
        acc = free - (desired / max(gap, gap_floor)) ** 2
    out = a_max * acc
    return out if max_brake is None else max(out, -max_brake)


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


def follow_accel(layout: Layout, follower_car: CarGeometry, follower: Pose, lead_car: CarGeometry, lead: Pose,
                 params: Ego, max_brake: float | None = None) -> float | None:
    """The follower's IDM acceleration [m/s^2] (its interaction term: its own controller
    holds its speed) behind the lead car when the lead is in the ego's lane ahead of it and
    heading its way (:func:`in_lane_ahead`, ``within=FOLLOW_HEADING``), else None (also for
    a pose that is not finite: a missed measurement). ``params`` gives the time gap,
    standstill gap and comfortable braking (``ego.time_gap``, ``ego.min_gap``,
    ``ego.comfort_brake``); ``max_brake`` [m/s^2] the most it brakes for it (default: the
    follower car's maximum). The ego follows the obstacle, and the obstacle the ego once it
    has merged behind it (``after_merge.follows``)."""
    if not (np.isfinite(lead).all() and np.isfinite(follower).all()):
        return None
    if not in_lane_ahead(layout, lead, lead_car, follower, follower_car, within=FOLLOW_HEADING):
        return None
    fv, lv = float(follower[3]), float(lead[3])
    gap = car_gap(follower_car, follower, lead_car, lead)
    return idm(fv, lv * math.cos(float(lead[2]) - float(follower[2])), gap, a_max=follower_car.max_accel,
               b=params.comfort_brake, time_gap=params.time_gap, min_gap=params.min_gap, s_star="total",
               gap_floor=1e-3,
               max_brake=follower_car.max_brake if max_brake is None else min(max_brake, follower_car.max_brake))
