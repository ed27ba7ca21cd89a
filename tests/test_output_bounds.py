"""Outputs bounded before they are made (issue 28, causes 3, 4, 9, 11): a trace's span and
ticks and a render's frame count checked before anything is allocated; GIF frames streamed,
never held; temporary names that fit the file system's limit whatever the target's; paths
as the OS gives them (a results directory whose name is not UTF-8); the temporary files of
killed renders removed by the next render of the same output."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from cdf_mj.config import MAX_DURATION
from cdf_mj.records import write_atomic
from cdf_mj.records.files import name_max
from cdf_mj.scenario.trace_file import MAX_TRACE_TICKS, TRACE_FORMAT, TraceError, read_trace
from cdf_mj.sim.gl import RenderError
from cdf_mj.sim.scene import DEFAULT_SCENE
from cdf_mj.viz.encoding import FrameWriter, remove_stale_temporaries
from cdf_mj.viz.render import MAX_FRAMES, frame_times
from tests.cli_helpers import assert_one_line_error, run_cli

pytest.importorskip("imageio_ffmpeg", reason="the viz extra (imageio-ffmpeg) is not installed")


# ----------------------------------------------------------------- trace spans (cause 3)
def _write_trace(path: Path, scene, times: list[float]) -> Path:
    """A trace of the default scene's cars, standing still, observed at ``times`` [s]."""
    layout = scene.layout()
    header = {"format": TRACE_FORMAT, "names": {}, "ego": layout.ego.to_dict(),
              "obstacle": layout.obstacle.to_dict(), "tau": 0.85}
    post = {"p_left": 0.5, "p_right": 0.5, "p_seen": 0.0, "p_cutoff": 0.1, "ess": 100.0}
    rows = [{"t": t, "ego": [-30.0, -1.75, 0.0, 0.0], "obstacle": [1.75, -30.0, 1.57, 0.0],
             "posterior": post, "brake": False} for t in times]
    path.write_text("\n".join(json.dumps(x) for x in [header, *rows]) + "\n")
    return path


@pytest.mark.parametrize(("times", "message"), [
    ([0.0, 1e6], "is 1e+06 s after the first observation (0 s); a trace spans at most 600 s"),
    ([0.0, 0.1, 1e15], "is 1e+15 s after the first observation"),
    ([5.0, 5.0 + MAX_DURATION + 0.1], "a trace spans at most 600 s"),
    ([0.0, 1e-9], "does not follow 0 s by at least 0.001 s"),
    ([0.0, 0.1, 0.1 + 1e-9], "does not follow 0.1 s by at least 0.001 s"),
])
def test_a_trace_without_bounded_time_is_refused_on_reading(scene, tmp_path, times, message) -> None:
    with pytest.raises(TraceError, match=message.replace("(", r"\(").replace(")", r"\)").replace("+", r"\+")):
        read_trace(_write_trace(tmp_path / "t.jsonl", scene, times))


def test_a_trace_at_its_bounds_is_read(scene, tmp_path) -> None:
    trace = read_trace(_write_trace(tmp_path / "t.jsonl", scene, [10.0, 10.001, 10.0 + MAX_DURATION]))
    assert trace.times[-1] - trace.times[0] == MAX_DURATION


def test_too_many_ticks_are_counted_before_parsing(tmp_path) -> None:
    path = tmp_path / "t.jsonl"
    path.write_text('{"format": "' + TRACE_FORMAT + '"}\n' + "x\n" * (MAX_TRACE_TICKS + 1))  # not even JSON
    with pytest.raises(TraceError, match=f"{MAX_TRACE_TICKS + 1} observations, more than the {MAX_TRACE_TICKS}"):
        read_trace(path)


@pytest.mark.parametrize("times", [[0.0, 1e6], [0.0, 1e15], [0.0, 1e-9]])
def test_cli_trace_of_unbounded_time_is_one_line_at_once(scene, tmp_path, capsys, times) -> None:
    trace = _write_trace(tmp_path / "t.jsonl", scene, times)
    start = time.monotonic()
    status, out, err = run_cli(capsys, "render", "--trace", str(trace), "--scene", str(DEFAULT_SCENE),
                               "--out", str(tmp_path / "t.mp4"))
    assert_one_line_error(status, out, err, "t.jsonl:")
    assert time.monotonic() - start < 10 and not (tmp_path / "t.mp4").exists()


def test_the_frame_count_is_bounded_before_the_frame_times_are_made() -> None:
    assert len(frame_times(MAX_DURATION, 60)) == MAX_FRAMES  # 600 s at 60 fps: the most
    for span, fps in ((1e6, 30), (1e15, 30), (MAX_DURATION, 240), (float("inf"), 30)):
        with pytest.raises(RenderError, match=r"^--fps \S+: .* a render draws; lower --fps"):
            frame_times(span, fps, "the trace")


def test_an_episode_of_too_many_frames_is_refused_naming_fps(tmp_path, capsys) -> None:
    """600 s of a crawling ego at 240 fps would be 144 001 frames: refused after the
    episode (its end is known), before a frame is drawn."""
    status, out, err = run_cli(capsys, "render", "--seed", "1", "--planner", "reactive",
                               "--set", "timing.duration=600", "--set", "ego.speed=0.01", "--fps", "240",
                               "--width", "64", "--height", "48", "--out", str(tmp_path / "v.mp4"))
    assert_one_line_error(status, out, err, "--fps 240:", "144001 frames", f"the {MAX_FRAMES} a render draws",
                          "at most 60 here")
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------- GIF streamed (cause 4)
def test_gif_frames_are_streamed_not_held(tmp_path) -> None:
    """300 frames of 160 x 120 are 17 MB; the writer holds none of them (ffmpeg encodes
    each as it comes), so Python's peak allocation stays about one frame."""
    frame = np.zeros((120, 160, 3), dtype=np.uint8)
    tracemalloc.start()
    try:
        with FrameWriter(tmp_path / "v.gif", fps=25) as writer:
            for i in range(300):
                frame[:, :, 0] = i % 256
                writer.append(frame)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 2_000_000, peak
    import imageio.v3 as iio

    assert iio.immeta(tmp_path / "v.gif")["duration"] == 40
    assert sum(1 for _ in iio.imiter(tmp_path / "v.gif")) == 300


# ----------------------------------------------------------------- long and odd names (cause 9)
def test_a_long_target_name_gets_a_temporary_name_that_fits(tmp_path) -> None:
    limit = name_max(tmp_path)
    target = tmp_path / ("é" * ((limit - 5) // 2) + "a.txt")  # 2 bytes a character: just fits
    assert len(os.fsencode(target.name)) <= limit
    write_atomic(target, "x")
    assert target.read_text() == "x" and [p.name for p in tmp_path.iterdir()] == [target.name]
    long = tmp_path / ("v" * (limit - 4) + ".gif")  # 251 characters for 255
    with FrameWriter(long, fps=10) as writer:
        writer.append(np.zeros((32, 32, 3), dtype=np.uint8))
    assert long.is_file()


def test_cli_renders_to_a_name_of_251_characters(backend, tmp_path, capsys) -> None:
    out = tmp_path / ("r" * 247 + ".mp4")
    status, stdout, err = run_cli(capsys, "render", "--seed", "1", "--set", "timing.duration=0.3",
                                  "--fps", "10", "--width", "64", "--height", "48", "--out", str(out))
    assert status == 0 and stdout.startswith(f"wrote {out}: 4 frames"), err
    assert out.is_file() and [p.name for p in tmp_path.iterdir()] == [out.name]


def test_a_name_longer_than_the_file_system_takes_is_one_line(tmp_path, capsys) -> None:
    out = tmp_path / ("r" * 300 + ".mp4")
    status, stdout, err = run_cli(capsys, "render", "--seed", "1", "--out", str(out))
    assert_one_line_error(status, stdout, err, "the name is 304 bytes, longer than the")


# ----------------------------------------------------------------- stale temporaries (cause 11)
def _dead_pid() -> int:
    """The pid of a process that has ended (and been reaped)."""
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_the_next_writer_removes_temporaries_of_killed_writers_only(tmp_path) -> None:
    dead, live = _dead_pid(), os.getppid()
    stale = tmp_path / f".v-{dead}-0123456789abcdef.mp4"
    kept = [tmp_path / f".v-{live}-0123456789abcdef.mp4",  # its writer still runs
            tmp_path / f".w-{dead}-0123456789abcdef.mp4",  # another target's
            tmp_path / f".v-{dead}-0123456789abcdef.gif",  # another format's
            tmp_path / f".v-{dead}-notmine.mp4",           # not of this pattern
            tmp_path / f".v.mp4.{dead}.tmp"]
    for p in (stale, *kept):
        p.write_bytes(b"partial")
    with FrameWriter(tmp_path / "v.mp4", fps=10) as writer:
        writer.append(np.zeros((32, 32, 3), dtype=np.uint8))
    assert writer.stale_removed == (stale,)
    assert not stale.exists() and all(p.exists() for p in kept)
    assert remove_stale_temporaries(tmp_path / "v.mp4") == ()


def test_a_killed_render_leaves_a_temporary_that_the_next_one_removes(backend, tmp_path, capsys) -> None:
    out = tmp_path / "k.mp4"
    cmd = [sys.executable, "-m", "cdf_mj", "render", "--seed", "1", "--set", "timing.duration=8",
           "--width", "320", "--height", "240", "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not any(
                p.stat().st_size > 0 for p in tmp_path.glob(f".k-{proc.pid}-*.mp4")):
            time.sleep(0.05)  # the temporary file of the writer, with frames in it
    finally:
        proc.kill()
        proc.wait()
    left = list(tmp_path.glob(".k-*.mp4"))
    assert len(left) == 1, left
    status, stdout, err = run_cli(capsys, "render", "--seed", "1", "--set", "timing.duration=0.3",
                                  "--fps", "10", "--width", "64", "--height", "48", "--out", str(out))
    assert status == 0, err
    lines = stdout.splitlines()
    assert lines[0] == f"removed 1 temporary file(s) that killed renders of {out} left: {left[0].name}"
    assert [p.name for p in tmp_path.iterdir()] == ["k.mp4"]
