"""Outputs replace only what they should (issue 39, causes 4 and 12): a FIFO, a device, a
socket or a directory at an output's path is refused by name before anything is written,
and a temporary file is never renamed over one (``write_atomic``, every ``report`` file,
``FrameWriter`` for ``render --out``, ``CDFMonitor.save_trace``); and ``save_trace`` never
writes a trace that ``read_trace`` would refuse.

The devices are made with ``mknod`` inside the test's directory (a copy of ``/dev/null``'s
numbers), never a system path: a check that failed would replace only the copy."""

from __future__ import annotations

import os
import socket
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from cdf_mj.config import MAX_DURATION
from cdf_mj.records.files import write_atomic
from cdf_mj.scenario.monitor import CDFMonitor
from cdf_mj.scenario.trace_file import MAX_TRACE_TICKS, MIN_TRACE_STEP, TraceError, read_trace, write_trace


def _make(kind: str, path: Path) -> Iterator[None] | None:
    """Put ``kind`` at ``path``: ``fifo``, ``device`` (a character device), ``socket``
    (bound, listening) or ``directory``."""
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "device":
        try:
            os.mknod(path, stat.S_IFCHR | 0o666, os.makedev(1, 3))
        except PermissionError:
            pytest.skip("mknod needs privileges this test does not have")
    elif kind == "directory":
        path.mkdir()
    else:
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.bind(str(path))
        _SOCKETS.append(sock)
    return None


_SOCKETS: list[socket.socket] = []
_WORDS = {"fifo": "a FIFO (named pipe)", "device": "a character device", "socket": "a socket",
          "directory": "a directory"}
KINDS = list(_WORDS)


@pytest.fixture
def short_dir() -> Iterator[Path]:
    """A directory with a short path (a UNIX socket's path is at most 107 bytes)."""
    with tempfile.TemporaryDirectory(prefix="o39") as name:
        yield Path(name)
    while _SOCKETS:
        _SOCKETS.pop().close()


def _same_kind(path: Path, kind: str) -> bool:
    mode = os.lstat(path).st_mode
    return {"fifo": stat.S_ISFIFO, "device": stat.S_ISCHR, "socket": stat.S_ISSOCK,
            "directory": stat.S_ISDIR}[kind](mode)


def _only(directory: Path, *names: str) -> None:
    """Nothing but ``names`` in ``directory``: no temporary file left behind."""
    assert sorted(os.listdir(directory)) == sorted(names)


# ----------------------------------------------------------------- cause 4: write_atomic
@pytest.mark.parametrize("kind", KINDS)
def test_write_atomic_refuses_what_is_not_a_regular_file_by_name_and_leaves_it(short_dir, kind):
    target = short_dir / "out.json"
    _make(kind, target)
    with pytest.raises(ValueError, match="an output replaces only a regular file") as info:  # one line, exit 2
        write_atomic(target, "{}\n")
    message = str(info.value)
    assert "\n" not in message and str(target) in message and _WORDS[kind] in message, message
    assert _same_kind(target, kind)
    _only(short_dir, "out.json")


def test_write_atomic_still_replaces_a_file_and_a_link_never_its_target(tmp_path):
    (tmp_path / "file").write_text("old")
    write_atomic(tmp_path / "file", "new")
    assert (tmp_path / "file").read_text() == "new"
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    (tmp_path / "link").symlink_to(fifo)  # the link is replaced, the FIFO it names untouched
    write_atomic(tmp_path / "link", "data")
    assert (tmp_path / "link").read_text() == "data" and not (tmp_path / "link").is_symlink()
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)


def test_a_fifo_made_while_writing_is_not_renamed_over(tmp_path, monkeypatch):
    target = tmp_path / "out.json"
    real = os.chmod

    def plant(path, mode, *args, **kwargs):  # the moment between the write and the rename
        real(path, mode, *args, **kwargs)
        if not target.exists():
            os.mkfifo(target)

    monkeypatch.setattr(os, "chmod", plant)
    with pytest.raises(ValueError, match="is a FIFO"):
        write_atomic(target, "{}\n")
    assert stat.S_ISFIFO(os.lstat(target).st_mode)
    _only(tmp_path, "out.json")


# ----------------------------------------------------------------- cause 4: FrameWriter (render --out)
@pytest.mark.parametrize("kind", KINDS)
def test_a_frame_writer_refuses_what_is_not_a_regular_file_before_any_frame(short_dir, kind):
    pytest.importorskip("imageio", reason="the viz extra is not installed")
    from cdf_mj.viz.encoding import EncodingError, FrameWriter, check_writable

    target = short_dir / "out.png"
    _make(kind, target)
    with pytest.raises(EncodingError) as info:
        FrameWriter(target, fps=10)
    message = str(info.value)
    assert "\n" not in message and str(target) in message and _WORDS[kind] in message, message
    with pytest.raises(ValueError, match="an output replaces only a regular file"):
        check_writable(target)
    assert _same_kind(target, kind)
    _only(short_dir, "out.png")


def test_a_frame_writer_never_renames_over_a_fifo_made_while_encoding(tmp_path):
    pytest.importorskip("imageio", reason="the viz extra is not installed")
    from cdf_mj.viz.encoding import EncodingError, FrameWriter

    target = tmp_path / "out.png"
    writer = FrameWriter(target, fps=10)
    writer.append(np.zeros((8, 8, 3), np.uint8))
    os.mkfifo(target)
    with pytest.raises(EncodingError, match="a FIFO \\(named pipe\\) was put there"):
        writer.close()
    assert stat.S_ISFIFO(os.lstat(target).st_mode)
    _only(tmp_path, "out.png")


# ----------------------------------------------------------------- cause 4: save_trace
def _monitor(scene, ticks: int = 3) -> CDFMonitor:
    layout = scene.layout()
    monitor = CDFMonitor(layout, rng=0)
    ego, obstacle = [-40.8, -1.85, 0.0, 13.4], list(layout.obstacle_start)
    for k in range(ticks):
        ego[0] += 1.34
        monitor.observe(0.1 * k, ego, obstacle)
    return monitor


@pytest.mark.parametrize("kind", KINDS)
def test_save_trace_refuses_what_is_not_a_regular_file(scene, short_dir, kind):
    target = short_dir / "t.jsonl"
    _make(kind, target)
    with pytest.raises(ValueError, match="an output replaces only a regular file") as info:
        _monitor(scene).save_trace(target)
    assert str(target) in str(info.value) and _WORDS[kind] in str(info.value)
    assert _same_kind(target, kind)
    _only(short_dir, "t.jsonl")


# ----------------------------------------------------------------- cause 4: the command line
def test_report_into_a_fifo_is_one_line_and_the_fifo_stays(tmp_path, capsys):
    pytest.importorskip("matplotlib", reason="the viz extra is not installed")
    from cli_helpers import assert_one_line_error, run_cli

    from cdf_mj.experiments.experiment import run_experiment

    run_experiment(tmp_path / "exp", range(2), planners=("reactive",), workers=1, progress=False)
    out = tmp_path / "report"
    out.mkdir()
    os.mkfifo(out / "report.md")
    status, stdout, err = run_cli(capsys, "report", str(tmp_path / "exp"), "--out", str(out))
    assert_one_line_error(status, stdout, err, str(out / "report.md"), "is a FIFO (named pipe)")
    assert stat.S_ISFIFO(os.lstat(out / "report.md").st_mode)
    assert sorted(p.name for p in out.iterdir()) == ["report.md"]  # refused before any figure was drawn


# ----------------------------------------------------------------- cause 12: what save_trace writes
def _rows(times: list[float]) -> list[dict[str, object]]:
    post = {"p_left": 0.5, "p_right": 0.5, "p_seen": 0.0, "p_cutoff": 0.1, "ess": 100.0}
    return [{"t": t, "ego": [-30.0, -1.75, 0.0, 0.0], "obstacle": [1.75, -30.0, 1.57, 0.0], "posterior": post,
             "brake": False, "risk": 0.0} for t in times]


def _header(scene) -> dict[str, object]:
    return _monitor(scene, 1).trace_header()


@pytest.mark.parametrize(("times", "needle"), [
    ([0.0, MAX_DURATION + 0.1], "a trace spans at most 600 s"),
    ([0.0, 0.1, 1e6], "is 1e+06 s after the first observation"),
    ([0.0, MIN_TRACE_STEP / 10], "does not follow 0 s by at least 0.001 s"),
    ([], "the trace has no observation after its header"),
])
def test_write_trace_refuses_what_read_trace_would_refuse_and_writes_nothing(scene, tmp_path, times, needle):
    path = tmp_path / "t.jsonl"
    with pytest.raises(TraceError) as info:
        write_trace(path, _header(scene), _rows(times))
    assert needle in str(info.value) and str(path) in str(info.value) and "\n" not in str(info.value)
    assert not path.exists()
    _only(tmp_path)


def test_write_trace_refuses_more_ticks_than_a_trace_holds(scene, tmp_path):
    path = tmp_path / "t.jsonl"
    times = [i * 0.001 for i in range(MAX_TRACE_TICKS + 1)]
    with pytest.raises(TraceError, match=f"{MAX_TRACE_TICKS + 1} observations, more than the {MAX_TRACE_TICKS}"):
        write_trace(path, _header(scene), _rows(times))
    assert not path.exists()


def test_what_save_trace_writes_read_trace_reads(scene, tmp_path):
    monitor = _monitor(scene)
    last = dict(monitor.trace[-1])
    monitor.trace.append({**last, "t": last["t"] + MAX_DURATION})  # 600 s after 0.2 s: over the span
    with pytest.raises(TraceError, match="a trace spans at most 600 s"):
        monitor.save_trace(tmp_path / "long.jsonl")
    assert not (tmp_path / "long.jsonl").exists()
    monitor.trace[-1]["t"] = monitor.trace[0]["t"] + MAX_DURATION  # exactly at the bound: saved and read
    trace = read_trace(monitor.save_trace(tmp_path / "ok.jsonl"))
    assert trace.times[-1] - trace.times[0] == pytest.approx(MAX_DURATION)


# ----------------------------------------------------------------- nothing outside --out
def test_counterexamples_are_never_written_through_a_linked_directory(tmp_path):
    from cdf_mj.falsify.counterexamples import write_counterexamples
    from cdf_mj.falsify.space import load_space

    space = tmp_path / "one.toml"
    space.write_text('description = "d"\n\n[failure]\nmargin = "gap"\nthreshold = 0.0\n\n'
                     '[dims."ego.start_spread"]\nrange = [-8.0, 8.0]\n')
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "01-seed-3.toml").write_text("not the run's")
    run = tmp_path / "run"
    run.mkdir()
    (run / "counterexamples").symlink_to(outside)
    with pytest.raises(ValueError, match="counterexamples is a symbolic link"):
        write_counterexamples(load_space(space), [], run / "counterexamples")
    assert (outside / "01-seed-3.toml").read_text() == "not the run's"


def test_falsify_never_writes_its_figure_into_a_fifo(tmp_path):
    """``progress.png`` was saved by matplotlib straight to its path: into a FIFO there it
    blocked (or, with a reader, fed it); now it is refused by name and the FIFO stays."""
    pytest.importorskip("matplotlib", reason="the viz extra is not installed")
    import threading

    from cdf_mj.falsify.run import falsify
    from cdf_mj.falsify.space import load_space

    (tmp_path / "fast.toml").write_text('description = "short"\n\n[scenario.timing]\nuntil_clear = false\n'
                                        'end_distance = 30.0\nduration = 6.0\n')
    space = tmp_path / "two.toml"
    space.write_text('description = "d"\npreset = "fast.toml"\n\n[failure]\nmargin = "gap"\nthreshold = 0.0\n\n'
                     '[dims."ego.start_spread"]\nrange = [-8.0, 8.0]\n\n'
                     '[dims."obstacle.family"]\nchoices = ["model", "aggressive"]\n')
    out = tmp_path / "run"
    out.mkdir()
    fifo = out / "progress.png"
    os.mkfifo(fifo)

    def drain() -> None:  # a reader, so that a write into the FIFO cannot hang the test
        with open(fifo, "rb") as fh:
            fh.read()

    drained = threading.Thread(target=drain, daemon=True)
    drained.start()
    try:
        with pytest.raises(ValueError, match=r"progress\.png is a FIFO \(named pipe\)"):
            falsify(load_space(space), "reactive", 8, out, workers=1, max_clusters=1)
    finally:
        if drained.is_alive():  # let the reader go
            with open(fifo, "wb"):
                pass
        drained.join(5)
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    journal = out / "evaluations.jsonl"  # refused before the search: no episode ran
    assert not journal.exists() or journal.stat().st_size == 0


@pytest.mark.parametrize("kind", ["fifo", "device"])
def test_render_out_onto_a_fifo_or_a_device_is_one_line_and_it_stays(scene, short_dir, capsys, kind):
    pytest.importorskip("imageio", reason="the viz extra is not installed")
    from cli_helpers import assert_one_line_error, run_cli

    trace = _monitor(scene, 5).save_trace(short_dir / "t.jsonl")
    target = short_dir / "out.mp4"
    _make(kind, target)
    status, stdout, err = run_cli(capsys, "render", "--trace", str(trace), "--scene", str(scene.source), "--out",
                                  str(target))
    assert_one_line_error(status, stdout, err, str(target), _WORDS[kind])
    assert _same_kind(target, kind)
    _only(short_dir, "t.jsonl", "out.mp4")
