"""The video panel's command chart (cdf_mj.viz.command_chart, drawn by cdf_mj.viz.panel and
cdf_mj.viz.render): the planner's command beside the ego's own controller's acceleration,
the intervening ticks shaded and the hard-brake ticks marked, where the trace says.

Pixels are checked against the chart's box and value range alone (t = 0 .. end left to
right, ``lo`` .. ``hi`` bottom to top), never against the drawing code's own mapping."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from cdf_mj.config import ScenarioConfig
from cdf_mj.viz.replay import CONTROL_KEYS, Replay, control_of, record_episode

pytest.importorskip("PIL", reason="the viz extra (pillow) is not installed")
from cdf_mj.viz.command_chart import COMMAND_COLORS, CommandChart
from cdf_mj.viz.panel import Panel, SidePanel, side_width

CONFIG = ScenarioConfig(timing={"duration": 4.0})  # seed 1: reactive brakes hard at 2.0 s
CW, CH, FONT = 420, 170, 12  # the chart: about 8 px per 0.1 s tick
SHADE, RED = COMMAND_COLORS["intervening"], COMMAND_COLORS["hard brake"]


@pytest.fixture(scope="module")
def reactive(scene) -> Replay:
    return record_episode(1, "reactive", CONFIG, scene, label=False)


@pytest.fixture(scope="module")
def constant(scene) -> Replay:
    return record_episode(1, "constant", CONFIG, scene, label=False)


@pytest.fixture(scope="module")
def cdf(scene) -> Replay:
    return record_episode(1, "cdf", CONFIG, scene, label=False)


def _is(img: np.ndarray, rgb) -> np.ndarray:
    return np.all(np.abs(img.astype(int) - np.asarray(rgb, dtype=int)) <= 3, axis=-1)


def _column(chart: CommandChart, t: float) -> int:
    x0, _y0, x1, _y1 = chart.box
    return round(x0 + t / chart.end * (x1 - x0))


def _marked(chart: CommandChart, img: np.ndarray, times: np.ndarray, rgb, rows: slice) -> np.ndarray:
    """Per tick, whether the column in its middle holds ``rgb`` on most of ``rows``."""
    out = []
    for ta, tb in itertools.pairwise(times):
        col = img[rows, _column(chart, 0.5 * (ta + tb))]
        out.append(_is(col, rgb).mean() > 0.5)
    return np.array(out)


def test_the_control_is_the_traces(reactive) -> None:
    tr = reactive.record.trace
    c = reactive.control
    assert c is not None and len(c.own) == len(reactive.times) - 1
    np.testing.assert_array_equal(c.command, tr["command"])
    np.testing.assert_array_equal(c.own, tr["own"])
    np.testing.assert_array_equal(c.intervening, tr["intervening"])
    np.testing.assert_array_equal(c.brake, tr["brake"])
    assert np.isfinite(c.command).all()


@pytest.mark.parametrize("name", ["reactive", "cdf", "constant"])
def test_intervening_ticks_are_shaded_exactly_where_the_trace_says(name, request) -> None:
    rep: Replay = request.getfixturevalue(name)
    chart = CommandChart(rep, CW, CH, FONT)
    img = chart.draw(rep.end_time)
    _x0, y0, _x1, y1 = chart.box
    shaded = _marked(chart, img, rep.times, SHADE, slice(y0 + chart.band + 1, y1))
    want = np.array((rep.record.trace or {})["intervening"], dtype=np.bool_)
    np.testing.assert_array_equal(shaded, want)
    if name == "constant":
        assert not want.any() and not _is(img, SHADE)[y0:y1].any()
    else:  # reactive from its brake on; cdf while it slows the ego
        assert want.sum() >= 10


def test_hard_brake_ticks_are_a_red_band_along_the_top(reactive, cdf) -> None:
    for rep in (reactive, cdf):
        chart = CommandChart(rep, CW, CH, FONT)
        img = chart.draw(rep.end_time)
        _x0, y0, _x1, _y1 = chart.box
        band = _marked(chart, img, rep.times, RED, slice(y0, y0 + chart.band))
        np.testing.assert_array_equal(band, rep.record.trace["brake"])
    assert np.asarray(reactive.record.trace["brake"]).any()  # something to see


def test_both_curves_land_at_their_values(reactive, cdf) -> None:
    """Each tick's command and own acceleration at their pixel (within 2 px), except where
    the command (drawn last) passes within 3 px of the own controller's."""
    for rep in (reactive, cdf):
        chart = CommandChart(rep, CW, CH, FONT)
        img = chart.draw(rep.end_time)
        c = rep.control
        assert chart.lo <= min(c.command.min(), c.own.min(), 0.0) and chart.hi >= max(c.command.max(), c.own.max())
        _x0, y0, _x1, y1 = chart.box

        def y_of(v: float, box=(y0, y1), lo=chart.lo, hi=chart.hi) -> int:
            return round(box[1] - (v - lo) / (hi - lo) * (box[1] - box[0]))

        checked = 0
        for k, t in enumerate(rep.times[:-1]):
            x = _column(chart, t)
            for key, v, other in (("command", c.command[k], None), ("own controller", c.own[k], c.command[k])):
                y = y_of(v)
                if other is not None and abs(y_of(other) - y) <= 3:
                    continue
                win = img[max(0, y - 2):y + 3, max(0, x - 2):x + 3]
                assert _is(win, COMMAND_COLORS[key]).any(), (key, t, v)
                checked += 1
        assert checked >= len(rep.times) - 1


def test_the_chart_reveals_up_to_the_time_and_writes_its_values(reactive) -> None:
    chart = CommandChart(reactive, CW, CH, FONT)
    first = reactive.times[np.argmax(reactive.control.intervening)]
    before, after = chart.draw(first - 0.2), chart.draw(first + 0.5)
    _x0, y0, _x1, y1 = chart.box
    assert not _is(before[y0:y1], SHADE).any() and _is(after[y0:y1], SHADE).sum() > 50
    assert not _is(before[y0:y1], RED).any() and _is(after[y0:y1], RED).any()
    legend = slice(0, y0 - 2)  # the values at the frame's time differ: the legend changes
    assert not np.array_equal(before[legend], after[legend])


def test_the_panel_draws_the_chart_at_the_bottom_left_above_a_caption(cdf) -> None:
    w, h, caption = 640, 480, 30
    panel = Panel(cdf, w, h, "cdf", bottom=caption)
    img = panel.draw(np.zeros((h, w, 3), dtype=np.uint8), 2.0)
    chart = panel.chart
    assert chart is not None and panel.chart_y + chart.h == h - caption and panel.chart_y >= panel.h
    covered = np.zeros((h, w), dtype=bool)
    covered[:panel.h, :panel.w] = True
    covered[panel.chart_y:h - caption, :chart.w] = True
    assert img[covered].any() and not img[~covered].any()
    shade = (Panel.ALPHA * np.asarray(SHADE)).astype(int)
    assert _is(img[panel.chart_y:], shade).sum() > 100  # cdf slows the ego early on seed 1
    # The side layout's view: the chart alone.
    alone = panel.draw_chart(np.zeros((h, w, 3), dtype=np.uint8), 2.0)
    assert not alone[:panel.chart_y].any() and alone[panel.chart_y:h - caption, :chart.w].any()


def test_a_trace_without_commands_renders_as_before(cdf) -> None:
    old = dataclasses.replace(cdf.record, trace={k: v for k, v in cdf.record.trace.items()
                                                 if k not in CONTROL_KEYS})
    rep = dataclasses.replace(cdf, record=old)
    assert rep.control is None
    panel = Panel(rep, 320, 240, "cdf")
    img = panel.draw(np.zeros((240, 320, 3), dtype=np.uint8), 1.0)
    assert panel.chart is None and img[:panel.h, :panel.w].any() and not img[panel.h:].any()
    assert SidePanel(rep, side_width(240), 240, "cdf").draw(1.0).shape == (240, side_width(240), 3)
    with pytest.raises(ValueError, match="no planner command to chart"):
        CommandChart(rep, CW, CH, FONT)


def test_a_damaged_control_trace_is_one_line(cdf) -> None:
    trace = dict(cdf.record.trace)
    trace["own"] = trace["own"][:-1]
    with pytest.raises(ValueError, match=r"trace 'own': \d+ values for \d+ ticks"):
        control_of(trace)
    trace = {**cdf.record.trace, "command": ["fast"] * len(cdf.record.trace["t"])}
    with pytest.raises(ValueError, match="trace 'command': not a list of floats"):
        control_of(trace)
    with pytest.raises(ValueError, match="at least 80 x 60"):
        CommandChart(cdf, 60, 60, FONT)


def _blended(img: np.ndarray, rgb) -> np.ndarray:
    """Pixels of ``rgb`` drawn at the panel's opacity over any scene colour."""
    want, slack = Panel.ALPHA * np.asarray(rgb, dtype=float), (1.0 - Panel.ALPHA) * 255 + 3
    diff = img.astype(float) - want
    return np.all((diff >= -3) & (diff <= slack), axis=-1)


def test_the_side_layout_and_compare_draw_the_chart_over_the_view(backend, scene, tmp_path) -> None:
    iio = pytest.importorskip("imageio.v3", reason="the viz extra (imageio) is not installed")
    from cdf_mj.viz.render import render_compare, render_episode

    kw = {"seed": 1, "config": CONFIG, "scene": scene, "width": 320, "height": 240}
    corner = (slice(round(0.68 * 240), 240), slice(0, round(0.55 * 320)))  # the view's bottom-left
    red = []
    for t in (1.0, 3.0):  # reactive brakes hard from 2.0 s
        render_episode(tmp_path / "side.png", planner="reactive", layout="side", frame_time=t, **kw)
        side = iio.imread(tmp_path / "side.png")
        assert side.shape == (240, 320 + side_width(240), 3)
        red.append(int(_blended(side[corner], RED).sum()))
    assert red[1] > red[0] + 20  # the hard-brake band once it happened (the legend's swatch at both)
    render_compare(tmp_path / "cmp.png", planners="cdf,reactive", frame_time=3.0, **kw)
    both = iio.imread(tmp_path / "cmp.png")
    assert both.shape == (240, 640, 3)
    for i in range(2):  # each tile: the shaded ticks above its caption (the bottom 15 px)
        tile = both[:, i * 320:(i + 1) * 320]
        assert _blended(tile[corner[0].start:225, corner[1]], SHADE).sum() > 20, i
