"""From a capture file to frames: container detection, stream routing, one decoder per sensor.

``lidarpkt.open(path)`` is :func:`open_frames`. The container (pcap, pcapng, MCAP,
rosbag2, ROS 1 bag) is recognised by its first bytes, not its name. Every batch of
packets is routed by what it is (the vendor registry's classifier: a vendor's stream, decoded
with the sensor files given where its sensors need one) and by its source, so that several
sensors in one file each get their own decoder. Streams that are none of these are
counted, not decoded. A file of decoded frames a vendor records (OSF) gives that vendor's
reader of its frames.
"""

from __future__ import annotations

import dataclasses
import os
import weakref
from pathlib import Path
from typing import TYPE_CHECKING, Any, Generator, Iterator, NamedTuple, cast

import numpy as np

from lidarpkt.containers.protocol import PacketSource
from lidarpkt.core.decoder import Decoder
from lidarpkt.core.dropped import DropCounts, format_dropped
from lidarpkt.core.frame import Frame
from lidarpkt.core.heap import keep_freed_arrays
from lidarpkt.core.packet import PacketBatch
from lidarpkt.core.readahead import warn  # warnings.warn, or handed to the caller's thread when decoding ahead
from lidarpkt.core.sequence import FrameIterator
from lidarpkt.core.streams import OTHER_STREAMS, SourceStats, UnroutedStream
from lidarpkt.core.vendor import DecodeSetup, Match
from lidarpkt.core.rotation import rate_disagreement
from lidarpkt.errors import (DroppedPacketsWarning, LidarpktWarning, MetadataError, SkippedPacketWarning, UnknownSensorError,
                             UnsupportedContainerError, UnusedSensorFileWarning)
from lidarpkt.vendors import registry
from .options import OpenOptions, with_options
from .router import MAX_SENSORS, Router, source_name as _source_name

if TYPE_CHECKING:
    from typing_extensions import Unpack  # typing.Unpack is Python 3.11+

    from lidarpkt.core.readahead import ReadAhead
    from lidarpkt.core.vendor import FrameFiles
    from .options import OpenKeywords

_MAX_LISTED_STREAMS = 1000  # unrouted streams named one by one in SourceStats; the rest are summed


class FrameReader(FrameIterator):
    """Iterator of :class:`Frame` over one capture; ``stats``, ``decoders`` and ``reader`` show what happened.

    Made by :func:`open_frames` (``lidarpkt.open``). Frames come out when their last packet has
    been read, so memory stays bounded whatever the length of the capture.

    Read-ahead (``read_ahead``): for pcap/pcapng captures of at least
    :data:`READ_AHEAD_MIN_BYTES`, the packets are read by a background thread into a queue
    bounded in bytes (:data:`lidarpkt.core.readahead.DEFAULT_MAX_BYTES`) while this thread routes
    and decodes; file reads and NumPy copies release the GIL, so the two overlap on two cores.
    Frames, their order and ``stats`` are those of the unthreaded path; the reader's errors
    are raised and its warnings re-emitted (same category and message) here, at the same point
    of the stream. ``reader.stats`` (the packet reader's own counters) may run ahead of the
    frames while iterating; it is complete at the end. ``close()`` (or ``with``, or dropping
    the reader) stops the thread.
    """

    @with_options
    def __init__(self, path: str | os.PathLike[str], **options: Any) -> None:
        """Open ``path`` (as :func:`open_frames`); reading starts on the first ``next()``.

        Args:
            path: pcap/pcapng file, MCAP file, rosbag2 directory or ``.db3``, or ROS 1 ``.bag``.
            {options}

        Raises:
            ValueError: ``workers`` is neither 1 nor None (``lidarpkt.open(path, workers=N)`` decodes in N).
            And what :func:`open_frames` raises on opening.
        """
        opts = OpenOptions.from_keywords("FrameReader", options)
        if opts.workers not in (None, 1):
            raise ValueError("FrameReader decodes in one thread; lidarpkt.open(path, workers=N) decodes in N")
        keep_freed_arrays()  # the arrays of each batch and frame, made again and again
        self.path = Path(path)
        self.segment = segment = opts.segment
        self._ownership = None
        filters = opts.filters()  # None: the reader's default
        if segment is not None:
            from lidarpkt.containers.segments import SegmentOwnership

            if segment.container not in ("pcap", "pcapng") and segment.count != 1:
                raise UnsupportedContainerError(f"{self.path}: a {segment.container} file is read whole (one segment)")
            if segment.count > 1:
                self._ownership = SegmentOwnership(segment)
                filters["segment"] = segment
        self.sensor_files, setup = opts.sensor_setup()  # before opening: a bad file says so first
        if segment is not None and not segment.first:  # what sensors send in-band, the segment may start past
            in_band = registry.sensor_files_in_packets(path, setup)  # the capture's own: not files given
            setup = registry.setup([*self.sensor_files, *in_band], opts.decoding()) if in_band else setup
        self.reader: PacketSource = registry.open_packets(path, **filters)
        self.read_ahead = _want_read_ahead(self.reader, opts.read_ahead)
        self._read_ahead: ReadAhead[PacketBatch] | None = None  # the running ReadAhead, if any
        self._decoding = opts.decoding()
        self._recorded_wanted = True  # a sensor file recorded in the capture is still to be looked for
        self._include_partial, self._rates_checked = opts.include_partial, set[Any]()
        self.driver = Driver(str(self.path), setup, max_sensors=opts.max_sensors, source=opts.source,
                             ownership=self._ownership, sensor_files=self.sensor_files)
        self.stats = self.driver.stats
        self.router = self.driver.router
        # the generator holds a weak proxy, not self: dropping the last reference to the reader
        # finalises it at once (no cycle left to the garbage collector), which stops the thread
        self._iter: Generator[Frame, None, None] = cast("Generator[Frame, None, None]",
                                                        FrameReader._frames(weakref.proxy(self)))  # frames only

    def items(self, decode: bool = True) -> Generator[Frame | Packets, None, None]:
        """The pass as it goes, instead of iterating the reader: each batch read, as :class:`Packets` (with
        what the router made of it), then the frames that batch completed; the last frames at the end.
        ``decode=False``: the batches alone, classified but not decoded (no frames, no error for a capture
        without a sensor). Call it before the first ``next()``; ``close()`` stops it as it stops the frames."""
        self._iter.close()  # not started: nothing is lost
        items = FrameReader._frames(weakref.proxy(self), packets=True, decode=decode)
        self._iter = cast("Generator[Frame, None, None]", items)  # close() ends whichever generator runs
        return items

    def close(self) -> None:
        """Stop reading: the read-ahead thread, if any, stops and the file is closed. Idempotent."""
        self._iter.close()
        ra, self._read_ahead = self._read_ahead, None
        if ra is not None:
            ra.close()

    def __del__(self) -> None:
        ra = getattr(self, "_read_ahead", None)
        if ra is not None:
            ra.close()

    # ------------------------------------------------------------------ routing
    def _batches(self) -> Iterator[PacketBatch]:
        if not self.read_ahead:
            return self.reader.batches()
        from lidarpkt.core.readahead import ReadAhead

        self._read_ahead = ReadAhead(self.reader.batches)
        return self._read_ahead

    @property
    def decoders(self) -> dict[tuple, Decoder]:
        """(vendor, source address, ...) → the decoder of that sensor, in order of first packet."""
        return self.router.decoders

    def drop_counts(self) -> DropCounts:
        """Packets dropped so far, by reason (each vendor's reasons, :attr:`~lidarpkt.core.vendor.Vendor.drops`)."""
        return self.driver.drop_counts()

    def _take_recorded_file(self) -> None:
        """A sensor file recorded inside the capture (an MCAP's, a bag's) serves when none of its vendor's was
        given."""
        text = self.reader.recorded_sensor_file()
        if text is None:
            return
        self._recorded_wanted = False
        recorded = registry.load_sensor_files([text])[0]
        if not self.router.setup.files(recorded.vendor):
            self.sensor_files.append(recorded)
            self.router.setup = registry.setup(self.sensor_files, self._decoding)

    def _frames(self, packets: bool = False, decode: bool = True) -> Generator[Frame | Packets, None, None]:
        batches = self._batches()
        ownership = self._ownership
        try:
            for batch in batches:
                if self._recorded_wanted:
                    self._take_recorded_file()
                split = getattr(self.reader, "split_ordinal", None)
                post_end = split is not None and int(batch.index[0]) >= split
                match, frames = self.driver.route(batch, post_end) if decode else (self.driver.classify(batch), [])
                if packets:
                    yield Packets(batch, match)  # items(): the batch before its frames
                yield from FrameReader._emit(self, frames)  # self: the weak proxy
                if ownership is not None and ownership.done(post_end):
                    break  # a segment: nothing further belongs to it
        finally:
            getattr(batches, "close", lambda: None)()  # stops the read-ahead thread (or closes the reader's generator) however we leave
        if not decode:
            return
        for key, decoder in list(self.decoders.items()):
            frames = decoder.finish()
            yield from FrameReader._emit(self, frames if ownership is None else ownership.finish(key, frames))
        if self.stats.packets and not self.decoders:
            raise UnknownSensorError(self.driver.no_sensor_message())
        if not self.stats.lidar_packets:
            wrong = registry.undecoded_hint(self.path, self.stats.unrouted_streams, self.router.setup)
            if wrong:  # a vendor's lidar packets without (fitting) sensor file: say so, not "no frames"
                raise UnknownSensorError(wrong)
        if self.segment is None:
            for f in self.driver.unused_files():
                warn(UnusedSensorFileWarning(f"{f.name}: {f.what}, but no stream of {self.path} fits it: not used"),
                     stacklevel=3)
        summary = self.driver.dropped_summary()  # what was skipped, lost or discarded: said once
        if summary:
            warn(DroppedPacketsWarning(summary), stacklevel=3)

    def _emit(self, frames: list[Frame]) -> Iterator[Frame]:
        for frame in frames:
            if not frame.partial and frame.sensor.source not in self._rates_checked:  # a file of another rate
                self._rates_checked.add(frame.sensor.source)
                if note := rate_disagreement(frame):
                    warn(LidarpktWarning(note), stacklevel=3)
            if frame.partial and not self._include_partial:
                continue
            self.stats.frames += 1
            yield frame


class Packets(NamedTuple):
    """A batch of a pass (:meth:`FrameReader.items`) and what the router made of it: ``stream`` is the
    vendor's :class:`~lidarpkt.core.vendor.Match` (``.stream``, ``.vendor``, ``.kind``, ``.lidar``; ``.make``
    ``None`` when the vendor recognises the stream but cannot decode it), ``None`` when no vendor recognised
    the batch or ``source=`` left its source out."""

    batch: PacketBatch
    stream: Match | None


class Driver:
    """The one driver from packet batches to decoders, for capture files (:class:`FrameReader`) and live
    sources (:class:`lidarpkt.pipeline.live.LiveDecoder`): each batch is routed by the router
    (:mod:`lidarpkt.pipeline.router`) to its sensor's decoder and counted in :attr:`stats`
    (:class:`SourceStats`); streams no vendor recognises, and sensors beyond ``max_sensors`` (said once, a
    :class:`~lidarpkt.errors.SkippedPacketWarning`), are counted as unrouted; ``source`` keeps one source.

    Args:
        name: what warnings and errors name (the capture's path, the live address).
        setup: the sensor files and decoding options the vendors' classifiers and decoders are given.
        max_sensors: most sensors given a decoder.
        source: decode only the packets of this source IP address (``None``: all).
        ownership: reading a segment, its :class:`~lidarpkt.containers.segments.SegmentOwnership`.
        unused_auxiliary: vendors whose auxiliary batches are counted, not handed to their decoders.
        sensor_files: the sensor files given (:func:`lidarpkt.vendors.registry.load_sensor_files`), whose use it
            follows (:meth:`unused_files`).
    """

    def __init__(self, name: str, setup: DecodeSetup, *, max_sensors: int = MAX_SENSORS, source: str | None = None,
                 ownership: Any = None, unused_auxiliary: frozenset[str] = frozenset(),
                 sensor_files: list | None = None) -> None:
        self.name = name
        self.stats = SourceStats()
        self._source_filter = source
        self._ownership = ownership
        self.unused_auxiliary = unused_auxiliary
        self.sensor_files = sensor_files if sensor_files is not None else []
        self._used_files: set[int] = set()  # id() of the loaded sensor files decoders were given
        # the router holds a weak method, not self: no reference cycle keeps a dropped reader (and its thread)
        too_many = weakref.WeakMethod(self._too_many_sensors)
        self.router = Router(setup, max_sensors=max_sensors, on_limit=lambda: (too_many() or (lambda: None))())

    @property
    def decoders(self) -> dict[tuple, Decoder]:
        """(vendor, source address, ...) → the decoder of that sensor, in order of first packet."""
        return self.router.decoders

    def route(self, batch: PacketBatch, post_end: bool = False) -> tuple[Match | None, list[Frame]]:
        """Count a batch and route it through the one router (:mod:`lidarpkt.pipeline.router`) to its sensor's
        decoder: (what the router made of it, the frames it completed). Reading a segment, nothing for a sensor
        whose frames of the segment are complete."""
        self.stats.batches += 1
        self.stats.packets += len(batch)
        src = batch.src.address if batch.src is not None else None
        if self._source_filter is not None and src != self._source_filter:
            if len(self.stats.filtered_sources) < 1000 or src in self.stats.filtered_sources:
                self.stats.filtered_sources[str(src)] = self.stats.filtered_sources.get(str(src), 0) + len(batch)
            return None, []
        router = self.router
        match = router.classify(batch)
        if match is None or match.make is None:  # no vendor's, or one its vendor cannot decode (no sensor file)
            return match, self._unrouted(batch)
        key = router.key(batch, match)
        if self._ownership is not None and self._ownership.state(key, post_end).closed:
            return match, []
        if key not in router.decoders:
            self._check_files(match)
        route = router.route_match(batch, match)
        if route.decoder is None:
            return match, self._unrouted(batch)
        self._used_files.update(id(f) for f in match.sensor_files)
        self.stats.routed[match.stream] = self.stats.routed.get(match.stream, 0) + len(batch)
        if match.lidar:
            return match, self._push(route.key, route.decoder, batch, post_end)
        if match.vendor not in self.unused_auxiliary:
            route.decoder.push_auxiliary(batch)
        return match, []

    def classify(self, batch: PacketBatch) -> Match | None:
        """What the router makes of a batch (``None`` too when ``source`` leaves it out), without counting
        or decoding it."""
        src = batch.src.address if batch.src is not None else None
        if self._source_filter is not None and src != self._source_filter:
            return None
        return self.router.classify(batch)

    def finish(self) -> list[Frame]:
        """The frames still being assembled in every decoder (the last, partial ones)."""
        return [frame for decoder in self.decoders.values() for frame in decoder.finish()]

    def unused_files(self) -> list:
        """The sensor files given that no decoder was given (they fit no stream routed so far)."""
        return [f for f in self.sensor_files if id(f.loaded) not in self._used_files]

    def _check_files(self, match: Match) -> None:
        """A new sensor whose vendor needs a sensor file for its XYZ, while the files given are all of other
        vendors and fit no stream so far: the files are for another sensor, which is an error (the frames
        would come without points, for a reason no later message could name).

        Raises:
            MetadataError: naming the files given and the one the sensor takes.
        """
        kind = registry.vendor(match.vendor).sensor_files
        if kind is None or kind.needed_for != "xyz" or match.sensor_files or not self.sensor_files:
            return
        if any(f.vendor == match.vendor or id(f.loaded) in self._used_files for f in self.sensor_files):
            return
        given = "; ".join(f"{f.name} is a {f.what}" for f in self.sensor_files)
        raise MetadataError(f"{self.name}: {given}, but its {registry.vendor(match.vendor).title} stream "
                            f"({match.kind}) takes a {kind.what}: give the sensor's own file (metadata=... / "
                            "--metadata)")

    def drop_counts(self) -> DropCounts:
        """Packets dropped so far, by reason, over every decoder (each vendor's reasons) and the unrouted ones."""
        counts = DropCounts()
        for key, decoder in self.decoders.items():
            counts += registry.vendor(key[0]).drops(decoder.stats)
        counts.unrouted += self.stats.unrouted_packets
        return counts

    def dropped_summary(self) -> str | None:
        """The end-of-read summary line (``None`` when nothing was dropped)."""
        text = format_dropped(self.drop_counts(), self.stats.packets)
        if not text:
            return None
        return f"{self.name}: {text}; the frames hold what arrived (each frame's counters say what it lost)"

    def _push(self, key: tuple, decoder, batch: PacketBatch, post_end: bool) -> list[Frame]:
        """``decoder.push(batch)``; reading a segment, only the frames that belong to it (SegmentOwnership)."""
        own = self._ownership
        if own is None:
            return decoder.push(batch)
        frames: list[Frame] = []
        for part in _post_end_parts(batch) if post_end else [batch]:
            if own.streams[key].closed:
                break
            got = decoder.push(part)
            frames += own.keep(key, got, post_end, lambda f, part=part: _holds_packet(f, part, decoder))
        return frames

    def _unrouted(self, batch: PacketBatch) -> list[Frame]:
        key = UnroutedStream(_source_name(batch), str(batch.dst) if batch.dst is not None else "?", batch.payload_size)
        self.stats.unrouted_packets += len(batch)
        streams = self.stats.unrouted_streams
        if key not in streams and len(streams) >= _MAX_LISTED_STREAMS:  # a capture of random traffic
            key = OTHER_STREAMS
        streams[key] = streams.get(key, 0) + len(batch)
        return []

    def _too_many_sensors(self) -> None:
        """The router met a sensor beyond ``max_sensors``: each decoder holds up to a frame (~3 MB for an
        OS-128), so a capture with thousands of source addresses (400 one-packet Ouster sources took
        660 MB) must not get one each. Said once."""
        warn(SkippedPacketWarning(
            f"{self.name}: more than {self.router.max_sensors} sensors (source addresses) in one capture; the "
            "packets of the others are counted in stats.unrouted_packets, not decoded (choose one with "
            "source=..., or raise max_sensors=...)"), stacklevel=7)

    def no_sensor_message(self) -> str:
        """Why no sensor was decoded: the sources ``source`` left out, or the streams seen (and a hint)."""
        if not self.stats.unrouted_streams and self.stats.filtered_sources:
            seen = ", ".join(f"{a} ({n} packets)" for a, n in list(self.stats.filtered_sources.items())[:8])
            return f"{self.name}: no packets from source {self._source_filter}; the capture holds packets from {seen}"
        streams = "; ".join(f"{k}: {n} packets" for k, n in list(self.stats.unrouted_streams.items())[:8])
        setup = self.router.setup
        wrong = registry.undecoded_hint(self.name, self.stats.unrouted_streams, setup)
        if wrong:
            return wrong
        needed = [v.sensor_files.what for v in registry.VENDORS if v.sensor_files is not None
                  and v.sensor_files.needed_for == "decoding" and not setup.files(v.name)]
        hint = (f" Some sensors are decoded only with their sensor file: pass the {' or the '.join(needed)} "
                "(metadata=... / --metadata)." if needed else "")
        return f"{self.name}: no stream of a sensor lidarpkt decodes ({registry.names()}) found among {streams}.{hint}"


@with_options
def open_frames(path: str | os.PathLike[str], **options: Unpack[OpenKeywords]
                ) -> FrameIterator:
    """Frames from a capture; this is ``lidarpkt.open``.

    Returns a :class:`FrameReader`: iterate it for :class:`~lidarpkt.core.frame.Frame` objects in the order
    their last packet arrived; its ``stats`` say what was routed where and what was skipped;
    ``close()`` (or ``with``) stops reading early; with ``workers`` > 1 a
    :class:`~lidarpkt.pipeline.parallel.ParallelFrameReader` or
    :class:`~lidarpkt.pipeline.parallel.PipelinedFrameReader` gives the same frames. A file of decoded frames
    (ouster-sdk's OSF) gives its vendor's reader of its stored frames (see :func:`_open_frame_file` for the
    options it takes).

    Args:
        path: pcap/pcapng file, MCAP file, rosbag2 directory or ``.db3``, ROS 1 ``.bag``, or OSF file.
        {options}

    Raises:
        UnsupportedContainerError: the file is no container lidarpkt reads.
        UnsupportedFilterError: a filter the container cannot apply (bags record no ports or addresses).
        UnknownSensorError: the file holds packets, but none of a supported sensor (message lists the streams).
        MetadataError, SensorMismatchError, CaptureFormatError: see their docstrings.
        UsageError: ``workers`` is not a whole number >= 1.
    """
    opts = OpenOptions.from_keywords("lidarpkt.open", dict(options))
    keep_freed_arrays()
    frame_files = registry.frame_files(path)
    if frame_files is not None:  # files of decoded frames, not packets
        return _open_frame_file(path, opts, frame_files)
    if opts.workers != 1:
        from .parallel import open_parallel

        reader = open_parallel(path, opts, _segment_reader, SourceStats())
        if reader is not None:
            return reader
    return FrameReader(path, **dataclasses.replace(opts, workers=1).keywords())  # one thread after all


_PACKET_OPTIONS = ("ports", "src_addresses", "payload_sizes", "topics", "batch_packets", "source")


def _open_frame_file(path: str | os.PathLike[str], options: OpenOptions, files: FrameFiles) -> FrameIterator:
    """``lidarpkt.open`` of a file of decoded frames (``files``: what it is): its vendor's reader (``workers``
    ≥ 2: decoded in a thread ahead of the caller, :class:`~lidarpkt.pipeline.parallel.PipelinedFrameReader`).

    The file carries its sensors' metadata: ``metadata`` is not used, nor are the options of packet decoding
    (``model``, ``verify_crc``...); ``include_partial`` applies.

    Raises:
        UnsupportedFilterError: a packet filter (``ports``, ``topics``, ``source``...): the file holds no packets.
        UnsupportedContainerError: a ``segment`` of a file cut in several: the file is read whole.
        CaptureFormatError: the file is damaged.
    """
    from lidarpkt.errors import UnsupportedFilterError

    what = f"an {files.what}"
    given = [name for name in _PACKET_OPTIONS if getattr(options, name) is not None]
    if given:
        raise UnsupportedFilterError(f"{path}: {', '.join(n + '=' for n in given)} cannot filter {what}: it holds "
                                     "decoded frames, not packets")
    if options.segment is not None and options.segment.count != 1:
        raise UnsupportedContainerError(f"{path}: {what} is read whole (one segment)")
    reader = files.open(path, SourceStats(), options.include_partial)  # options checked by OpenOptions
    if options.workers in (None, 1):
        return reader
    from .parallel import PipelinedFrameReader

    return PipelinedFrameReader(reader)


def _segment_reader(path: str | os.PathLike[str], options: OpenOptions) -> FrameReader:
    """The reader of one segment for :mod:`lidarpkt.pipeline.parallel` (which does not import this module)."""
    return FrameReader(path, **options.keywords())


READ_AHEAD_MIN_BYTES = 8 << 20  # smaller captures are read in the caller's thread (a thread would not pay)


def _want_read_ahead(reader, read_ahead: bool | None) -> bool:
    """Read ahead in a thread? pcap/pcapng only (a bag reader's embedded metadata is looked up as its
    batches arrive); by default when the file has at least READ_AHEAD_MIN_BYTES and there are 2+ CPUs."""
    from lidarpkt.containers.pcap_reader import PcapReader

    if not isinstance(reader, PcapReader) or read_ahead is False:
        return False
    if read_ahead:
        return True
    try:
        size = os.path.getsize(reader.path)
    except OSError:
        return False
    return size >= READ_AHEAD_MIN_BYTES and (os.cpu_count() or 1) > 1


def _post_end_parts(batch: PacketBatch) -> Iterator[PacketBatch]:
    """A batch past a segment's end as views of 1, 32, 64, 128... packets: the first alone (as
    ``SegmentOwnership.split_first_post`` asks), and the reader stops pushing as soon as the segment's last
    frame is complete instead of decoding (and copying) the rest of a batch of up to 2048 packets."""
    n, start, step = len(batch), 0, 1
    while start < n:
        yield batch if (start, step) == (0, 1) and n == 1 else batch.select(slice(start, min(n, start + step)))
        start, step = start + step, max(32, 2 * step)


def _holds_packet(frame: Frame, batch: PacketBatch, decoder) -> bool:
    """Does ``frame`` hold the (first) packet of ``batch``? Frames that list their packets' ordinals
    (``extra["packet_index"]``) say so; a decoder whose frames do not answers it (``holds_packet``)."""
    index = frame.extra.get("packet_index")
    if index is not None:
        return bool(np.isin(int(batch.index[0]), index))
    holds = getattr(decoder, "holds_packet", None)
    return bool(holds(frame, batch)) if holds is not None else False
