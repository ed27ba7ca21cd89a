"""Deprecated: car following moved to :mod:`cdf_mj.model.road`, the one home of the road's
words (in the lane, ahead, gap, the IDM, the RSS distance, following).

The names of version 0.3 still read from here, each with a DeprecationWarning naming its
new spelling, and give what they gave::

    following.follow_accel(...)        ->  road.follow_accel(...)
    following.in_lane_ahead(...)       ->  road.in_lane_ahead(..., lane="corner", by="axle")
    following.ahead_in_lane(..., w)    ->  road.in_lane_ahead(..., lane="corner", by="axle", within=w)
    following.idm_interaction(...)     ->  road.idm(..., s_star="total", gap_floor=1e-3, max_brake=...)
    following.rss_distance(...)        ->  road.rss_distance(...)
    following.FOLLOW_HEADING           ->  road.FOLLOW_HEADING
"""

from __future__ import annotations

import warnings
from typing import Any

from cdf_mj.model import road

__all__: list[str] = []  # nothing new is exported from here


def _in_lane_ahead(layout: Any, lead: Any, lead_car: Any, follower: Any) -> bool:
    return road.in_lane_ahead(layout, lead, lead_car, follower, None, lane="corner", by="axle")


def _ahead_in_lane(layout: Any, lead: Any, lead_car: Any, follower: Any, within: float = road.FOLLOW_HEADING) -> bool:
    return road.in_lane_ahead(layout, lead, lead_car, follower, None, lane="corner", by="axle", within=within)


def _idm_interaction(gap: float, v: float, v_lead: float, a_max: float, b: float, time_gap: float,
                     min_gap: float, max_brake: float) -> float:
    return road.idm(v, v_lead, gap, a_max=a_max, b=b, time_gap=time_gap, min_gap=min_gap, s_star="total",
                    gap_floor=1e-3, max_brake=max_brake)


_MOVED: dict[str, tuple[Any, str]] = {
    "FOLLOW_HEADING": (road.FOLLOW_HEADING, "cdf_mj.model.road.FOLLOW_HEADING"),
    "follow_accel": (road.follow_accel, "cdf_mj.model.road.follow_accel"),
    "in_lane_ahead": (_in_lane_ahead, 'cdf_mj.model.road.in_lane_ahead(..., lane="corner", by="axle")'),
    "ahead_in_lane": (_ahead_in_lane, 'cdf_mj.model.road.in_lane_ahead(..., lane="corner", by="axle", within=...)'),
    "idm_interaction": (_idm_interaction, 'cdf_mj.model.road.idm(..., s_star="total", gap_floor=1e-3, max_brake=...)'),
    "rss_distance": (road.rss_distance, "cdf_mj.model.road.rss_distance"),
}


def __getattr__(name: str) -> Any:
    """A name of version 0.3, with a DeprecationWarning naming where it lives now."""
    try:
        value, new = _MOVED[name]
    except KeyError:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
    warnings.warn(f"cdf_mj.model.following.{name} is deprecated; use {new}", DeprecationWarning, stacklevel=2)
    return value
