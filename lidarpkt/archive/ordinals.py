"""Whole-file ordinals for the segments of a capture: VLP-16 ``frame_id`` and ``packet_index``.

An Ouster frame id comes from its packets, but a VLP-16 ``frame_id`` is an ordinal (the n-th
rotation of its stream) and ``extra["packet_index"]`` the n-th packet of the file; a segment's
reader counts both from where it starts reading. A segment unit runs on its own (elsewhere,
resumed after a kill) and its outputs are never rewritten, so it must know, before it starts,
how many frames of each VLP-16 stream and how many packets lie in the segments before it.

The count pass (:func:`count_segment`, one picklable task per segment, run on the engine like the
units) reads each segment with the very reader a unit uses (``lidarpkt.open(path,
segment=...)``), so the frames it counts are, by construction, the frames that unit writes:
:class:`~lidarpkt.containers.segments.SegmentOwnership` gives every frame exactly one segment, and
the whole file's ordinal of a segment's i-th frame of a stream is the sum of the earlier
segments' frames of that stream plus i (what :mod:`lidarpkt.pipeline.parallel` does in one process). It
reads without Ouster metadata: Ouster packets are then counted as foreign traffic, not decoded
(their frame ids need no count), so the pass costs reading the packets and decoding the VLP-16 ones.
Its cost is that of one decode of the VLP-16 data of the segments before the last (a full
export costs several times that: XYZ, encoding, compression).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any, Sequence


from lidarpkt.errors import LidarpktError, LidarpktWarning, UnknownSensorError

from .plan import local_path


@dataclass(frozen=True)
class CountTask:
    """One segment to count (picklable). ``key``: the segment's unit key; ``open_options``: the job's
    other keyword options of ``lidarpkt.open`` (``model`` ...), as sorted ``(name, value)`` pairs."""

    key: str
    input: str
    segment: Any
    open_options: tuple[tuple[str, Any], ...] = ()


@dataclass(frozen=True)
class SegmentCount:
    """What one segment holds: ``frames`` as sorted ``(VLP-16 stream source, frames)`` pairs,
    ``packets`` the packets before its end (the reader's ``split_ordinal``), ``rates`` per VLP-16
    stream the ``(frequency_hz, columns_per_frame)`` its decoder measured from its first packets,
    ``error`` why the segment could not be counted (None when it was)."""

    key: str
    frames: tuple[tuple[str, int], ...] = ()
    packets: int = 0
    error: str | None = None
    rates: tuple[tuple[str, float | None, int], ...] = ()


@dataclass(frozen=True)
class Ordinals:
    """Where a segment's ordinals start in the whole file (picklable; a field of a unit task).

    Attributes:
        frame_id: per VLP-16 stream (``str(SensorInfo.source)``), the whole-file ``frame_id`` of
            the segment's first frame of that stream; a stream not listed starts at 0.
        packet_index: the whole-file ordinal of the segment's first packet.
        rates: per VLP-16 stream, ``(frequency_hz, columns_per_frame)`` of the stream's
            :class:`~lidarpkt.core.sensor.SensorInfo` in the whole file: a decoder measures the rate
            from the first packets it reads, and the whole file's are those of the segment where
            the stream starts (as :mod:`lidarpkt.pipeline.parallel` keeps the first segment's SensorInfo).
    """

    frame_id: tuple[tuple[str, int], ...] = ()
    packet_index: int = 0
    rates: tuple[tuple[str, float | None, int], ...] = ()


def count_segment(task: CountTask) -> SegmentCount:
    """The VLP-16 frames (per stream) and packets of one segment; bad input is the result's ``error``."""
    from lidarpkt.pipeline.reader import open_frames
    from lidarpkt.vendors import registry

    frames: dict[str, int] = {}
    rates: dict[str, tuple[float | None, int]] = {}
    reader = None
    error = None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", LidarpktWarning)  # the unit reports them
            reader = open_frames(local_path(task.input), segment=task.segment, **dict(task.open_options))
            for frame in reader:
                if registry.vendor(frame.sensor.vendor).frame_ids_counted:  # frame ids counted from the start
                    source = str(frame.sensor.source)
                    frames[source] = frames.get(source, 0) + 1
                    rates.setdefault(source, (frame.sensor.frequency_hz, frame.sensor.columns_per_frame))
    except UnknownSensorError:
        pass  # no VLP-16 data in this segment (Ouster, foreign traffic): nothing to count
    except (LidarpktError, OSError) as exc:
        error = f"{task.input}: {exc}"
    finally:
        if reader is not None:
            reader.close()
    split = getattr(getattr(reader, "reader", None), "split_ordinal", None)
    if error is None and split is None and task.segment.index < task.segment.count - 1:
        error = f"{task.input}: the reader of {task.key} stopped before the segment's end"
    return SegmentCount(task.key, tuple(sorted(frames.items())), int(split or 0), error,
                        tuple(sorted((k, *v) for k, v in rates.items())))


def start_ordinals(counts: Sequence[SegmentCount]) -> list[Ordinals | str]:
    """For segments 0..n of a capture, given the counts of segments 0..n-1 (in order): each one's
    :class:`Ordinals`, or the error of the first earlier segment that could not be counted."""
    out: list[Ordinals | str] = [Ordinals()]
    frame_id: dict[str, int] = {}
    rates: dict[str, tuple] = {}
    packets = 0
    for c in counts:
        if c.error is not None or isinstance(out[-1], str):
            out.append(out[-1] if isinstance(out[-1], str) else
                       f"{c.error}; the frame ids of the segments after {c.key} depend on it")
            continue
        for source, n in c.frames:
            frame_id[source] = frame_id.get(source, 0) + n
        for source, hz, width in c.rates:
            rates.setdefault(source, (source, hz, width))  # the segment where the stream starts
        packets += c.packets
        out.append(Ordinals(tuple(sorted(frame_id.items())), packets, tuple(sorted(rates.values()))))
    return out


def renumber_from(start: Ordinals | None) -> Any:
    """The :class:`lidarpkt.pipeline.parallel.Renumber` that gives a segment unit's frames the whole file's
    VLP-16 ordinals and rate, from where the segment starts (``start``)."""
    from lidarpkt.pipeline.parallel import Renumber

    start = start or Ordinals()
    return Renumber(dict(start.frame_id), start.packet_index,
                    {source: (hz, width) for source, hz, width in start.rates})
