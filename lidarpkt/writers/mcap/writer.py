"""The MCAP file lidarpkt writes: ROS 2 profile, zstd chunks sized by time, rotation.

A :class:`McapWriter` takes encoded messages for the topics of :mod:`lidarpkt.writers.mcap.schemas` and
writes them as the ``mcap`` library's writer does (with :class:`~lidarpkt.writers.mcap.chunks.ChunkWriter`,
which holds messages by reference until their chunk is written): profile ``ros2``, schemas in
``ros2msg``, messages in ``cdr``, each channel carrying ``offered_qos_profiles`` (so that ``ros2 bag
play`` accepts the file), zstd-compressed chunks, and at :meth:`close` a summary with statistics, chunk
and message indexes.

Chunks are closed by *time* (``chunk_seconds`` of wall clock, default 0.5 s) as well as by
size, and each closed chunk is handed to the operating system at once: if the process is
killed, the file is readable up to its last complete chunk, so at most about
``chunk_seconds`` of data is lost. With rotation (``rotate_bytes`` / ``rotate_seconds``)
the output is ``STEM_0000.mcap``, ``STEM_0001.mcap`` …; every file is complete on its own
(metadata records and latched topics such as ``/ouster/metadata`` are written again).

Errors: :class:`lidarpkt.errors.DiskFullError` when the disk is full (what was written is
readable up to the last complete chunk), :class:`lidarpkt.errors.OutputError` for other
write failures.
"""

from __future__ import annotations

import errno
import os
import time
from functools import partial
from pathlib import Path
from typing import BinaryIO, Callable

from lidarpkt.errors import DiskFullError, OutputError

from lidarpkt.containers import rosmsgs

from . import schemas
from lidarpkt.core.ros import Topic

from .chunks import ChunkWriter, Data

LIBRARY = "lidarpkt recorder"

#: Chunk compression of a file that holds frames (point clouds, images), chosen for speed: none. Organised
#: float32 clouds barely shrink under a fast codec, and compressing them costs more CPU than writing the
#: bytes saved (measured in the documentation's performance page). Files of packets alone keep zstd: raw
#: packets shrink more, and arrive at packet rate. ``mcap compress`` (the mcap CLI) compresses a file
#: afterwards where its size matters more than the time.
FRAMES_COMPRESSION = "none"


class McapWriter:
    """Writes ROS 2 MCAP, chunked by time, optionally rotated.

    Args:
        path: output file (``.mcap``). With rotation, files are named ``STEM_NNNN.mcap``
            beside it.
        chunk_seconds: close a chunk once its first message is this old (wall clock).
        chunk_bytes: close a chunk once its uncompressed size exceeds this.
        compression: ``"zstd"`` (default), ``"lz4"`` or ``"none"``.
        rotate_bytes / rotate_seconds: start a new file once the current one is this large /
            old (checked between chunks). ``None`` = never.
        clock: wall clock in seconds (tests pass a fake one).
        sync: flush each finished file to the disk (``fsync``) before going on: a recording's closed files
            survive a power loss. ``False`` for an output that can be made again (``lidarpkt decode``), as the
            other writers leave it to the system.
        chunk_crcs: give each chunk the CRC-32 of its records, with which readers check it. ``False``: 0,
            "not computed" in the MCAP specification (readers check nothing), for an output that can be made
            again whose uncompressed chunks are mostly point clouds (the CRC would read every byte once more).

    Raises:
        OutputError: the file cannot be created (with the reason).
    """

    _writer: ChunkWriter  # the records of the current file (from the first _open_next on)

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        chunk_seconds: float = 0.5,
        chunk_bytes: int = 1 << 20,
        compression: str = "zstd",
        rotate_bytes: int | None = None,
        rotate_seconds: float | None = None,
        clock: Callable[[], float] = time.monotonic,
        sync: bool = True,
        chunk_crcs: bool = True,
    ) -> None:
        self.path = Path(path)
        self.chunk_seconds = chunk_seconds
        self.chunk_bytes = chunk_bytes
        self._compression = {"zstd": "zstd", "lz4": "lz4", "none": ""}[compression]
        self.rotate_bytes = rotate_bytes
        self.rotate_seconds = rotate_seconds
        self._clock = clock
        self._sync = bool(sync)
        self._chunk_crcs = bool(chunk_crcs)
        self.files: list[Path] = []
        self.messages_written = 0
        self._bytes_closed_files = 0
        self._metadata: list[tuple[str, dict[str, str]]] = []
        self._latched: dict[tuple[str, str], tuple[Topic, bytes, int]] = {}  # (topic, key): latest
        self._file: BinaryIO | None = None  # the current file; None once finished
        self._closed = False
        self._open_next()

    # ------------------------------------------------------------------ files
    def _next_path(self) -> Path:
        if self.rotate_bytes is None and self.rotate_seconds is None:
            return self.path
        stem = self.path.name[:-5] if self.path.name.endswith(".mcap") else self.path.name
        return self.path.with_name(f"{stem}_{len(self.files):04d}.mcap")

    def _open_next(self) -> None:
        path = self._next_path()
        try:
            self._file = open(path, "wb", buffering=0)  # unbuffered: the chunk writer gathers its writes
        except OSError as exc:
            raise OutputError(f"cannot create the MCAP output {path}: {exc.strerror or exc}") from exc
        self.files.append(path)
        self._writer = ChunkWriter(self._file, chunk_size=self.chunk_bytes, compression=self._compression,
                                   chunk_crcs=self._chunk_crcs)
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._opened_at = self._clock()
        self._chunk_started: float | None = None
        self._guard(lambda: self._writer.start(profile="ros2", library=LIBRARY))
        for name, fields in self._metadata:
            self._guard(partial(self._writer.add_metadata, name, fields))
        for topic, data, log_time in self._latched.values():
            self._add(topic, data, log_time)
        self._guard(self._flush_chunk)

    def _guard(self, action: Callable[[], object]) -> object:
        try:
            return action()
        except OSError as exc:
            self._abandon()
            where = self.files[-1] if self.files else self.path
            if exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
                raise DiskFullError(
                    f"no space left while writing {where} ({self.messages_written} messages written); free some "
                    "space or write elsewhere (a recording keeps what it wrote, readable up to its last complete chunk)"
                ) from exc
            raise OutputError(f"writing {where} failed: {exc.strerror or exc}") from exc

    def _abandon(self) -> None:
        """Stop writing after a failed write: close the file without a summary (still readable)."""
        self._closed = True
        if self._file is not None:
            try:
                self._file.close()
            except OSError:
                pass

    @property
    def bytes_written(self) -> int:
        """Bytes on disk so far over all files (closed chunks only for the current file)."""
        current = self._file.tell() if self._file is not None and not self._file.closed else 0
        return self._bytes_closed_files + current

    # ---------------------------------------------------------------- records
    def _channel(self, topic: Topic) -> int:
        cid = self._channels.get(topic.name)
        if cid is None:
            sid = self._schemas.get(topic.msgtype)
            if sid is None:
                sid = self._writer.register_schema(topic.msgtype, "ros2msg",
                                                   schemas.schema_text(topic.msgtype).encode())
                self._schemas[topic.msgtype] = sid
            cid = self._writer.register_channel(topic.name, "cdr", sid,
                                                {"offered_qos_profiles": topic.qos})
            self._channels[topic.name] = cid
        return cid

    def _add(self, topic: Topic, data: Data, log_time_ns: int, publish_time_ns: int | None = None) -> None:
        cid = self._channel(topic)
        self._writer.add_message(cid, log_time=int(log_time_ns), data=data,
                                 publish_time=int(log_time_ns if publish_time_ns is None else publish_time_ns))
        self.messages_written += 1
        if self._chunk_started is None:
            self._chunk_started = self._clock()

    def write(self, topic: Topic, data: Data, log_time_ns: int, publish_time_ns: int | None = None) -> None:
        """Write one CDR message on ``topic`` (its bytes, or its pieces in order, held until its chunk is
        written); log time = host receive time (ns since the epoch)."""
        if self._closed:
            raise OutputError(f"{self.path} is closed")
        self._guard(lambda: self._add(topic, data, log_time_ns, publish_time_ns))
        self.tick()

    def write_message(self, topic: Topic, message: object, log_time_ns: int) -> None:
        """Encode a rosbags message object of ``topic.msgtype`` and write it. A ``PointCloud2``'s points are
        written from its ``data`` array (held until its chunk is written: the caller must not change it)."""
        if topic.msgtype == schemas.POINTCLOUD2:
            from .pointcloud import pointcloud_cdr

            self.write(topic, pointcloud_cdr(message), log_time_ns)
            return
        self.write(topic, rosmsgs.encode(topic.msgtype, message), log_time_ns)

    def write_latched(self, topic: Topic, data: bytes, log_time_ns: int, *, key: str = "") -> None:
        """Write a message that every rotated file must start with (``/ouster/metadata``, ``/tf_static``).

        ``key`` names what the message is about (a sensor, a frame id): the latest message of each
        (topic, key) starts every later file, so that with several sensors each one's is kept."""
        self._latched[(topic.name, key)] = (topic, data, log_time_ns)
        self.write(topic, data, log_time_ns)

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """An MCAP Metadata record (string → string); repeated in every rotated file."""
        data = {str(k): str(v) for k, v in data.items()}
        self._metadata.append((name, data))
        if not self._closed:
            self._guard(lambda: self._writer.add_metadata(name, data))

    def _flush_chunk(self) -> None:
        self._writer.flush()  # closes the chunk (with its message indexes) and hands it to the OS
        self._chunk_started = None

    def tick(self) -> None:
        """Close the chunk if it is ``chunk_seconds`` old, rotate if due. Call it at least a few
        times a second when no message arrives, so that the last messages reach the disk."""
        if self._closed:
            return
        now = self._clock()
        if self._chunk_started is not None and now - self._chunk_started >= self.chunk_seconds:
            self._guard(self._flush_chunk)
        if self._chunk_started is None and self._rotation_due(now):
            self._rotate()

    def _rotation_due(self, now: float) -> bool:
        if self.rotate_bytes is not None and self._file is not None and self._file.tell() >= self.rotate_bytes:
            return True
        return self.rotate_seconds is not None and now - self._opened_at >= self.rotate_seconds

    def _rotate(self) -> None:
        self._finish_current()
        self._open_next()

    def _finish_current(self) -> None:
        fh = self._file
        if fh is None:  # finished already
            return

        def finish() -> None:
            self._writer.finish()
            fh.flush()
            if self._sync:
                os.fsync(fh.fileno())

        self._guard(finish)
        self._bytes_closed_files += fh.tell()
        fh.close()
        self._file = None

    def close(self) -> None:
        """Write the summary and indexes, and close. Safe to call twice."""
        if self._closed:
            return
        self._finish_current()
        self._closed = True

    def __enter__(self) -> "McapWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
