"""One pass over a capture: its frames and, when asked, the packet batches they were decoded from.

:func:`open_pass` reads a capture once and yields, in order, each packet batch read (a
:class:`~lidarpkt.pipeline.reader.Packets`: the batch and what the router made of it) followed by the
frames that batch completed: what the writers take (:func:`lidarpkt.writers.write_captures`), so that
an output holding raw packets and frames (an MCAP of ``packets,points``) costs one read of the capture.
Without packets it is ``lidarpkt.open``'s frames, whatever ``workers`` chooses.

With packets, ``workers`` ≥ 2 (or ``None`` where :func:`~lidarpkt.pipeline.parallel.default_workers` gives
2 or more) decodes in a thread of its own ahead of the caller (the pipeline of
:class:`~lidarpkt.pipeline.parallel.PipelinedFrameReader`, batches and frames in one queue bounded in
bytes): segments decoded side by side would hand the packets out of order.
"""

from __future__ import annotations

import dataclasses
import os
from typing import TYPE_CHECKING, Any, Iterator

from lidarpkt.containers.magic import FRAME_CONTAINERS
from lidarpkt.core.frame import Frame

from .options import OpenOptions, with_options
from .reader import FrameReader, Packets, open_frames

if TYPE_CHECKING:
    from typing_extensions import Unpack

    from .options import OpenKeywords
    from lidarpkt.core.streams import SourceStats


class Capture:
    """The input of a pass, as writers are told of it (``begin_capture`` / ``end_capture``).

    Attributes:
        path: the capture as it was given (a path or its text).
        container: what :func:`lidarpkt.containers.magic.container_kind` says of it (``"pcap"``, ``"mcap"``...;
            one of :data:`~lidarpkt.containers.magic.FRAME_CONTAINERS` for a file of decoded frames).
    """

    def __init__(self, path: str | os.PathLike[str], container: str, frames: Any) -> None:
        self.path = path
        self.container = container
        self._frames = frames  # the FrameReader (or OSF reader) of the pass

    @property
    def sensor_files(self) -> list:
        """The sensor files the packets are recognised with (:class:`lidarpkt.vendors.registry.SensorFile`, one
        per sensor): those given, and one the capture records (known once the pass has read its first batch)
        where none of its vendor's was given; empty when the sensors need none."""
        return list(getattr(self._frames, "sensor_files", ()))

    @property
    def stats(self) -> SourceStats:
        """What the pass routed where (complete once it has ended)."""
        return self._frames.stats

    @property
    def bytes_read(self) -> int | None:
        """File bytes read so far (pcap/pcapng), ``None`` when the container does not say."""
        stats = getattr(getattr(self._frames, "reader", None), "stats", None)
        return getattr(stats, "bytes_read", None)

    def receive_span(self) -> tuple[int | None, int | None] | None:
        """A file of decoded frames' first and last frame receive times (ns), read from the file (its vendor's
        :attr:`~lidarpkt.core.vendor.FrameFiles.receive_span`); ``None`` for captures of packets (their packets'
        capture times are handed in the pass)."""
        if self.container not in FRAME_CONTAINERS:
            return None
        from lidarpkt.vendors import registry

        files = registry.frame_files(self.path)
        return files.receive_span(self.path) if files is not None else None


class CapturePass:
    """One pass over a capture (:func:`open_pass`): iterate it for :class:`~lidarpkt.core.frame.Frame` and
    :class:`~lidarpkt.pipeline.reader.Packets` items in capture order; ``capture`` describes it;
    ``reader`` is the frame reader (its ``stats`` complete at the end). ``close()`` (or ``with``) stops
    it early."""

    def __init__(self, path: str | os.PathLike[str], packets: bool, options: OpenOptions, decode: bool = True) -> None:
        from lidarpkt.containers.magic import container_kind

        from .parallel import PipelinedFrameReader, check_workers, default_workers

        container = container_kind(path)
        if not packets or container in FRAME_CONTAINERS:  # a file of decoded frames holds no packets
            self.reader: Any = open_frames(path, **options.keywords())
        else:
            workers = check_workers(options.workers)
            self.reader = FrameReader(path, **dataclasses.replace(options, workers=1).keywords())
            self.reader.items(decode)  # iterating the reader now yields the batches too
            if workers is None and options.segment is None:
                workers = default_workers(path)
            if workers != 1 and options.segment is None:
                self.reader = PipelinedFrameReader(self.reader)
        frames = self.reader.reader if isinstance(self.reader, PipelinedFrameReader) else self.reader
        self.capture = Capture(path, container, frames)
        self._iter: Iterator[Frame | Packets] = iter(self.reader)

    @property
    def stats(self) -> SourceStats:
        return self.reader.stats

    def __iter__(self) -> Iterator[Frame | Packets]:
        return self._iter

    def __next__(self) -> Frame | Packets:
        return next(self._iter)

    def close(self) -> None:
        """Stop reading (threads and files). Idempotent."""
        self.reader.close()

    def __enter__(self) -> CapturePass:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@with_options
def open_pass(path: str | os.PathLike[str], *, packets: bool = True, decode: bool = True,
              **options: Unpack[OpenKeywords]) -> CapturePass:
    """One pass over a capture: its frames and, with ``packets``, every packet batch before the frames it
    completed (see the module doc).

    Args:
        path: as ``lidarpkt.open`` takes it.
        packets: hand the packet batches too (``False``: ``lidarpkt.open``'s frames only).
        decode: with ``packets``, ``False`` hands the batches alone (classified, not decoded: no frames, and
            no error for a capture of no known sensor).
        {options}

    Raises:
        What ``lidarpkt.open`` raises, on opening and while iterating.
    """
    return CapturePass(path, packets, OpenOptions.from_keywords("open_pass", dict(options)), decode)
