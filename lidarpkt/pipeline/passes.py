"""One pass over a capture: its frames and, when asked, the packet batches they were decoded from.

:func:`open_pass` reads a capture once and yields, in order, each packet batch read (a
:class:`~lidarpkt.pipeline.reader.Packets`: the batch and what the router made of it) followed by the
frames that batch completed: what the writers take (:func:`lidarpkt.writers.write_captures`), so that
an output holding raw packets and frames (an MCAP of ``packets,points``) costs one read of the capture.
Without packets it is ``lidarpkt.open``'s frames, whatever ``workers`` chooses.

With packets, ``workers`` ≥ 2 decodes in a thread of its own ahead of the caller (the pipeline of
:class:`~lidarpkt.pipeline.parallel.PipelinedFrameReader`, batches and frames in one queue bounded in
bytes): segments decoded side by side would hand the packets out of order.
"""

from __future__ import annotations

import dataclasses
import os
from typing import TYPE_CHECKING, Any, Iterator

from lidarpkt.core.frame import Frame

from .options import OpenOptions, with_options
from .reader import FrameReader, Packets, open_frames

if TYPE_CHECKING:
    from typing_extensions import Unpack

    from .options import OpenKeywords
    from .reader import SourceStats


class Capture:
    """The input of a pass, as writers are told of it (``begin_capture`` / ``end_capture``).

    Attributes:
        path: the capture as it was given (a path or its text).
        container: ``"pcap"`` (pcap or pcapng), ``"mcap"``, ``"rosbag2"``, ``"rosbag1"`` or ``"osf"``.
    """

    def __init__(self, path: str | os.PathLike[str], container: str, frames: Any) -> None:
        self.path = path
        self.container = container
        self._frames = frames  # the FrameReader (or OSF reader) of the pass

    @property
    def metadata(self) -> list:
        """The loaded sensor metadata the packets are recognised with (Ouster metadata, one per sensor): those
        given, else the one the capture records (known once the pass has read its first batch); empty when the
        sensors need none."""
        router = getattr(self._frames, "router", None)
        return list(router.options.ouster_metadata) if router is not None else []

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
        """An OSF file's first and last frame receive times (ns), read from the file; ``None`` for captures
        of packets (their packets' capture times are handed in the pass)."""
        if self.container != "osf":
            return None
        from lidarpkt.vendors.ouster.osf import receive_span

        return receive_span(self.path)


class CapturePass:
    """One pass over a capture (:func:`open_pass`): iterate it for :class:`~lidarpkt.core.frame.Frame` and
    :class:`~lidarpkt.pipeline.reader.Packets` items in capture order; ``capture`` describes it;
    ``reader`` is the frame reader (its ``stats`` complete at the end). ``close()`` (or ``with``) stops
    it early."""

    def __init__(self, path: str | os.PathLike[str], packets: bool, options: OpenOptions, decode: bool = True) -> None:
        from lidarpkt.containers.magic import container_kind

        from .parallel import PipelinedFrameReader, check_workers

        container = container_kind(path)
        if not packets or container == "osf":  # an OSF file holds frames only
            self.reader: Any = open_frames(path, **options.keywords())
        else:
            check_workers(options.workers)
            self.reader = FrameReader(path, **dataclasses.replace(options, workers=1).keywords())
            self.reader.items(decode)  # iterating the reader now yields the batches too
            if options.workers != 1 and options.segment is None:
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
