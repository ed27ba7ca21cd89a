"""Frames to an MP4, GIF or PNG file, all or nothing.

:class:`FrameWriter` encodes into a temporary file beside the target (same directory, so
the final rename stays on one file system), checks everything the encoder reports (ffmpeg's
exit status, every write, the final flush and ``fsync``), and only then renames it onto the
target. On any failure the temporary file is removed, the target is left as it was, and
:class:`EncodingError` names the path: a full disk never reports success or leaves a
partial file. Only a regular file (or a symbolic link, itself replaced) is ever replaced:
a FIFO, a device, a socket or a directory at the target is refused by name before a
frame is encoded, and again before the rename
(:func:`cdf_mj.records.files.check_output_target`).

The temporary file is ``.STEM-PID-HEX.SUFFIX`` (the stem cut short where the name would
pass the file system's limit, :func:`cdf_mj.records.files.temp_prefix`), ``PID`` the
writing process. A process killed while writing leaves its temporary file behind; the next
:class:`FrameWriter` of the same target removes those of processes that no longer run
(:attr:`FrameWriter.stale_removed`). ::

    with FrameWriter("episode.mp4", fps=30) as writer:
        for frame in frames:            # (height, width, 3) uint8 RGB, all the same size
            writer.append(frame)
    # the file exists, complete, only here

MP4 (H.264 in yuv420p) and GIF are streamed to the ffmpeg of ``imageio-ffmpeg`` frame by
frame, so memory does not grow with the number of frames (a GIF gets a palette of its own
per frame); a PNG is Pillow's, through ``imageio``. Needs the ``viz`` extra.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
import subprocess
import tempfile
from fractions import Fraction
from pathlib import Path
from types import ModuleType
from typing import IO, TYPE_CHECKING

import numpy as np

from cdf_mj.extras import require
from cdf_mj.records.files import OutputTargetError, check_output_target, temp_prefix

if TYPE_CHECKING:
    from typing_extensions import Self

__all__ = ["FORMATS", "EncodingError", "FrameWriter", "check_writable", "remove_stale_temporaries"]

#: Output formats by file suffix.
FORMATS = {".mp4": "mp4", ".gif": "gif", ".png": "png"}
# ffmpeg's output options per streamed format. MP4: H.264 as imageio's ffmpeg writer makes
# it at quality 7 (crf 15), fast preset. GIF: a 256-colour palette computed for each frame
# (palettegen's single mode needs no other frame, so nothing is held), looping forever.
_OUTPUT = {
    "mp4": ["-an", "-vcodec", "libx264", "-pix_fmt", "yuv420p", "-crf", "15", "-preset", "veryfast"],
    "gif": ["-an", "-filter_complex",
            "split[a][b];[a]palettegen=stats_mode=single:reserve_transparent=0[p];[b][p]paletteuse=new=1",
            "-loop", "0"],
}
_FFMPEG_PREFIX = re.compile(r"^(\[[^\]]*\]\s*)+")  # "[libx264 @ 0x55e9c6ab5e40] "


class EncodingError(OSError):
    """Frames that could not be written to :attr:`filename`; the file is as it was before
    (absent, or its earlier content). ``str()`` is one line: the path and the cause."""

    def __str__(self) -> str:
        return f"{self.filename}: {self.strerror}"


def _temp_prefix(path: Path) -> str:
    """``.STEM``: the start of the name of every temporary file of ``path`` (cut so that
    the longest ``-PID-HEX.SUFFIX`` still fits the file system's limit)."""
    return temp_prefix(path.with_suffix(""), reserve=len(f"-{2**32}-{'0' * 16}{path.suffix}"))


def _temp_beside(path: Path) -> tuple[int, Path]:
    """A new, empty hidden file ``.STEM-PID-HEX.SUFFIX`` in ``path``'s directory (the
    suffix tells ffmpeg the container, the pid who wrote it), its mode that of any new
    file (the umask applies): ``(descriptor open for writing, its path)``. OSError if it
    cannot be made."""
    tmp = path.with_name(f"{_temp_prefix(path)}-{os.getpid()}-{secrets.token_hex(8)}{path.suffix}")
    return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666), tmp


def _running(pid: int) -> bool:
    """Whether process ``pid`` runs (or might: True wherever it cannot be told)."""
    if os.name != "posix":  # os.kill would end the process there
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (OSError, OverflowError):  # another user's process, or no such pid at all
        return True
    return True


def remove_stale_temporaries(path: str | Path) -> tuple[Path, ...]:
    """Remove the temporary files that writers of ``path`` killed while writing left
    beside it: only names of :class:`FrameWriter`'s pattern for this target, and only those
    whose writing process no longer runs. Returns the files removed (none where the
    directory cannot be listed)."""
    path = Path(path)
    pattern = re.compile(re.escape(_temp_prefix(path)) + r"-(\d{1,10})-[0-9a-f]{16}" + re.escape(path.suffix))
    removed = []
    try:
        names = os.listdir(path.parent)
    except OSError:
        return ()
    for name in names:
        match = pattern.fullmatch(name)
        if match and not _running(int(match.group(1))):
            with contextlib.suppress(FileNotFoundError):  # another writer removed it first
                (path.parent / name).unlink()
                removed.append(path.parent / name)
    return tuple(removed)


def check_writable(path: str | Path) -> None:
    """OSError unless a :class:`FrameWriter` could write ``path``: creates and removes the
    temporary file it would write first (permissions alone miss read-only and virtual
    file systems, and root). :class:`~cdf_mj.records.files.OutputTargetError` (a
    ValueError naming what is there) for a target that is not a regular file or absent."""
    check_output_target(path)
    fd, tmp = _temp_beside(Path(path))
    os.close(fd)
    tmp.unlink()


def _one_line(text: str) -> str:
    """``text`` with every run of whitespace (newlines too) as one space."""
    return " ".join(text.split())


class FrameWriter:
    """Writes frames to ``path`` as MP4, GIF or PNG (by its suffix, :data:`FORMATS`); the
    file appears only when :meth:`close` succeeds. Use with ``with`` (an exception in the
    block calls :meth:`abort`).

    Args:
        path: the target; its directory must exist. An existing file is replaced, and the
            temporary files that killed writers of it left are removed
            (:func:`remove_stale_temporaries`, listed in :attr:`stale_removed`).
        fps: frame rate [frames per second of the video]; a GIF stores it as whole
            hundredths of a second per frame.

    Raises:
        ValueError: an unknown suffix.
        EncodingError: a FIFO, a device, a socket or a directory at ``path`` (naming it).
        ImportError: the ``viz`` extra is missing (one line naming it).
        EncodingError: the temporary file cannot be created (and later: any failure to
            encode or write, from :meth:`append` and :meth:`close`).
    """

    def __init__(self, path: str | Path, fps: float) -> None:
        self.path = Path(path)
        fmt = FORMATS.get(self.path.suffix.lower())
        if fmt is None:
            raise ValueError(f"{self.path}: unknown format {self.path.suffix or '(no suffix)'!r}; "
                              f"use {', '.join(FORMATS)}")
        self.fmt, self.fps = fmt, fps
        try:  # a FIFO, a device, a socket or a directory is never replaced
            check_output_target(self.path)
        except OutputTargetError as exc:
            raise EncodingError(None, f"it is {exc.kind}: an output replaces only a regular file; move it away or "
                                "choose another path; nothing was written", str(self.path)) from None
        feature = f"writing {fmt.upper()}"
        if fmt in _OUTPUT:
            self._ffmpeg_exe: str = require("imageio_ffmpeg", "viz", feature).get_ffmpeg_exe()
        else:
            self._iio: ModuleType = require("imageio.v3", "viz", feature)
        try:
            fd, self._tmp = _temp_beside(self.path)
        except OSError as exc:
            raise self._error(exc.strerror or type(exc).__name__, exc.errno) from exc
        #: The temporary files of killed writers of :attr:`path` that this one removed.
        self.stale_removed: tuple[Path, ...] = remove_stale_temporaries(self.path)
        self._file: IO[bytes] | None = os.fdopen(fd, "wb")
        self._png: np.ndarray | None = None  # PNG: its one frame, encoded at close
        self._ffmpeg: subprocess.Popen[bytes] | None = None  # MP4, GIF: started by the first frame
        self._stderr: IO[bytes] | None = None  # ffmpeg's messages
        self._shape: tuple[int, ...] | None = None
        self._open = True

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def _error(self, cause: str, errno: int | None = None) -> EncodingError:
        """The error naming :attr:`path` and ``cause`` (one line)."""
        return EncodingError(errno, f"could not write the {self.fmt.upper()} ({_one_line(cause)}); "
                                    "nothing was written", str(self.path))

    def _ffmpeg_messages(self) -> str:
        """ffmpeg's first message on stderr (the cause; the rest follow from it), without
        its ``[component @ address]`` prefixes; empty if it wrote none."""
        if self._stderr is None:
            return ""
        self._stderr.seek(0)
        for line in self._stderr.read().decode(errors="replace").splitlines():
            text = _FFMPEG_PREFIX.sub("", line).strip()
            if text:
                return text[:300]
        return ""

    def append(self, frame: np.ndarray) -> None:
        """Add a frame: RGB ``(height, width, 3)`` uint8, the size of the first one (PNG:
        exactly one frame). ValueError for a frame that does not fit; EncodingError (and
        :meth:`abort`) when the encoder fails."""
        if not self._open:
            raise ValueError(f"{self.path}: the writer is closed")
        frame = np.asarray(frame)
        if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
            raise ValueError(f"a frame must be RGB (height, width, 3) uint8, got {frame.dtype} "
                             f"{frame.shape}")
        if self._shape is None:
            self._shape = frame.shape
        elif frame.shape != self._shape:
            raise ValueError(f"frame of size {frame.shape[:2]} after frames of {self._shape[:2]}")
        if self.fmt == "png":
            if self._png is not None:
                raise ValueError(f"{self.path}: a PNG holds one frame")
            self._png = frame.copy()
            return
        if self._ffmpeg is None:
            self._start_ffmpeg(frame.shape[1], frame.shape[0])
        assert self._ffmpeg is not None and self._ffmpeg.stdin is not None
        try:
            self._ffmpeg.stdin.write(np.ascontiguousarray(frame).tobytes())
        except OSError as exc:  # ffmpeg has gone: its messages say why
            error = self._error(f"ffmpeg stopped: {self._ffmpeg_messages() or exc}", exc.errno)
            self.abort()
            raise error from exc

    def _start_ffmpeg(self, width: int, height: int) -> None:
        assert self._file is not None
        self._file.close()  # ffmpeg opens the temporary file itself
        self._file = None
        self._stderr = tempfile.TemporaryFile()  # noqa: SIM115 - open until ffmpeg is reaped (_release)
        fps = str(Fraction(self.fps).limit_denominator())
        cmd = [self._ffmpeg_exe, "-y", "-f", "rawvideo", "-vcodec", "rawvideo",
               "-s", f"{width}x{height}", "-pix_fmt", "rgb24", "-r", fps, "-i", "-",
               *_OUTPUT[self.fmt], "-v", "error", str(self._tmp)]
        self._ffmpeg = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                                        stderr=self._stderr)

    def close(self) -> None:
        """Finish the file: encode, flush, ``fsync``, rename onto :attr:`path`.
        :class:`EncodingError` (nothing written, the target as it was) if any step fails
        or no frame was given."""
        if not self._open:
            return
        try:
            if self._shape is None:
                raise self._error("no frames")
            if self.fmt == "png":
                self._write_png()
            else:
                self._finish_ffmpeg()
            fd = os.open(self._tmp, os.O_RDONLY)  # what the kernel still holds must reach the disk
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
            check_output_target(self.path)  # made while encoding: still never renamed over
            os.replace(self._tmp, self.path)
        except OutputTargetError as exc:
            self.abort()
            raise self._error(f"{exc.kind} was put there while encoding: an output replaces only a regular "
                              "file") from None
        except EncodingError:
            self.abort()
            raise
        except OSError as exc:
            self.abort()
            raise self._error(exc.strerror or str(exc), exc.errno) from exc
        self._open = False
        self._release()

    def _finish_ffmpeg(self) -> None:
        proc = self._ffmpeg
        assert proc is not None and proc.stdin is not None
        try:
            proc.stdin.close()  # flushes: ffmpeg may have died on the last frames
        except OSError as exc:
            raise self._error(f"ffmpeg stopped: {self._ffmpeg_messages() or exc}", exc.errno) from exc
        status = proc.wait()
        if status != 0:
            cause = self._ffmpeg_messages() or (f"killed by signal {-status}" if status < 0
                                                else f"exit status {status}")
            raise self._error(f"ffmpeg failed: {cause}")

    def _write_png(self) -> None:
        data = self._iio.imwrite("<bytes>", self._png, extension=".png")
        assert self._file is not None
        self._file.write(data)
        self._file.flush()
        self._file.close()
        self._file = None

    def abort(self) -> None:
        """Stop without writing: the encoder is stopped, the temporary file removed, the
        target left as it was (idempotent)."""
        self._open = False
        self._png = None
        if self._file is not None:
            with contextlib.suppress(OSError):
                self._file.close()
            self._file = None
        if self._ffmpeg is not None and self._ffmpeg.poll() is None:
            self._ffmpeg.kill()
        self._release()
        self._tmp.unlink(missing_ok=True)

    def _release(self) -> None:
        """Close the pipes and reap ffmpeg."""
        if self._ffmpeg is not None:
            if self._ffmpeg.stdin is not None:
                with contextlib.suppress(OSError):
                    self._ffmpeg.stdin.close()
            self._ffmpeg.wait()
            self._ffmpeg = None
        if self._stderr is not None:
            self._stderr.close()
            self._stderr = None
