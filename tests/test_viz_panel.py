"""cdf_mj.viz.panel: the posterior panel over the view and the side panel's time series,
drawn with NumPy and Pillow (no OpenGL)."""

from __future__ import annotations

import numpy as np
import pytest

from cdf_mj.config import ScenarioConfig
from cdf_mj.viz.replay import record_episode

pytest.importorskip("PIL", reason="the viz extra (pillow) is not installed")
from cdf_mj.viz.overlays import OVERLAY_COLORS
from cdf_mj.viz.panel import Panel, SidePanel, particle_legend, side_width

CONFIG = ScenarioConfig(timing={"duration": 2.0})
W, H = 320, 240


@pytest.fixture(scope="module")
def cdf_replay(scene):
    return record_episode(1, "cdf-threshold", CONFIG, scene, label=False)  # brakes within the clip


def _draw(panel: Panel, t: float) -> np.ndarray:
    return panel.draw(np.zeros((H, W, 3), dtype=np.uint8), t)


def _bar(panel: Panel, img: np.ndarray, row: int) -> int:
    """Filled length [px] of the bar on panel row ``row``: the pixels of its first pixel's
    colour (the ``tau`` mark on the last bar is one pixel of another)."""
    y = panel.rows[row]
    line = img[y, panel.bar_x0:panel.bar_x1].astype(int)
    return int(np.all(np.abs(line - line[0]) < 4, axis=1).sum())


def test_the_panel_covers_only_the_top_left_and_its_command_chart_the_bottom_left(cdf_replay) -> None:
    panel = Panel(cdf_replay, W, H, "cdf")
    img = _draw(panel, 0.5)
    assert (panel.w, panel.h) == (round(0.38 * W), round(0.36 * H))
    assert panel.chart is not None and (panel.chart.w, panel.chart.h) == (round(0.55 * W), round(0.32 * H))
    chart = np.zeros((H, W), dtype=bool)
    chart[H - panel.chart.h:, :panel.chart.w] = True
    assert img[:panel.h, :panel.w].any() and img[chart].any()
    assert not img[panel.h:][~chart[panel.h:]].any() and not img[:panel.h, panel.w:].any()


def test_bars_show_the_probabilities_of_the_tick(cdf_replay) -> None:
    panel = Panel(cdf_replay, W, H, "cdf")
    assert panel.keys == ("p_left", "p_seen", "p_cutoff")
    span = panel.bar_x1 - panel.bar_x0
    for t in (0.3, 1.2):
        img = _draw(panel, t)
        k = cdf_replay.tick(t)
        for i, key in enumerate(panel.keys):
            p = cdf_replay.posterior[key][k]
            assert abs(_bar(panel, img, 2 + i) - round(p * span)) <= 1, (t, key)


def test_brake_appears_when_the_ego_brakes(cdf_replay) -> None:
    panel = Panel(cdf_replay, W, H, "cdf")
    y, x = panel.rows[1], panel.w - 4
    brake = cdf_replay.record.brake_time
    assert brake is not None
    before, after = _draw(panel, brake - 0.1)[y, x], _draw(panel, brake)[y, x]
    assert after[0] > 150 and after[1] < 40 and not (before[0] > 150 and before[1] < 40)


def test_a_planner_without_probabilities_gets_no_bars(scene) -> None:
    rep = record_episode(1, "reactive", CONFIG, scene, label=False)
    panel = Panel(rep, W, H, "reactive")
    img = _draw(panel, 1.0)
    assert panel.keys == () and panel.curves is None
    assert _bar(panel, img, 3) == panel.bar_x1 - panel.bar_x0  # an empty row: one colour


# ----------------------------------------------------------------- legend in words
def _particle_pixels(img: np.ndarray, alpha: float = 1.0) -> int:
    """Pixels of the particle colours that no curve uses (the legend's swatches), drawn at
    opacity ``alpha`` over black."""
    curves = {tuple(int(v * 255) for v in c[:3]) for c in OVERLAY_COLORS.values()}
    count = 0
    for rgb, _words in particle_legend():
        if rgb in curves:
            continue
        want = (alpha * np.asarray(rgb)).astype(int)
        count += int(np.all(np.abs(img.astype(int) - want) <= 2, axis=-1).sum())
    return count


def test_the_particle_legend_is_in_words_and_only_for_particles(cdf_replay, scene) -> None:
    words = [w for _rgb, w in particle_legend()]
    assert sorted(words) == ["left", "left, saw ego", "right", "right, saw ego"]
    cdf = Panel(cdf_replay, W, H, "cdf")
    assert _particle_pixels(_draw(cdf, 0.5)[cdf.rows[8] - 3:], Panel.ALPHA) > 8  # the swatches
    imm = Panel(record_episode(1, "imm", CONFIG, scene, label=False), W, H, "imm")
    assert imm.legend == [] and _particle_pixels(_draw(imm, 0.5), Panel.ALPHA) == 0


# ----------------------------------------------------------------- the side panel
SIDE_H = 240


@pytest.fixture(scope="module")
def side(cdf_replay) -> SidePanel:
    return SidePanel(cdf_replay, side_width(SIDE_H), SIDE_H, "cdf")


def _has(img: np.ndarray, x: int, y: int, rgb, r: int = 2) -> bool:
    """Whether colour ``rgb`` is within ``r`` px of pixel (x, y)."""
    win = img[max(0, y - r):y + r + 1, max(0, x - r):x + r + 1].astype(int)
    return bool(np.any(np.all(np.abs(win - np.asarray(rgb, dtype=int)) <= 3, axis=-1)))


def _expected(box, t: float, v: float, end: float, top: float) -> tuple[int, int]:
    """The pixel of value ``v`` at time ``t`` from the chart's box alone: t = 0 .. end
    left to right, 0 .. top bottom to top."""
    x0, y0, x1, y1 = box
    return round(x0 + t / end * (x1 - x0)), round(y1 - v / top * (y1 - y0))


def _check_curves(img, box, times, series: dict, colors: dict, end: float, top: float) -> int:
    """Every sample of every curve lands on its colour, except where a curve drawn later
    passes within 3 px; returns how many samples were checked."""
    checked = 0
    order = list(series)
    for i, key in enumerate(order):
        for k, t in enumerate(times):
            x, y = _expected(box, t, series[key][k], end, top)
            later = [series[o][k] for o in order[i + 1:]]
            if any(abs(_expected(box, t, v, end, top)[1] - y) <= 3 for v in later):
                continue
            assert _has(img, x, y, colors[key]), (key, t, series[key][k], (x, y))
            checked += 1
    return checked


def test_side_panel_probabilities_land_at_their_pixels(side, cdf_replay) -> None:
    img = side.draw(cdf_replay.end_time)
    assert img.shape == (SIDE_H, side_width(SIDE_H), 3)
    post = cdf_replay.posterior
    series = {k: post[k] for k in ("p_left", "p_seen", "p_cutoff")}
    colors = {k: tuple(int(v * 255) for v in OVERLAY_COLORS[k][:3]) for k in series}
    n = _check_curves(img, side.prob_box, post["t"], series, colors, cdf_replay.end_time, 1.0)
    assert n >= len(post["t"])  # most samples of the three curves were seen


def test_side_panel_speeds_land_at_their_pixels(side, cdf_replay) -> None:
    img = side.draw(cdf_replay.end_time)
    v = cdf_replay.poses[:, :, 3]
    series = {"ego": v[:, 0], "obstacle": v[:, 1]}
    colors = {"ego": (90, 190, 255), "obstacle": (255, 170, 60)}
    assert side.speed_max >= v.max() and side.speed_max <= 1.5 * v.max() + 1
    n = _check_curves(img, side.speed_box, cdf_replay.times, series, colors, cdf_replay.end_time,
                      side.speed_max)
    assert n >= len(cdf_replay.times)


def test_side_panel_reveals_up_to_the_time_and_marks_the_brake(side, cdf_replay) -> None:
    brake = cdf_replay.record.brake_time
    assert brake is not None and 0.3 < brake < cdf_replay.end_time - 0.3
    red = tuple(int(c * 255) for c in OVERLAY_COLORS["brake"][:3])
    bx = int(side.x_of(brake))
    _x0, y0, _x1, y1 = side.speed_box
    mid = (y0 + y1) // 2
    before, after = side.draw(brake - 0.2), side.draw(brake + 0.1)
    assert _has(after, bx, mid, red, r=0) and not _has(before, bx, mid, red, r=1)
    # Before the brake no curve is drawn right of the cursor.
    cx = int(side.x_of(brake - 0.2))
    _x0, py0, x1, py1 = side.prob_box
    right = before[py0:py1, cx + 2:x1 + 1].astype(int)
    magenta = np.all(np.abs(right - np.array([255, 25, 255])) <= 3, axis=-1)
    assert not magenta.any()


def test_side_panel_axes_have_tick_labels(side) -> None:
    img = side.draw(0.5)
    x0, _y0, _x1, _y1 = side.prob_box
    y_half = int(side.prob_y(0.5))
    label = img[y_half - 4:y_half + 5, side.pad:x0 - 6].astype(int)
    assert (label.max(axis=-1) > 60).sum() >= 4  # "0.5" written left of the axis
    below = img[side.row_ticks - 4:side.row_ticks + 5, x0 - 4:x0 + 5].astype(int)
    assert (below.max(axis=-1) > 60).sum() >= 2  # "0" under the time axis


def test_side_panel_of_a_planner_without_particles_or_probabilities(scene) -> None:
    rep = record_episode(1, "reactive", CONFIG, scene, label=False)
    panel = SidePanel(rep, side_width(SIDE_H), SIDE_H, "reactive")
    img = panel.draw(1.0)
    assert panel.prob_box is None and panel.legend == [] and _particle_pixels(img) == 0
    with pytest.raises(ValueError, match="no probabilities"):
        panel.prob_y(0.5)
    with pytest.raises(ValueError, match="at least 160 px"):
        SidePanel(rep, 120, 120, "reactive")
