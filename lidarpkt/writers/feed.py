"""Captures into writers, one pass each: what ``lidarpkt decode`` and an archive's unit of work run.

>>> from lidarpkt.writers import open_writer, write_captures              # doctest: +SKIP
>>> with open_writer("mcap", "out.mcap", topics=("packets", "points")) as w:
...     write_captures(["drive1.pcap", "drive2.pcap"], [w])

Each capture is read once (:func:`lidarpkt.pipeline.passes.open_pass`): its frames go to every writer's
``write``, and, when a writer takes them (``wants_packets``), its packet batches with what the router made
of them go to its ``write_packets`` as they are read, before the frames they completed; ``begin_capture``
and ``end_capture`` frame each capture (:mod:`lidarpkt.writers.base`). Progress is reported as the pass
reads.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any, Callable, Sequence

from lidarpkt.pipeline.options import with_options
from lidarpkt.pipeline.passes import CapturePass, open_pass
from lidarpkt.pipeline.reader import Packets

if TYPE_CHECKING:
    from typing_extensions import Unpack

    from lidarpkt.core.frame import Frame
    from lidarpkt.pipeline.options import OpenKeywords

Progress = Callable[[int | None, int], None]  # (bytes of the captures read so far or None, frames so far)


class Feed:
    """Captures into writers, one pass each (see the module doc); the counts add up over the captures.

    Args:
        progress: called as each pass goes with (bytes of the captures read so far, ``None`` when the
            container does not say; frames so far).
        map_frame: applied to each frame before the writers see it (an archive segment's whole-file
            ordinals).

    Attributes:
        frames: frames handed to the writers.
        lost_packets, malformed_packets: the frames' counters, summed.
        bytes_done: sizes of the capture files done.
        last: the :class:`~lidarpkt.pipeline.passes.CapturePass` of the last capture begun (its
            ``reader.stats`` and ``capture``), also after an error.
    """

    def __init__(self, *, progress: Progress | None = None, map_frame: Callable[[Frame], Frame] | None = None) -> None:
        self.progress = progress
        self.map_frame = map_frame
        self.frames = 0
        self.lost_packets = 0
        self.malformed_packets = 0
        self.bytes_done = 0
        self.last: CapturePass | None = None

    @with_options
    def write(self, path: str | os.PathLike[str], writers: Sequence[Any], **options: Unpack[OpenKeywords]) -> None:
        """One pass over ``path`` into ``writers`` (which stay open: the caller closes them).

        Args:
            path: a capture, as ``lidarpkt.open`` takes it.
            writers: frame writers (:func:`lidarpkt.writers.open_writer`); those whose ``wants_packets`` is
                true get the packets too.
            {options}

        Raises:
            What ``lidarpkt.open`` raises, and what the writers raise; the frames and packets handed before
            are in the writers.
        """
        takers = [w.write_packets for w in writers if getattr(w, "wants_packets", False)]
        decode = not takers or any(getattr(w, "wants_frames", True) for w in writers)
        progress, map_frame = self.progress, self.map_frame
        with open_pass(path, packets=bool(takers), decode=decode, **options) as run:
            self.last = run
            capture = run.capture
            for w in writers:
                getattr(w, "begin_capture", _nothing)(capture)
            for item in run:
                if isinstance(item, Packets):
                    for take in takers:
                        take(item.batch, item.stream)
                else:
                    frame = item if map_frame is None else map_frame(item)
                    for w in writers:
                        w.write(frame)
                    self.frames += 1
                    counters = frame.counters
                    self.lost_packets += counters.lost_packets
                    self.malformed_packets += counters.malformed_packets
                if progress is not None:
                    done = capture.bytes_read
                    progress(None if done is None else self.bytes_done + done, self.frames)
            for w in writers:
                getattr(w, "end_capture", _nothing)(capture)
        self.bytes_done += os.path.getsize(path) if os.path.isfile(path) else 0


def _nothing(capture: Any) -> None:
    """What a writer without ``begin_capture`` / ``end_capture`` does."""


@with_options
def write_captures(inputs: Sequence[str | os.PathLike[str]], writers: Sequence[Any], *,
                   progress: Progress | None = None, **options: Unpack[OpenKeywords]) -> Feed:
    """Every capture of ``inputs``, in order, into the same ``writers``, one pass each (see the module doc).

    Args:
        inputs: captures, as ``lidarpkt.open`` takes them.
        writers: frame writers (:func:`lidarpkt.writers.open_writer`), left open: the caller closes them
            (``with`` blocks), which writes their files.
        progress: see :class:`Feed`.
        {options}

    Returns:
        the :class:`Feed`, with its counts.

    Raises:
        What ``lidarpkt.open`` raises, and what the writers raise.
    """
    feed = Feed(progress=progress)
    for path in inputs:
        feed.write(path, writers, **options)
    return feed
