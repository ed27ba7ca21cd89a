"""cdf_mj.viz.render: offscreen videos of episodes with the CDF's belief drawn in.

Tests that draw need an OpenGL backend (EGL or OSMesa); they are skipped, with the
reason, only when none can be created. Requests are checked before any simulation. The
parts have their own tests: test_sim_gl (backend), test_viz_replay, test_viz_overlays,
test_viz_panel, test_viz_encoding.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cdf_mj.cli import main
from cdf_mj.config import ScenarioConfig
from cdf_mj.viz import render, replay
from cdf_mj.viz.render import (
    DEFAULT_SEED,
    RenderError,
    check_request,
    frame_times,
    parse_planners,
    render_compare,
    render_episode,
)

iio = pytest.importorskip("imageio.v3", reason="the viz extra (imageio) is not installed")

SHORT = ScenarioConfig(timing={"duration": 1.0})  # 10 ticks: frames 0.0, 0.1, ..., 1.0 s at 10 fps
SMALL = {"width": 160, "height": 120}



def _magenta(img: np.ndarray) -> np.ndarray:
    """Pixels of the P(left) / left-turner particle colour (magenta)."""
    r, g, b = (img[..., i].astype(int) for i in range(3))
    return (r > 200) & (g < 90) & (b > 200)


# ----------------------------------------------------------------- no GL needed
def test_frame_times_constant_rate_in_simulated_time() -> None:
    t = frame_times(1.0, 10)
    assert len(t) == 11 and t[0] == 0.0 and t[-1] == pytest.approx(1.0)
    np.testing.assert_allclose(np.diff(t), 0.1)
    assert len(frame_times(5.3, 30)) == 160  # 0 .. 5.3 s, last frame at 159/30 = 5.2967 s


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"camera": "bird"}, "unknown camera 'bird': choose one of top, ego_chase, obstacle_chase"),
    ({"width": 161}, "must be even"),
    ({"height": 0}, "must be a positive integer"),
    ({"width": 10000}, "above the largest offscreen buffer"),
    ({"width": 16}, "below the smallest frame this draws (32 px)"),
    ({"out": "x.gif", "fps": 25, "height": 31}, "below the smallest frame"),
    ({"out": "nowhere/x.mp4"}, "does not exist"),
    ({"out": "."}, "unknown format"),
    ({"out": "x.avi"}, "unknown format"),
    ({"out": "x.png"}, "--frame"),
    ({"out": "x.gif", "fps": 30}, "GIF frame delays"),
    ({"fps": 0}, "between 1 and 240"),
    ({"layout": "beside"}, "--layout 'beside': choose one of overlay, side"),
    ({"layout": "side", "height": 120}, "--layout side needs at least 160 px"),
])
def test_bad_input_refused_before_any_work(scene, tmp_path, monkeypatch, kwargs, message) -> None:
    def no_work(*args, **kw):
        raise AssertionError("simulated before the request was checked")

    monkeypatch.setattr(render, "record_episode", no_work)
    monkeypatch.setattr(replay, "run_episode", no_work)
    monkeypatch.chdir(tmp_path)
    kwargs = {"out": "x.mp4", **kwargs}
    with pytest.raises(RenderError, match=message.replace("(", r"\(").replace(")", r"\)")):
        render_episode(kwargs.pop("out"), seed=1, scene=scene, **kwargs)


def test_output_directory_is_refused(scene, tmp_path) -> None:
    (tmp_path / "d.mp4").mkdir()
    with pytest.raises(RenderError, match="is a directory"):
        check_request(tmp_path / "d.mp4", scene.model)


def test_cli_bad_camera_is_one_line(tmp_path, capsys) -> None:
    status = main(["render", "--seed", "1", "--camera", "bird", "--out", str(tmp_path / "e.mp4")])
    err = capsys.readouterr().err
    assert status == 2
    assert err.count("\n") == 1 and err.startswith("cdf-mj: error: unknown camera 'bird'")
    assert not (tmp_path / "e.mp4").exists()


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux's /proc")
def test_an_output_no_one_can_write_is_refused_before_any_work(scene) -> None:
    # Permissions alone would pass it for root; opening it does not.
    with pytest.raises(RenderError, match="not writable"):
        render.check_request("/proc/cdf_mj_test.mp4", scene.model)


def test_odd_sizes_are_fine_for_png_and_gif(scene, tmp_path) -> None:
    req = render.check_request(tmp_path / "x.gif", scene.model, width=161, height=121, fps=25)
    assert (req.width, req.height) == (161, 121) and not (tmp_path / "x.gif").exists()


def test_a_broken_mujoco_gl_is_one_line_before_anything(tmp_path) -> None:
    env = {**os.environ, "MUJOCO_GL": "nonesuch"}
    out = subprocess.run([sys.executable, "-m", "cdf_mj", "episode"], env=env, capture_output=True,
                         text=True, timeout=60, check=False)
    assert out.returncode == 2 and out.stdout == ""
    assert out.stderr.startswith("cdf-mj: error: MuJoCo cannot load the OpenGL backend MUJOCO_GL=nonesuch")
    assert out.stderr.count("\n") == 1


# ----------------------------------------------------------------- drawing
def test_short_video_has_every_frame_and_they_move(backend, scene, tmp_path) -> None:
    out = tmp_path / "short.mp4"
    res = render_episode(out, seed=1, planner="cdf", config=SHORT, scene=scene, fps=10,
                         camera="top", **SMALL)  # a fixed camera: every frame's change is the cars'
    assert res.n_frames == 11 == len(frame_times(res.record.end_time, 10))
    frames = np.stack(list(iio.imiter(out)))
    assert frames.shape == (11, 120, 160, 3)
    assert all(f.std() > 10 for f in frames)  # not blank
    view = frames[:, 50:].astype(float)  # below the panel: the scene itself
    assert np.abs(view[-1] - view[0]).mean() > 1.0  # the ego drove ~13 m
    assert all(np.abs(view[i + 1] - view[i]).mean() > 0.05 for i in range(10))  # no repeated frame


def test_gif_has_every_frame(backend, scene, tmp_path) -> None:
    out = tmp_path / "short.gif"
    res = render_episode(out, seed=1, planner="reactive", config=SHORT.replace(timing={"duration": 0.5}),
                         scene=scene, fps=10, **SMALL)
    frames = iio.imread(out, index=None)
    assert len(frames) == res.n_frames == 6


def test_overlay_is_visible(backend, scene, tmp_path) -> None:
    """P(left) bar and the left-turner particles are magenta; without overlays there is none."""
    kw = {"seed": 1, "planner": "cdf", "config": SHORT, "scene": scene, "camera": "obstacle_chase",
          "frame_time": 0.5, **SMALL}
    render_episode(tmp_path / "on.png", **kw)
    render_episode(tmp_path / "off.png", overlays=False, **kw)
    on, off = iio.imread(tmp_path / "on.png"), iio.imread(tmp_path / "off.png")
    assert on.shape == (120, 160, 3)
    assert _magenta(off).sum() == 0
    assert _magenta(on[:44, :61]).sum() > 20  # the panel's P(left) bar (P(left) ~ 0.75 at 0.5 s)
    assert _magenta(on[50:]).sum() > 3  # particles over the obstacle, below the panel
    assert np.abs(on[50:].astype(int) - off[50:]).mean() > 1.0  # the isovist tints the road


def test_cli_renders_a_frame(backend, tmp_path, capsys) -> None:
    out = tmp_path / "frame.png"
    status = main(["render", "--seed", "1", "--frame", "0.3", "--out", str(out), "--width", "96",
                   "--height", "64", "--set", "timing.duration=1.0", "--particles", "200"])
    assert status == 0, capsys.readouterr().err
    assert iio.imread(out).shape == (64, 96, 3)
    assert "wrote" in capsys.readouterr().out


def test_frame_wider_than_the_models_buffer(backend, scene, tmp_path) -> None:
    """The offscreen buffer is enlarged for the render context, and the model left as it was."""
    offwidth = scene.model.vis.global_.offwidth
    out = tmp_path / "wide.png"
    render_episode(out, seed=1, config=SHORT, scene=scene, frame_time=0.0, width=offwidth + 320,
                   height=96)
    assert iio.imread(out).shape == (96, offwidth + 320, 3)
    assert scene.model.vis.global_.offwidth == offwidth


def test_a_failed_render_leaves_the_earlier_file(backend, scene, tmp_path, monkeypatch) -> None:
    out = tmp_path / "v.mp4"
    out.write_bytes(b"the earlier video")
    frame, calls = render._Painter.frame, []

    def fails_on_the_third(self, t):
        calls.append(t)
        if len(calls) == 3:
            raise RuntimeError("the third frame failed")
        return frame(self, t)

    monkeypatch.setattr(render._Painter, "frame", fails_on_the_third)
    with pytest.raises(RuntimeError, match="third frame"):
        render_episode(out, seed=1, config=SHORT, scene=scene, fps=10, **SMALL)
    assert out.read_bytes() == b"the earlier video"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.mp4"]  # no temporary file left


# ----------------------------------------------------------------- defaults, --frame, layouts
def test_the_default_seed_is_a_cut_off_the_cdf_acts_on(scene) -> None:
    """The reason render's default seed differs from episode's (seed 0, reactive)."""
    from cdf_mj.scenario.episode import run_episode

    rec = run_episode(ScenarioConfig(), DEFAULT_SEED, "cdf", scene)
    assert rec.label == "Cutoff" and rec.planner_info["prediction"] == "Cutoff" and not rec.collision
    args = cli_parser().parse_args(["render", "--out", "x.mp4"])
    assert args.seed is None and args.planner is None  # resolved to DEFAULT_SEED and cdf


def cli_parser():
    from cdf_mj.cli import build_parser

    return build_parser()


@pytest.mark.parametrize(("text", "message"), [
    ("cdf", "give 2 to 6 planners"),
    ("cdf,cdf", "planner 'cdf' given twice"),
    ("cdf,bogus", "unknown planner 'bogus'; choose from"),
])
def test_bad_compare_lists_are_one_line(text, message) -> None:
    with pytest.raises(RenderError, match=message):
        parse_planners(text)


def test_compare_and_planner_together_is_an_error(tmp_path, capsys) -> None:
    status = main(["render", "--compare", "cdf,imm", "--planner", "cdf", "--out", str(tmp_path / "c.mp4")])
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1 and "--planner: not used with --compare" in err


def test_a_frame_past_the_end_is_one_line_naming_the_end(backend, tmp_path, capsys) -> None:
    out = tmp_path / "late.png"
    status = main(["render", "--seed", "1", "--frame", "20", "--out", str(out), "--width", "96",
                   "--height", "64", "--set", "timing.duration=1.0", "--particles", "200"])
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1
    assert "--frame 20" in err and "1.00 s" in err
    assert not out.exists()


def test_side_layout_puts_the_charts_beside_the_view(backend, scene, tmp_path) -> None:
    kw = {"seed": 1, "planner": "cdf", "config": SHORT, "scene": scene, "frame_time": 0.8,
          "width": 160, "height": 160}
    render_episode(tmp_path / "side.png", layout="side", **kw)
    render_episode(tmp_path / "over.png", **kw)
    side, over = iio.imread(tmp_path / "side.png"), iio.imread(tmp_path / "over.png")
    assert side.shape == (160, 160 + 120, 3) and over.shape == (160, 160, 3)
    assert _magenta(side[:, 160:]).sum() > 20  # the P(left) curve and its legend, in the panel
    assert _magenta(side[:60, :60]).sum() == 0 < _magenta(over[:60, :60]).sum()  # no overlay panel


def test_compare_tiles_same_times_and_the_shorter_holds_its_last_frame(backend, scene, tmp_path,
                                                                       monkeypatch) -> None:
    """Seed 1 to 4 s: the constant-speed ego (no following) hits the obstacle at 3.66 s and
    its episode ends; cdf and imm run to 4 s. Three tiles, 21 frames at 5 fps, captions written."""
    calls: dict[str, list[float]] = {}
    frame = render._Painter.frame

    def spy(self, t):
        calls.setdefault(self.replay.record.planner, []).append(t)
        return frame(self, t)

    monkeypatch.setattr(render._Painter, "frame", spy)
    out = tmp_path / "compare.mp4"
    config = ScenarioConfig(timing={"duration": 4.0}, ego={"follow": False})
    res = render_compare(out, seed=1, planners="cdf,imm,constant", config=config, scene=scene, fps=5, **SMALL)
    ends = {r.planner: r.end_time for r in res.records}
    assert ends["constant"] < 3.8 and ends["cdf"] == ends["imm"] == pytest.approx(4.0)
    assert res.n_frames == len(frame_times(4.0, 5)) == 21 and res.tile_width == 160
    frames = np.stack(list(iio.imiter(out)))
    assert frames.shape == (21, 120, 3 * 160, 3)
    assert [p for p, _ in sorted(calls.items())] == ["cdf", "constant", "imm"]
    assert all(len(ts) == 21 for ts in calls.values())
    np.testing.assert_allclose(calls["cdf"], frame_times(4.0, 5))
    assert max(calls["constant"]) == pytest.approx(ends["constant"])  # held after its end
    assert calls["constant"][-2:] == [ends["constant"]] * 2
    for i in range(3):  # each tile's caption: white text on a dark strip at its bottom-left
        strip = frames[-1, 110:, i * 160:i * 160 + 80].astype(int)
        assert (strip.min(axis=-1) > 200).sum() > 10, i


def test_episode_options_with_a_trace_are_refused(tmp_path, capsys) -> None:
    status = main(["render", "--trace", str(tmp_path / "t.jsonl"), "--seed", "3", "--layout", "side",
                   "--out", str(tmp_path / "t.mp4")])
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1
    assert "--layout, --seed: not used with --trace" in err
