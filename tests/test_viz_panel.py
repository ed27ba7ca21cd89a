"""cdf_mj.viz.panel: the posterior panel, drawn with NumPy and Pillow (no OpenGL)."""

from __future__ import annotations

import numpy as np
import pytest

from cdf_mj.config import ScenarioConfig
from cdf_mj.viz.replay import record_episode

pytest.importorskip("PIL", reason="the viz extra (pillow) is not installed")
from cdf_mj.viz.panel import Panel

CONFIG = ScenarioConfig(duration=2.0)
W, H = 320, 240


@pytest.fixture(scope="module")
def cdf_replay(scene):
    return record_episode(1, "cdf", CONFIG, scene, label=False)


def _draw(panel: Panel, t: float) -> np.ndarray:
    return panel.draw(np.zeros((H, W, 3), dtype=np.uint8), t)


def _bar(panel: Panel, img: np.ndarray, row: int) -> int:
    """Filled length [px] of the bar on panel row ``row``: the pixels of its first pixel's
    colour (the ``tau`` mark on the last bar is one pixel of another)."""
    y = panel.rows[row]
    line = img[y, panel.bar_x0:panel.bar_x1].astype(int)
    return int(np.all(np.abs(line - line[0]) < 4, axis=1).sum())


def test_the_panel_covers_only_the_top_left(cdf_replay) -> None:
    panel = Panel(cdf_replay, W, H, "cdf")
    img = _draw(panel, 0.5)
    assert (panel.w, panel.h) == (round(0.38 * W), round(0.36 * H))
    assert img[:panel.h, :panel.w].any() and not img[panel.h:].any() and not img[:, panel.w:].any()


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
