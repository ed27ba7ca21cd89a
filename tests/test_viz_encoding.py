"""cdf_mj.viz.encoding: MP4, GIF and PNG written all or nothing.

Failures are real ones: ffmpeg refusing a frame size, the directory removed before the
rename, and a full disk stood in for by a file-size limit (RLIMIT_FSIZE, in a child
process) that the real encoders run into.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from cdf_mj.viz.encoding import EncodingError, FrameWriter, check_writable

iio = pytest.importorskip("imageio.v3", reason="the viz extra (imageio) is not installed")
pytest.importorskip("imageio_ffmpeg", reason="the viz extra (imageio-ffmpeg) is not installed")


def _frames(n: int, height: int = 48, width: int = 64) -> list[np.ndarray]:
    """``n`` distinct smooth frames (a moving gradient), RGB uint8."""
    y, x = np.mgrid[:height, :width]
    return [np.stack([(x * 4 + 20 * i) % 256, (y * 5) % 256, np.full_like(x, 40 * i % 256)],
                     axis=-1).astype(np.uint8) for i in range(n)]


def _leftovers(directory: Path) -> list[str]:
    """Hidden files in ``directory``: a temporary file left behind."""
    return sorted(p.name for p in directory.iterdir() if p.name.startswith("."))


# ----------------------------------------------------------------- writing
def test_mp4_has_every_frame(tmp_path) -> None:
    out = tmp_path / "v.mp4"
    frames = _frames(6)
    with FrameWriter(out, fps=10) as writer:
        for f in frames:
            writer.append(f)
    back = np.stack(list(iio.imiter(out)))
    assert back.shape == (6, 48, 64, 3)
    assert np.abs(back.astype(int) - np.stack(frames)).mean() < 3.0  # lossy, but close
    assert _leftovers(tmp_path) == []


def test_png_is_exact_and_gif_keeps_its_rate(tmp_path) -> None:
    frame = _frames(1)[0]
    with FrameWriter(tmp_path / "f.png", fps=30) as writer:
        writer.append(frame)
    np.testing.assert_array_equal(iio.imread(tmp_path / "f.png"), frame)
    with FrameWriter(tmp_path / "a.gif", fps=25) as writer:
        for f in _frames(4):
            writer.append(f)
    assert len(iio.imread(tmp_path / "a.gif", index=None)) == 4
    assert iio.immeta(tmp_path / "a.gif")["duration"] == 40  # [ms] per frame at 25 fps
    assert _leftovers(tmp_path) == []


def test_the_file_appears_only_when_complete(tmp_path) -> None:
    out = tmp_path / "v.mp4"
    writer = FrameWriter(out, fps=10)
    writer.append(_frames(1)[0])
    assert not out.exists() and len(_leftovers(tmp_path)) == 1  # the temporary file, beside it
    writer.close()
    assert out.exists() and _leftovers(tmp_path) == []


def test_bad_frames_are_refused(tmp_path) -> None:
    with FrameWriter(tmp_path / "v.gif", fps=10) as writer:
        writer.append(_frames(1)[0])
        with pytest.raises(ValueError, match="frame of size"):
            writer.append(_frames(1, height=50)[0])
        with pytest.raises(ValueError, match="RGB"):
            writer.append(np.zeros((48, 64, 3), dtype=np.float32))
    with FrameWriter(tmp_path / "f.png", fps=10) as writer:
        writer.append(_frames(1)[0])
        with pytest.raises(ValueError, match="one frame"):
            writer.append(_frames(1)[0])
    with pytest.raises(ValueError, match=r"unknown format '\.avi'"):
        FrameWriter(tmp_path / "v.avi", fps=10)


# ----------------------------------------------------------------- failing
@pytest.mark.parametrize("name", ["v.mp4", "v.gif"])
def test_a_failure_leaves_the_old_file_as_it_was(tmp_path, name) -> None:
    out = tmp_path / name
    out.write_bytes(b"the earlier video")
    def draw_then_fail() -> None:
        with FrameWriter(out, fps=10) as writer:
            writer.append(_frames(1)[0])
            raise RuntimeError("drawing failed")

    with pytest.raises(RuntimeError, match="drawing failed"):
        draw_then_fail()
    assert out.read_bytes() == b"the earlier video"
    assert _leftovers(tmp_path) == []


def test_no_frames_writes_nothing(tmp_path) -> None:
    with pytest.raises(EncodingError, match="no frames"), FrameWriter(tmp_path / "v.mp4", fps=10):
        pass
    assert list(tmp_path.iterdir()) == []


def test_ffmpeg_refusing_the_frames_is_an_error_naming_the_path(tmp_path) -> None:
    """yuv420p needs even sizes: ffmpeg exits with an error, which must not pass as success."""
    out = tmp_path / "odd.mp4"
    writer = FrameWriter(out, fps=10)
    writer.append(_frames(1, height=47, width=63)[0])  # ffmpeg may not have read it yet
    with pytest.raises(EncodingError) as info:
        writer.close()
    msg = str(info.value)
    assert msg.startswith(f"{out}: could not write the MP4 (ffmpeg ") and "\n" not in msg
    assert "divisible by 2" in msg  # ffmpeg's own words
    assert info.value.filename == str(out)
    assert list(tmp_path.iterdir()) == []


def test_directory_gone_before_the_rename(tmp_path) -> None:
    sub = tmp_path / "sub"
    sub.mkdir()
    writer = FrameWriter(sub / "f.png", fps=10)
    writer.append(_frames(1)[0])
    for p in sub.iterdir():  # the writer's temporary file stays open, the directory goes
        p.unlink()
    sub.rmdir()
    with pytest.raises(EncodingError, match="could not write the PNG"):
        writer.close()
    assert not sub.exists()


def test_unwritable_directory_is_refused_at_once() -> None:
    with pytest.raises(EncodingError, match="could not write the GIF"):
        FrameWriter("/proc/cdf_mj_test.gif", fps=10)
    with pytest.raises(OSError, match="cdf_mj_test"):
        check_writable("/proc/cdf_mj_test.gif")


_FULL_DISK = textwrap.dedent("""
    import resource, signal, sys
    import numpy as np
    from cdf_mj.viz.encoding import EncodingError, FrameWriter

    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG
    resource.setrlimit(resource.RLIMIT_FSIZE, (50_000, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))
    noise = np.random.default_rng(0).integers(0, 256, (10, 240, 320, 3), dtype=np.uint8)
    try:
        with FrameWriter(sys.argv[1], fps=10) as writer:
            for frame in noise[:1] if sys.argv[1].endswith(".png") else noise:  # incompressible: > 50 kB
                writer.append(frame)
    except EncodingError as exc:
        print(exc)
        sys.exit(3)
""")


@pytest.mark.skipif(sys.platform == "win32", reason="needs POSIX resource limits")
@pytest.mark.parametrize("name", ["v.mp4", "v.gif", "f.png"])
def test_a_full_disk_is_an_error_and_leaves_no_partial_file(tmp_path, name) -> None:
    """The encoder runs out of room (a 50 kB file-size limit): an error naming the path,
    the earlier file untouched, no temporary file left behind, nothing on stderr (no
    "Exception ignored" from a file closed during garbage collection)."""
    out = tmp_path / name
    out.write_bytes(b"the earlier video")
    run = subprocess.run([sys.executable, "-c", _FULL_DISK, str(out)], capture_output=True,
                         text=True, timeout=120, check=False)
    assert run.returncode == 3, run.stderr
    assert run.stdout.startswith(f"{out}: could not write the {name[-3:].upper()} (")
    assert run.stderr == ""
    assert out.read_bytes() == b"the earlier video"
    assert _leftovers(tmp_path) == []
