"""The CDF monitor on poses: observe(t, ego, obstacle) from a Layout alone (no MuJoCo), its
bad-input errors, attach and step on our junction variants with mocap cars that wait and
then cut across or turn away, the trace file and its render."""

from __future__ import annotations

import json
import math
import os
import pickle
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
from cars import add_mocap_car, set_mocap_pose
from junctions import build_junction

from cdf_mj.config import SceneNames
from cdf_mj.model.layout import Layout
from cdf_mj.model.vehicle import CarGeometry
from cdf_mj.scenario.monitor import CDFMonitor, TraceError, TrackedCar, attach, read_trace
from cdf_mj.sim.scene import Scene

OWN_NAMES = SceneNames(ego_prefix="av/", obstacle_prefix="other/", route_ego="av_path",
                       route_left="cross_path", route_right="away_path", conflict="crossing",
                       building_prefix="house")


def _poses(layout: Layout, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Tick ``k``: the ego at 13.4 m/s from its start, the obstacle waiting at its start."""
    ego = layout.route_ego.point_at(layout.route_ego.project(layout.ego_start[None, :2])[0][0] + 1.34 * k)
    return np.array([ego[0], ego[1], layout.ego_start[2], 13.4]), layout.obstacle_start.copy()


def test_observe_refuses_bad_input_with_one_line(scene: Scene):
    layout = scene.layout()
    monitor = CDFMonitor(layout, rng=0)
    ego, obs = _poses(layout, 0)
    for bad, fragment in (([1.0, 2.0, 3.0], "ego_pose must be 4 finite numbers"),
                          ([np.nan, 0, 0, 0], "ego_pose must be 4 finite numbers"),
                          ("abcd", "ego_pose must be 4 finite numbers")):
        with pytest.raises(ValueError, match=fragment):
            monitor.observe(0.0, bad, obs)
    with pytest.raises(ValueError, match="t must be a finite time"):
        monitor.observe(float("inf"), ego, obs)
    monitor.observe(0.0, ego, obs)
    with pytest.raises(ValueError, match="time went back"):
        monitor.observe(-0.1, ego, obs)
    with pytest.raises(ValueError, match=r"0\.09 s of simulated time since the last call; call it every dt=0\.1"):
        monitor.observe(0.09, ego, obs)  # a 0.03 s timestep: three steps are not a tick
    with pytest.raises(RuntimeError, match="observe"):
        monitor.step()
    assert len(monitor.trace) == 1  # nothing of the refused calls was kept
    monitor.observe(0.1, ego, obs)
    assert [row["t"] for row in monitor.trace] == [0.0, 0.1]


def test_a_missed_measurement_only_predicts_and_is_never_written_to_a_trace(scene: Scene):
    """Four NaN for the obstacle are a sensor's dropout: without a trace the filter skips its
    weighing (its posterior moves only by prediction, as the ``cdf`` planner's does); with a
    trace it is refused, since a trace file holds measured poses; half a NaN pose never passes."""
    layout = scene.layout()
    ego, obs = _poses(layout, 0)
    missing = [np.nan] * 4
    with pytest.raises(ValueError, match="obstacle_pose must be 4 finite numbers"):
        CDFMonitor(layout, rng=0).observe(0.0, ego, missing)  # a trace is kept by default
    dropped, measured = CDFMonitor(layout, rng=0, record_trace=False), CDFMonitor(layout, rng=0, record_trace=False)
    for m in (dropped, measured):
        m.observe(0.0, ego, obs)
    ego1, obs1 = _poses(layout, 1)
    with pytest.raises(ValueError, match="or 4 NaN"):
        dropped.observe(0.1, ego1, [np.nan, 0.0, 0.0, 0.0])
    d = dropped.observe(0.1, ego1, missing)
    assert np.isnan(d.poses[1]).all() and 0.0 <= d.posterior.p_cutoff <= 1.0
    assert measured.observe(0.1, ego1, obs1).posterior != d.posterior  # the measurement was not weighed in


def test_step_on_a_scene_equals_observe_on_its_poses(scene: Scene):
    layout = scene.layout()
    by_scene, by_poses = CDFMonitor(scene, rng=3), CDFMonitor(layout, rng=3)
    scene.reset(layout.ego_start + np.array([0, 0, 0, 13.4]), layout.obstacle_start)
    for _ in range(6):
        a = by_scene.step()
        b = by_poses.observe(float(scene.data.time), *scene.poses())
        assert a.posterior == b.posterior and a.brake == b.brake
        scene.step(20)


def test_a_layout_monitor_runs_without_mujoco(scene: Scene, tmp_path: Path):
    path = tmp_path / "layout.pickle"
    path.write_bytes(pickle.dumps(scene.layout()))
    code = f"""
import pickle, sys
sys.modules["mujoco"] = None  # any import of MuJoCo now fails
from cdf_mj.scenario.monitor import CDFMonitor
layout = pickle.loads(open({str(path)!r}, "rb").read())
monitor = CDFMonitor(layout, rng=0)
ego, obs = [-40.8, -1.85, 0.0, 13.4], list(layout.obstacle_start)
for k in range(5):
    ego[0] += 1.34
    d = monitor.observe(0.1 * k, ego, obs)
monitor.save_trace({str(tmp_path / "t.jsonl")!r})
print(round(d.t, 6), d.brake, [m for m in sys.modules if m.startswith("cdf_mj.sim")])
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                         env={**os.environ, "PYTHONPATH": str(Path(__file__).parents[1])})
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["0.4", "False", "[]"]


# ------------------------------------------------------------------ drivers that wait
def _wait_and_go(names: SceneNames, wait: float, intent: str, seed: int, **junction: object
                 ) -> tuple[float | None, float | None, CDFMonitor]:
    """Two mocap cars on a junction variant: the obstacle waits ``wait`` s at the stop line,
    then goes at 2.5 m/s^2 (up to 8 m/s) along its ``intent`` route; the ego holds
    13.4 m/s from where it reaches the conflict point as the obstacle gets there.
    Returns (brake time, time the obstacle enters the ego's lane, monitor)."""
    spec = build_junction(names=names, cars=False, **junction)  # type: ignore[arg-type]
    add_mocap_car(spec, "ego_car")
    add_mocap_car(spec, "obstacle_car")
    model = spec.compile()
    data = mujoco.MjData(model)
    ours = CarGeometry.ours()
    monitor = attach(model, data, names, rng=seed, ego=TrackedCar(body="ego_car", geometry=ours),
                     obstacle=TrackedCar(body="obstacle_car", geometry=ours))
    lay = monitor.layout
    route = lay.route_left if intent == "left" else lay.route_right
    s0 = float(route.project(lay.obstacle_start[None, :2])[0][0])
    s_conflict = float(lay.route_ego.project(lay.conflict[None])[0][0])
    ego_s0 = s_conflict - 13.4 * (wait + 2.4)  # about when a left-turner gets there
    s = v = 0.0
    entered = None
    nstep = round(0.1 / model.opt.timestep)
    for k in range(int((wait + 5.0) / 0.1)):
        t = 0.1 * k
        ego = lay.route_ego.point_at(ego_s0 + 13.4 * t)
        ahead = lay.route_ego.point_at(ego_s0 + 13.4 * t + 1.0)
        set_mocap_pose(model, data, "ego_car", ego[0], ego[1], math.atan2(*(ahead - ego)[::-1]))
        if t >= wait - 1e-9:
            v = min(v + 2.5 * 0.1, 8.0)
            s += v * 0.1
        p, q = route.point_at(s0 + s), route.point_at(s0 + s + 0.5)
        set_mocap_pose(model, data, "obstacle_car", p[0], p[1], math.atan2(*(q - p)[::-1]))
        decision = monitor.step()
        if entered is None and lay.ego_lane.contains(ours.footprint(decision.poses[1])).any():
            entered = t
        mujoco.mj_step(model, data, nstep=nstep)
    return monitor.brake_time, entered, monitor


VARIANTS = {
    "rotated, 3.2 m lanes, own names": {"rotation": 0.7, "lane_width": 3.2, "names": OWN_NAMES},
    "mirrored": {"mirror": True, "names": SceneNames()},
    "mirrored and rotated, no buildings": {"mirror": True, "rotation": -2.0, "buildings": False,
                                           "names": SceneNames()},
}


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_waiting_drivers_warned_when_they_cut_across_and_not_when_they_turn_away(variant: str):
    """A left-turner that waited 0, 1 or 2 s is braked for before it enters the ego's lane.
    A right-turner may be braked for while its intent is unknown and the ego must decide
    (the ego here reaches the junction 2.4 s after the obstacle leaves: its last safe
    moment comes before the turn shows), but never once the filter reads the turn
    (P(right) > 0.9), and the brake is released by the end."""
    kw = dict(VARIANTS[variant])
    names = kw.pop("names")
    for i, wait in enumerate((0.0, 1.0, 2.0)):
        brake, entered, _ = _wait_and_go(names, wait, "left", seed=i, **kw)
        assert entered is not None and brake is not None, (wait, "no warning for a cut-off")
        assert brake < entered, (wait, brake, entered)
        brake, entered, monitor = _wait_and_go(names, wait, "right", seed=i, **kw)
        rows = monitor.trace
        assert not rows[-1]["brake"], (wait, "still braking for a turn away")
        assert not any(r["brake"] for r in rows if r["posterior"]["p_right"] > 0.9), \
            (wait, "braked for a car read as turning away")
        assert rows[-1]["posterior"]["p_right"] > 0.5


# ------------------------------------------------------------------ the trace file
def _edit(line: str, **changes: object) -> str:
    """One JSON line of a trace with some keys replaced (NaN written as JSON's NaN)."""
    return json.dumps({**json.loads(line), **changes})


def test_trace_round_trip_and_damaged_files(tmp_path: Path):
    _, _, monitor = _wait_and_go(SceneNames(), 0.5, "left", seed=0)
    path = monitor.save_trace(tmp_path / "episode.jsonl")
    umask = os.umask(0)
    os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask  # an ordinary file, readable by others
    trace = read_trace(path)
    assert len(trace.times) == len(monitor.trace) and trace.names == SceneNames()
    np.testing.assert_allclose(trace.poses[3], [monitor.trace[3]["ego"], monitor.trace[3]["obstacle"]])
    assert trace.brake_time == monitor.brake_time and trace.tau == monitor.cdf.tau
    assert trace.ego.wheelbase == 2.7 and trace.posterior["p_cutoff"][-1] == monitor.trace[-1]["posterior"]["p_cutoff"]
    assert trace.rule == "layered" and trace.threshold == monitor.cdf.risk.brake
    np.testing.assert_allclose(trace.posterior["risk"], monitor.planner.history["risk"], atol=1e-5)  # 5 decimals
    np.testing.assert_array_equal(trace.brake, [row["brake"] for row in monitor.trace])
    lines = path.read_text().splitlines()
    old = tmp_path / "old.jsonl"  # a trace written before the risk rule: no rule, no risk
    header = {k: v for k, v in json.loads(lines[0]).items() if k not in ("rule", "threshold")}
    old.write_text("\n".join([json.dumps(header), *(json.dumps({k: v for k, v in json.loads(x).items() if k != "risk"})
                                                    for x in lines[1:])]) + "\n")
    assert read_trace(old).rule == "threshold" and read_trace(old).threshold == monitor.cdf.tau
    bad = tmp_path / "bad.jsonl"
    for text, fragment in (
        ("\n".join([lines[0], lines[1], lines[2][:30]]), "bad.jsonl:3: not JSON"),
        ("\n".join([lines[0], json.dumps({"t": 0.0, "ego": [0, 0, 0, 0]})]),
         "bad.jsonl:2: the observation lacks 'obstacle'"),
        ("\n".join([lines[0], lines[2], lines[1]]), "bad.jsonl:3: time 0 s does not follow 0.1 s"),
        (json.dumps({"format": "other"}), "bad.jsonl:1: not a monitor trace"),
        ("", "bad.jsonl:1: empty file"),
        ("\n".join([_edit(lines[0], tau=float("nan")), lines[1]]),
         r"bad.jsonl:1: the header's 'tau' must be in \(0, 1\]"),
        ("\n".join([_edit(lines[0], tau=-5), lines[1]]), r"bad.jsonl:1: the header's 'tau' must be in \(0, 1\]"),
        ("\n".join([_edit(lines[0], threshold=1.5), lines[1]]),
         r"bad.jsonl:1: the header's 'threshold' must be in \(0, 1\]"),
        ("\n".join([_edit(lines[0], rule="often"), lines[1]]), "bad.jsonl:1: the header's 'rule' must be"),
        ("\n".join([lines[0], _edit(lines[1], risk=2.0)]), "bad.jsonl:2: 'posterior' has risk out of range"),
        ("\n".join([_edit(lines[0], names={"nosuch": "x"}), lines[1]]),
         "bad.jsonl:1: the header's 'names' has unknown key.s. nosuch; valid: ego_prefix"),
        ("\n".join([lines[0], _edit(lines[1], posterior={**json.loads(lines[1])["posterior"], "p_left": 7.0})]),
         "bad.jsonl:2: 'posterior' has p_left out of range"),
        ("\n".join([lines[0], _edit(lines[1], posterior={**json.loads(lines[1])["posterior"],
                                                          "p_cutoff": float("nan")})]),
         "bad.jsonl:2: 'posterior' has p_cutoff out of range"),
    ):
        bad.write_text(text)
        with pytest.raises(TraceError, match=fragment):
            read_trace(bad)
    with pytest.raises(TraceError, match="cannot read"):
        read_trace(tmp_path / "missing.jsonl")


def test_render_draws_a_trace_frame(tmp_path: Path):
    pytest.importorskip("imageio.v3", reason="the viz extra (imageio) is not installed")
    from cdf_mj.sim.gl import RenderError, gl_backend
    from cdf_mj.viz.trace import render_trace

    try:
        gl_backend()
    except RenderError as exc:
        pytest.skip(f"no OpenGL backend can be created here: {exc}")
    spec = build_junction(names=OWN_NAMES, cars=False, rotation=0.7, camera=None)
    xml = tmp_path / "junction.xml"
    xml.write_text(spec.to_xml())
    _, _, monitor = _wait_and_go(OWN_NAMES, 0.5, "left", seed=0, rotation=0.7)
    trace = monitor.save_trace(tmp_path / "episode.jsonl")
    out = tmp_path / "frame.png"
    result = render_trace(trace, xml, out, frame_time=2.0, width=320, height=240)
    import imageio.v3 as iio

    img = iio.imread(out)
    assert img.shape == (240, 320, 3) and result.n_frames == 1 and result.brake_time == monitor.brake_time
    r, g, b = (img[..., i].astype(int) for i in range(3))
    red, blue = (r > g + 80) & (r > b + 80), (b > r + 50) & (b > g + 30)
    assert red[80:].sum() > 20 and blue[80:].sum() > 20  # both cars' boxes, below the panel
