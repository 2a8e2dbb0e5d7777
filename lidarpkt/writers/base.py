"""The writer interface every output format meets, and the temporary-then-rename files.

A writer takes the frames of one capture (one or several sensors, in order) and writes them in
its format. Every file is first written under a hidden temporary name in its final folder
(``.NAME.<random>.tmp``) and renamed to ``NAME`` only when complete, so a killed job never
leaves a partial file that looks complete; :meth:`FrameWriter.abort` (also what a ``with`` block
that raises does) removes the temporaries.

Packets ride along with the frames. Writers never open their inputs: one pass over each capture
(:func:`lidarpkt.writers.write_captures`, :func:`lidarpkt.pipeline.passes.open_pass`) hands every
writer, in this order (:class:`PacketWriter`; :class:`BaseWriter` gives each a default that does nothing):

* ``begin_capture(capture)``: a capture starts; ``capture`` is a :class:`lidarpkt.pipeline.passes.Capture`
  (``path`` as given, ``container``, ``metadata``: the loaded sensor metadata its packets are
  recognised with, once its first batch is handed; ``receive_span()`` for an OSF file);
* ``write_packets(batch, stream)``, only to a writer whose ``wants_packets`` is true: every
  :class:`~lidarpkt.core.packet.PacketBatch` read, in capture order, before the frames it completed
  (one stream: ``src``/``dst`` endpoints or ``None`` for a bag's, ``timestamp_ns`` int64[N] host capture
  times in ns, ``payload`` uint8[N, L], ``index`` int64[N] ordinals in the capture), with ``stream``,
  what the router made of it: a :class:`lidarpkt.pipeline.router.Match` (``vendor``, ``kind``: the
  vendor's name of the stream, ``lidar``: frames are made of it), or ``None`` when no vendor recognised
  the batch (it is still handed: raw outputs keep every packet);
* ``write(frame)``: each frame, in order;
* ``end_capture(capture)``: the capture's last batch and frame have been handed.

A writer that wants no packets ignores them (``wants_packets = False``, the default): the pass then
decodes as ``lidarpkt.open`` does, segments and threads included. A writer that takes packets and no
frames says so (``wants_frames = False``): when no writer of a pass wants frames, the capture's packets
are classified but not decoded.
"""

from __future__ import annotations

import errno
import os
import re
import secrets
import shutil
import sqlite3
from pathlib import Path
from typing import Any, Callable, Protocol, runtime_checkable

from lidarpkt.errors import OutputError

#: what a failed write raises: the file system's errors, and SQLite's (rosbag2's storage) when the disk fills
WRITE_ERRORS: tuple[type[BaseException], ...] = (OSError, sqlite3.Error)


def failure_text(exc: BaseException) -> str:
    """Why a write failed, in words: the system's reason (and what to do when the disk is full)."""
    if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG) or "full" in str(exc):
        return f"{(exc.strerror if isinstance(exc, OSError) else None) or exc}; free some space or write elsewhere"
    if isinstance(exc, OSError) and exc.errno is None:  # a library's short write (NumPy's tofile...): no reason given
        return f"{exc} (is the disk full?)"
    return str((exc.strerror if isinstance(exc, OSError) else None) or exc)


@runtime_checkable
class FrameWriter(Protocol):
    """What :func:`lidarpkt.writers.open_writer` returns."""

    def write(self, frame: Any) -> None:
        """Write one :class:`lidarpkt.Frame` (frames of one capture, in order)."""
        ...

    def close(self) -> list[Path]:
        """Finish; return the complete files written (renamed from their temporaries)."""
        ...

    def abort(self) -> None:
        """Stop and remove every temporary file; nothing partial is left."""
        ...


@runtime_checkable
class PacketWriter(Protocol):
    """What a writer that takes the raw packets beside the frames offers (see the module doc)."""

    wants_packets: bool
    wants_frames: bool

    def begin_capture(self, capture: Any) -> None:
        """A capture starts (a :class:`lidarpkt.pipeline.passes.Capture`)."""
        ...

    def write_packets(self, batch: Any, stream: Any) -> None:
        """One :class:`~lidarpkt.core.packet.PacketBatch` of the capture, in capture order, and what the router
        made of it (a :class:`lidarpkt.pipeline.router.Match`, or ``None``)."""
        ...

    def end_capture(self, capture: Any) -> None:
        """The capture's last batch and frame have been handed."""
        ...


class AtomicFiles:
    """Temporary files beside their final names, renamed into place when complete."""

    def __init__(self) -> None:
        self._pending: dict[Path, Path] = {}  # temporary -> final
        self.committed: list[Path] = []

    def temporary(self, final: str | os.PathLike[str]) -> Path:
        """A new temporary path in ``final``'s folder (the folder must exist): a file's, or a folder's
        (a rosbag2), which :meth:`commit` renames as a whole."""
        final = Path(final)
        if not final.parent.is_dir():
            raise OutputError(f"{final}: the folder {final.parent} does not exist; create it or choose another")
        tmp = final.with_name(f".{final.name}.{secrets.token_hex(4)}.tmp")
        self._pending[tmp] = final
        return tmp

    def commit(self, tmp: Path) -> Path:
        """Rename a complete temporary to its final name (replacing an older file of that name, or an
        empty folder)."""
        final = self._pending.pop(tmp)
        try:
            os.replace(tmp, final)
        except OSError as exc:
            raise OutputError(f"{final}: cannot rename {tmp.name} into place: {exc.strerror or exc}") from exc
        self.committed.append(final)
        return final

    def abort(self) -> None:
        """Remove every temporary not yet committed (a temporary folder with what it holds)."""
        for tmp in list(self._pending):
            try:
                if tmp.is_dir() and not tmp.is_symlink():
                    shutil.rmtree(tmp)
                else:
                    tmp.unlink()
            except FileNotFoundError:
                pass
            except OSError:
                pass  # best effort: the name stays hidden and marked .tmp
            self._pending.pop(tmp, None)


def write_atomic(path: str | os.PathLike[str], write: Callable[[Path], object]) -> Path:
    """``write(tmp)`` into a hidden temporary beside ``path`` (:class:`AtomicFiles`), then renamed to
    ``path``: no reader ever sees a half-written file, and on any error the temporary is removed.

    Raises:
        OutputError: the folder does not exist, or writing or renaming failed (the cause chained).
        And what ``write`` raises otherwise.
    """
    files = AtomicFiles()
    tmp = files.temporary(path)
    try:
        write(tmp)
        return files.commit(tmp)
    except OSError as exc:
        raise OutputError(f"{path}: cannot write it ({exc.strerror or exc})") from exc
    finally:
        files.abort()  # nothing left once committed; the temporary otherwise


class BaseWriter:
    """Shared plumbing: ``with`` support (abort on error), idempotent close/abort, file names.

    Subclasses implement :meth:`_write` and :meth:`_finish` (which commits its files through
    ``self.files``) and may extend :meth:`abort`; one that takes the packets too (module doc) sets
    ``wants_packets`` and overrides :meth:`write_packets` (and :meth:`begin_capture`,
    :meth:`end_capture` as it needs).

    Attributes:
        frames_written: frames given to :meth:`write`.
        points_written: points (or rows) written, for the formats that write points.
        files: the :class:`AtomicFiles` (``files.committed``: the complete files so far).
    """

    suffix = ""
    wants_packets = False  # True: the pass hands this writer every packet batch (write_packets)
    wants_frames = True  # False (with wants_packets): it writes no frames; a pass for such writers alone decodes none

    def __init__(self, out: str | os.PathLike[str], *, capture: str | os.PathLike[str] | None = None,
                 part: str | None = None) -> None:
        self.out = Path(out)
        self.capture = Path(capture).name if capture is not None else None
        self.part = part
        self.files = AtomicFiles()
        self.frames_written = 0
        self.points_written = 0
        self._done = False

    # ------------------------------------------------------------- naming
    def single_file(self) -> Path:
        """The output of a one-file format: ``out``, or ``STEM.PART.SUFFIX`` for a segment."""
        if self.part is None:
            return self.out
        return self.out.with_name(f"{self.out.stem}.{_safe(self.part)}{self.out.suffix}")

    def frame_file_name(self, frame: Any, suffix: str) -> str:
        """``CAPTURESTEM_SENSOR_FRAMEID.SUFFIX``: the same whatever the segmentation."""
        stem = Path(self.capture).stem if self.capture else "frames"
        return f"{_safe(stem)}_{sensor_tag(frame.sensor)}_{frame.frame_id:06d}{suffix}"

    def one_file_or_groups(self, frames_per_file: int | None) -> int | None:
        """Set up a format that writes one file (``out``; its folder must exist) or, with ``frames_per_file``
        N, a folder ``out`` of files of N frames each (:meth:`group_file`; made if missing). Returns N.

        Raises :class:`~lidarpkt.errors.OutputError`: N below 1, a folder that does not exist."""
        if frames_per_file is not None and int(frames_per_file) < 1:
            raise OutputError(f"--frames-per-file {frames_per_file}: give a positive number of frames")
        if frames_per_file is None:
            self.path = self.single_file()
            if not self.path.parent.is_dir():
                raise OutputError(f"-o {self.path}: the folder {self.path.parent} does not exist")
            return None
        self.out_dir()
        return int(frames_per_file)

    def group_file(self, frame: Any, frames_per_file: int, suffix: str) -> tuple[tuple[str, int], Path]:
        """(key, path) of the file holding ``frame`` when each file holds ``frames_per_file`` frames of one
        sensor: ``OUT/CAPTURESTEM_SENSOR_FFFFFF[.PART]SUFFIX``, F the first frame id of its group (grouped by
        frame id, so that the grouping does not depend on how the capture was segmented)."""
        start = frame.frame_id // frames_per_file * frames_per_file
        stem = _safe(Path(self.capture).stem) if self.capture else "frames"
        tag = sensor_tag(frame.sensor)
        name = f"{stem}_{tag}_{start:06d}" + (f".{_safe(self.part)}" if self.part else "")
        return (tag, start), self.out / (name + suffix)

    def out_dir(self) -> Path:
        """``out`` as a folder (created if missing; its parent must exist)."""
        if not self.out.exists():
            if not self.out.parent.is_dir():
                raise OutputError(f"{self.out}: the folder {self.out.parent} does not exist; create it first")
            try:
                self.out.mkdir(exist_ok=True)
            except OSError as exc:
                raise OutputError(f"{self.out}: cannot create the folder: {exc.strerror or exc}") from None
        elif not self.out.is_dir():
            raise OutputError(f"{self.out}: this format writes a folder, and a file has that name; "
                              "choose another output")
        return self.out

    # ------------------------------------------------------------- protocol
    def write(self, frame: Any) -> None:
        if self._done:
            raise OutputError(f"{self.out}: the writer is closed")
        try:
            self._write(frame)
        except WRITE_ERRORS as exc:
            self.abort()
            raise OutputError(f"{self.out}: writing failed: {failure_text(exc)}") from None
        self.frames_written += 1

    def begin_capture(self, capture: Any) -> None:
        """A capture starts (module doc); nothing by default."""

    def write_packets(self, batch: Any, stream: Any) -> None:
        """A packet batch of the capture (module doc); ignored by default."""

    def end_capture(self, capture: Any) -> None:
        """The capture has been handed whole (module doc); nothing by default."""

    def close(self) -> list[Path]:
        if self._done:
            return list(self.files.committed)
        try:
            self._finish()
        except WRITE_ERRORS as exc:
            self.abort()
            raise OutputError(f"{self.out}: writing failed: {failure_text(exc)}") from None
        except BaseException:
            self.abort()
            raise
        self._done = True
        return list(self.files.committed)

    def abort(self) -> None:
        self._done = True
        self._release()
        self.files.abort()

    def _write(self, frame: Any) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _finish(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _release(self) -> None:
        """Close open handles (before the temporaries are removed)."""

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def _safe(text: str) -> str:
    """``text`` with characters unsafe in file names replaced by ``-``."""
    return re.sub(r"[^A-Za-z0-9._+-]", "-", str(text)).strip(".") or "x"


def sensor_tag(sensor: Any) -> str:
    """A file-name-safe name of a sensor: its serial, else its source address, else its vendor."""
    if getattr(sensor, "serial", None):
        return _safe(str(sensor.serial))
    if getattr(sensor, "source", None):
        return _safe(str(sensor.source))
    return _safe(sensor.vendor)


def sensor_name(sensor: Any) -> str:
    """The ``sensor`` column/field value: its serial, else its source address, else its vendor."""
    return str(sensor.serial or sensor.source or sensor.vendor)
