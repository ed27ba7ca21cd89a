"""Names that issue 34 moved still read from their old homes, each with a DeprecationWarning
naming the new one, and give what the new one gives."""

from __future__ import annotations

import math

import pytest

from cdf_mj.model import road


def test_the_old_following_module_reads_the_roads_words(scene):
    from cdf_mj.model import following

    with pytest.warns(DeprecationWarning, match=r"cdf_mj\.model\.road\.follow_accel"):
        assert following.follow_accel is road.follow_accel
    with pytest.warns(DeprecationWarning, match="within"):
        ahead_in_lane = following.ahead_in_lane
    with pytest.warns(DeprecationWarning, match='s_star="total"'):
        interaction = following.idm_interaction
    # the interaction term as it was: a_max (1 - (s*/s)^2), s* = s0 + v T + v dv / (2 sqrt(a b)), at least -brake
    v, v_lead, gap, a, b, t_gap, s0, brake = 10.0, 6.0, 12.0, 2.0, 3.0, 1.5, 2.0, 4.0
    desired = s0 + v * t_gap + v * (v - v_lead) / (2.0 * math.sqrt(a * b))
    assert interaction(gap, v, v_lead, a, b, t_gap, s0, brake) == max(a * (1.0 - (desired / gap) ** 2), -brake)
    # the 0.3 reading of "in the lane, ahead": a corner inside, rear axles; a crossing car
    # straddling the lane is in it now and was not then
    layout = scene.layout()
    car, ego, crossing = layout.obstacle, [0.0, -1.85, 0.0, 10.0], [5.0, -1.85 + 1.35, -math.pi / 2, 5.0]
    assert ahead_in_lane(layout, [20.0, -1.85, 0.0, 8.0], car, ego)  # a merged car ahead
    assert not ahead_in_lane(layout, crossing, car, ego, math.pi / 2)
    assert road.in_lane_ahead(layout, crossing, car, ego, layout.ego, within=math.pi / 2)
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        _ = following.nope


def test_the_old_idm_accel_is_the_families_idm():
    from cdf_mj.scenario import drivers

    with pytest.warns(DeprecationWarning, match="road.idm"):
        idm_accel = drivers.idm_accel
    free = 2.0 * (1.0 - (5.0 / 8.0) ** 4)
    assert idm_accel(5.0, 8.0, 2.0, 3.0) == pytest.approx(free, rel=1e-15)  # free road: a [1 - (v/v0)^4]
    assert idm_accel(5.0, 8.0, 2.0, 3.0, gap=20.0, v_lead=5.0) < free
