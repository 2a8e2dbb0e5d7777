"""From a capture file to frames: container detection, stream routing, one decoder per sensor.

``lidarpkt.open(path)`` is :func:`open_frames`. The container (pcap, pcapng, MCAP,
rosbag2, ROS 1 bag) is recognised by its first bytes, not its name. Every batch of
packets is routed by what it is (VLP-16 data or position packets; Ouster lidar or IMU
packets of a sensor whose metadata was given) and by its source, so that several
sensors in one file each get their own decoder. Streams that are none of these are
counted, not decoded.
"""

from __future__ import annotations

import dataclasses
import os
import weakref
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Generator, Iterator, NamedTuple, cast

import numpy as np

from lidarpkt.errors import DroppedPacketsWarning, SkippedPacketWarning, UnknownSensorError, UnsupportedContainerError
from lidarpkt.core.readahead import warn  # warnings.warn, or handed to the caller's thread when decoding ahead
from lidarpkt.core.decoder import Decoder
from lidarpkt.core.frame import Frame, FrameIterator
from .options import OpenOptions, load_ouster_metadata, with_options
from lidarpkt.core.packet import PacketBatch
from .router import MAX_SENSORS, Match, Router, RouteOptions, source_name as _source_name

if TYPE_CHECKING:
    from typing_extensions import Unpack  # typing.Unpack is Python 3.11+

    from .options import OpenKeywords
    from lidarpkt.core.readahead import ReadAhead
    from lidarpkt.vendors.ouster.osf import OsfReader
    from .parallel import ParallelFrameReader, PipelinedFrameReader

from lidarpkt.containers.magic import MCAP_MAGIC, ROS1_MAGIC, SQLITE_MAGIC, container_kind, is_osf  # noqa: F401 (public here too)
from lidarpkt.containers.magic import PCAP_MAGIC_BYTES as PCAP_MAGICS  # noqa: F401
from lidarpkt.containers.protocol import PacketSource, open_packet_source

_MAX_LISTED_STREAMS = 1000  # unrouted streams named one by one in SourceStats; the rest are summed


def read_batches(path: str | os.PathLike[str], **filters: Any) -> Iterator[PacketBatch]:
    """Packet batches of any supported container, in capture order (see :func:`lidarpkt.containers.open_packet_source`)."""
    return open_packet_source(path, **filters).batches()


class UnroutedStream(NamedTuple):
    """A stream :func:`open_frames` did not decode, as :attr:`SourceStats.unrouted_streams` keys it;
    ``str()`` gives ``"src → dst (size B)"``."""

    src: str
    dst: str
    payload_size: int | None  # None: the streams beyond the listed ones, summed

    def __str__(self) -> str:
        return self.src if self.payload_size is None else f"{self.src} → {self.dst} ({self.payload_size} B)"


OTHER_STREAMS = UnroutedStream("(other streams)", "", None)


@dataclass
class SourceStats:
    """What :func:`open_frames` saw: packets routed to each kind of decoder and streams it could not use."""

    batches: int = 0
    packets: int = 0
    velodyne_data_packets: int = 0
    velodyne_position_packets: int = 0
    ouster_lidar_packets: int = 0
    ouster_imu_packets: int = 0
    hesai_data_packets: int = 0
    ouster_zone_packets: int = 0
    unrouted_packets: int = 0
    unrouted_streams: dict[UnroutedStream, int] = field(default_factory=dict)  # stream → packets
    other_sensor_packets: dict[str, int] = field(default_factory=dict)  # "vendor kind" → packets, other vendors
    filtered_sources: dict[str, int] = field(default_factory=dict)  # sources left out by source= → packets
    frames: int = 0


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
            ValueError: ``workers`` is not 1 (``lidarpkt.open(path, workers=N)`` decodes in N threads).
            And what :func:`open_frames` raises on opening.
        """
        opts = OpenOptions.from_keywords("FrameReader", options)
        if opts.workers != 1:
            raise ValueError("FrameReader decodes in one thread; lidarpkt.open(path, workers=N) decodes in N")
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
        self.reader: PacketSource = open_packet_source(path, **filters)
        self.read_ahead = _want_read_ahead(self.reader, opts.read_ahead)
        self._read_ahead: ReadAhead[PacketBatch] | None = None  # the running ReadAhead, if any
        metadata, self._decoder_options = decoder_options(opts)
        self._include_partial = opts.include_partial
        self.driver = Driver(str(self.path), RouteOptions(metadata, self._decoder_options),
                             max_sensors=opts.max_sensors, source=opts.source, ownership=self._ownership)
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

    @property
    def _ouster_metadata(self) -> list:
        return list(self.router.options.ouster_metadata)

    def _frames(self, packets: bool = False, decode: bool = True) -> Generator[Frame | Packets, None, None]:
        embedded = self.reader.ouster_metadata
        batches = self._batches()
        ownership = self._ownership
        try:
            for batch in batches:
                if not self.router.options.ouster_metadata:
                    # Metadata recorded inside the file (MCAP /ouster/metadata) serves when none was given.
                    self.router.options = RouteOptions(load_ouster_metadata(embedded()), self._decoder_options)
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
        from lidarpkt.core.dropped import dropped_summary, no_sensor_hint  # what was skipped, lost or discarded: said once

        if not (self.stats.velodyne_data_packets or self.stats.ouster_lidar_packets or self.stats.hesai_data_packets):
            wrong = no_sensor_hint(self.path, self.stats.unrouted_streams, self._ouster_metadata)
            if wrong:  # Ouster lidar packets without (fitting) metadata: say so, not "no frames"
                raise UnknownSensorError(wrong)

        summary = dropped_summary(self)
        if summary:
            warn(DroppedPacketsWarning(summary), stacklevel=3)

    def _emit(self, frames: list[Frame]) -> Iterator[Frame]:
        for frame in frames:
            if frame.partial and not self._include_partial:
                continue
            self.stats.frames += 1
            yield frame


class Packets(NamedTuple):
    """A batch of a pass (:meth:`FrameReader.items`) and what the router made of it: ``stream`` is the
    vendor's :class:`~lidarpkt.pipeline.router.Match` (``.vendor``, ``.kind``, ``.lidar``), ``None`` when no
    vendor recognised the batch or ``source=`` left its source out."""

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
        options: the router's :class:`~lidarpkt.pipeline.router.RouteOptions`.
        max_sensors: most sensors given a decoder.
        source: decode only the packets of this source IP address (``None``: all).
        ownership: reading a segment, its :class:`~lidarpkt.containers.segments.SegmentOwnership`.
        unused_auxiliary: vendors whose auxiliary batches are counted, not handed to their decoders.
    """

    def __init__(self, name: str, options: RouteOptions, *, max_sensors: int = MAX_SENSORS, source: str | None = None,
                 ownership: Any = None, unused_auxiliary: frozenset[str] = frozenset()) -> None:
        self.name = name
        self.stats = SourceStats()
        self._source_filter = source
        self._ownership = ownership
        self.unused_auxiliary = unused_auxiliary
        # the router holds a weak method, not self: no reference cycle keeps a dropped reader (and its thread)
        too_many = weakref.WeakMethod(self._too_many_sensors)
        self.router = Router(options, max_sensors=max_sensors, on_limit=lambda: (too_many() or (lambda: None))())

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
        if match is None:
            return None, self._unrouted(batch)
        key = router.key(batch, match)
        if self._ownership is not None and self._ownership.state(key, post_end).closed:
            return match, []
        route = router.route_match(batch, match)
        if route.decoder is None:
            return match, self._unrouted(batch)
        name = f"{match.vendor}_{match.kind}_packets"
        if hasattr(self.stats, name):
            setattr(self.stats, name, getattr(self.stats, name) + len(batch))
        else:  # a vendor SourceStats has no field of its own for
            other = self.stats.other_sensor_packets
            other[f"{match.vendor} {match.kind}"] = other.get(f"{match.vendor} {match.kind}", 0) + len(batch)
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
        out: list[Frame] = []
        for decoder in self.decoders.values():
            out += decoder.finish()
        return out

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
        from lidarpkt.core.dropped import no_sensor_hint

        metadata = list(self.router.options.ouster_metadata)
        wrong = no_sensor_hint(self.name, self.stats.unrouted_streams, metadata)
        if wrong:
            return wrong
        hint = "" if metadata else " For an Ouster sensor pass its metadata JSON (metadata=... / --metadata)."
        return f"{self.name}: no VLP-16 or Ouster stream (nor a Hesai Pandar one) found among {streams}.{hint}"


@with_options
def open_frames(path: str | os.PathLike[str], **options: Unpack[OpenKeywords]
                ) -> FrameReader | ParallelFrameReader | PipelinedFrameReader | OsfReader:
    """Frames from a capture; this is ``lidarpkt.open``.

    Returns a :class:`FrameReader`: iterate it for :class:`~lidarpkt.core.frame.Frame` objects in the order
    their last packet arrived; its ``stats`` say what was routed where and what was skipped;
    ``close()`` (or ``with``) stops reading early. An OSF file (ouster-sdk's recording of decoded
    frames) gives a :class:`~lidarpkt.vendors.ouster.osf.OsfReader` of its stored frames (see
    :func:`~lidarpkt.vendors.ouster.osf.open_osf` for the options it takes).

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
    opts = OpenOptions.from_keywords("open_frames", dict(options))
    if is_osf(path):  # ouster-sdk's frame files: frames, not packets
        from lidarpkt.vendors.ouster.osf import open_osf

        return open_osf(path, opts)
    if opts.workers != 1:
        from .parallel import open_parallel

        reader = open_parallel(path, opts, _segment_reader, SourceStats())
        if reader is not None:
            return reader
    return FrameReader(path, **dataclasses.replace(opts, workers=1).keywords())  # one thread after all


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


def decoder_options(opts: OpenOptions) -> tuple[list, dict[str, dict[str, Any]]]:
    """(the loaded Ouster metadata, each vendor's decoder options) of the options of ``lidarpkt.open``:
    what its router is given, for files and live packets alike.

    Raises:
        lidarpkt.errors.MetadataError: a ``metadata`` file that is no Ouster metadata.
    """
    from lidarpkt.vendors.hesai.calibration import is_hesai_calibration  # a CSV is Hesai's, a YAML/XML the VLP-16's

    hesai_cal = is_hesai_calibration(opts.calibration)
    metadata, hesai_md = _split_hesai(opts.metadata)  # a Hesai CSV given as the sensor's metadata
    return load_ouster_metadata(metadata), {
        "velodyne": {"calibration": None if hesai_cal else opts.calibration, "cut_angle_deg": opts.cut_angle_deg,
                     "cut_on_block": opts.cut_on_block, "model": opts.velodyne_model},
        "ouster": {"verify_crc": opts.verify_crc, "soft_id_check": opts.soft_id_check},
        "hesai": {"calibration": opts.calibration if hesai_cal else hesai_md, "cut_angle_deg": opts.cut_angle_deg}}


def _split_hesai(metadata: Any) -> tuple[Any, Any]:
    """(the Ouster metadata, the Hesai calibration) of the ``metadata`` option: an archive job's
    ``--metadata`` may name a Pandar's angle-correction CSV, its sensor description as the JSON is an Ouster's."""
    from lidarpkt.vendors.hesai.calibration import is_hesai_calibration

    items = metadata if isinstance(metadata, (list, tuple)) else [metadata] if metadata is not None else []
    hesai = [m for m in items if is_hesai_calibration(m)]
    if not hesai:
        return metadata, None
    rest = [m for m in items if not is_hesai_calibration(m)]
    return rest or None, hesai[0]


def _post_end_parts(batch: PacketBatch) -> Iterator[PacketBatch]:
    """A batch past a segment's end as views of 1, 32, 64, 128... packets: the first alone (as
    ``SegmentOwnership.split_first_post`` asks), and the reader stops pushing as soon as the segment's last
    frame is complete instead of decoding (and copying) the rest of a batch of up to 8192 packets."""
    n, start, step = len(batch), 0, 1
    while start < n:
        yield batch if (start, step) == (0, 1) and n == 1 else batch.select(slice(start, min(n, start + step)))
        start, step = start + step, max(32, 2 * step)


def _holds_packet(frame: Frame, batch: PacketBatch, decoder) -> bool:
    """Does ``frame`` hold the (first) packet of ``batch``? VLP-16 frames list their packets' ordinals;
    an Ouster frame holds the packets of its frame id."""
    index = frame.extra.get("packet_index")
    if index is not None:
        return bool(np.isin(int(batch.index[0]), index))
    metadata = getattr(decoder, "metadata", None)
    if metadata is None:
        return False
    from lidarpkt.vendors.ouster import decode_packets

    fields = decode_packets(batch.payload[:1], metadata, verify_crc=False, fields=(), header_fields=("frame_id",))
    return int(fields.frame_id[0]) == frame.frame_id

