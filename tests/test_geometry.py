"""Planar geometry's one-box twins: the same answers as shapely and as the vectorised
functions (box gap against ``shapely.distance``; corners, lane test and projection against
their NumPy forms)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely

from cdf_mj.model.geometry import OrientedBox, Polyline, box_corners, box_corners_one, box_gap, rotated_corners


def _shapely_gap(a: np.ndarray, b: np.ndarray) -> float:
    return float(shapely.distance(shapely.Polygon(a), shapely.Polygon(b)))


def _random_boxes(rng: np.random.Generator, k: int, spread: float) -> np.ndarray:
    """``k`` rectangles ``(k, 4, 2)`` [m]: car-sized to building-sized, any heading."""
    centres = rng.uniform(-spread, spread, (k, 2))
    half = rng.uniform(0.1, 3.0, (k, 2))
    return np.stack([box_corners(c, h, hh) for c, h, hh in zip(centres, rng.uniform(-4, 4, k), half,
                                                                 strict=True)])


def _random_quads(rng: np.random.Generator, k: int, spread: float) -> np.ndarray:
    """``k`` convex quadrilaterals ``(k, 4, 2)`` [m]: four points on an ellipse in order."""
    angles = np.sort(rng.uniform(0.0, 2 * np.pi, (k, 4)), axis=1)
    radii = rng.uniform(0.3, 3.0, (k, 1, 2))
    quads = np.stack([np.cos(angles), np.sin(angles)], axis=-1) * radii
    return quads + rng.uniform(-spread, spread, (k, 1, 2))


@pytest.mark.parametrize("spread", [1.0, 4.0, 30.0])  # mostly overlapping, mixed, mostly far apart
def test_box_gap_is_shapely_distance_for_random_boxes(spread: float):
    rng = np.random.default_rng(int(spread * 10))
    a, b = _random_boxes(rng, 2000, spread), _random_boxes(rng, 2000, spread)
    gaps = np.array([box_gap(p, q) for p, q in zip(a, b, strict=True)])
    want = np.array([_shapely_gap(p, q) for p, q in zip(a, b, strict=True)])
    np.testing.assert_allclose(gaps, want, rtol=0, atol=1e-9)
    assert (gaps == 0).any() or spread > 10  # the overlapping case is exercised
    assert (gaps > 0).any()


def test_box_gap_is_shapely_distance_for_convex_quads_either_way_round():
    rng = np.random.default_rng(3)
    a, b = _random_quads(rng, 2000, 4.0), _random_quads(rng, 2000, 4.0)
    for p, q in zip(a, b, strict=True):
        want = _shapely_gap(p, q)
        for pp, qq in ((p, q), (p[::-1], q), (q, p[::-1]), (p[::-1], q[::-1])):
            assert box_gap(pp, qq) == pytest.approx(want, abs=1e-9)


def test_box_gap_of_touching_nested_and_nearly_touching_boxes():
    unit = box_corners(np.array([0.0, 0.0]), 0.0, np.array([1.0, 0.5]))  # [-1, 1] x [-0.5, 0.5]
    cases = {
        "shared edge": box_corners(np.array([2.0, 0.0]), 0.0, np.array([1.0, 0.5])),
        "shared corner": box_corners(np.array([2.0, 1.0]), 0.0, np.array([1.0, 0.5])),
        "corner on an edge": box_corners(np.array([1.0 + math.sqrt(0.5), 0.0]), math.pi / 4, np.array([0.5, 0.5])),
        "inside": box_corners(np.array([0.1, 0.0]), 0.3, np.array([0.2, 0.1])),
        "around": box_corners(np.array([0.0, 0.0]), 0.0, np.array([5.0, 5.0])),
        "1 nm apart": box_corners(np.array([2.0 + 1e-9, 0.0]), 0.0, np.array([1.0, 0.5])),
        "rotated, off a corner": box_corners(np.array([3.0, 2.0]), math.pi / 4, np.array([math.sqrt(2.0), 0.1])),
    }
    for what, other in cases.items():
        want = _shapely_gap(unit, other)
        assert box_gap(unit, other) == pytest.approx(want, abs=1e-12), what
        assert box_gap(other, unit) == pytest.approx(want, abs=1e-12), what
    assert box_gap(unit, cases["shared edge"]) == 0.0
    assert box_gap(unit, cases["inside"]) == 0.0 and box_gap(unit, cases["around"]) == 0.0
    assert box_gap(unit, unit + np.array([0.0, 3.0])) == pytest.approx(2.0, abs=1e-15)


def test_box_gap_takes_corner_lists():
    a = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]
    b = [(4.0, 5.0), (5.0, 5.0), (5.0, 6.0), (4.0, 6.0)]
    assert box_gap(a, b) == pytest.approx(5.0, abs=1e-15)
    assert isinstance(box_gap(a, b), float)


def test_one_box_twins_give_the_vectorised_values_exactly():
    rng = np.random.default_rng(5)
    lane = OrientedBox(np.array([3.0, -1.0]), 0.4, np.array([6.0, 1.75]))
    route = Polyline(np.array([[0.0, 0.0], [10.0, 0.0], [14.0, 3.0], [14.0, 20.0]]))
    for _ in range(500):
        cx, cy, heading = rng.uniform(-10, 10), rng.uniform(-10, 10), rng.uniform(-7, 7)
        half = rng.uniform(0.1, 3.0, 2)
        c, s = math.cos(heading), math.sin(heading)
        one = box_corners_one(cx, cy, c, s, float(half[0]), float(half[1]))
        want = rotated_corners(np.float64(cx), np.float64(cy), np.cos(heading), np.sin(heading), half)
        assert np.array_equal(np.array(one), want)
        assert lane.contains_any(one) == bool(lane.contains(want).any())
        s_one, lat_one = route.project_point(cx, cy)
        s_vec, lat_vec = route.project(np.array([cx, cy]))
        assert (s_one, lat_one) == (float(s_vec), float(lat_vec))
    assert lane.contains_any([(100.0, 0.0), (3.0, -1.0)]) and not lane.contains_any([(100.0, 0.0), (-100.0, 0.0)])
    corners = [tuple(p) for p in lane.corners().tolist()]  # on the boundary, up to rounding
    assert lane.contains_any(corners) == bool(lane.contains(np.array(corners)).any())
    np.testing.assert_equal(route.project_point(math.nan, 0.0),
                            tuple(float(v) for v in route.project(np.array([math.nan, 0.0]))))
