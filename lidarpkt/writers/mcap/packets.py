"""Raw packets into MCAP topics, losslessly, with loss accounting: what ``record`` writes live and
the MCAP frame writer writes of a capture (``decode``).

:class:`PacketSink` takes packet batches (one stream, one payload size, in arrival order)
and writes them to a :class:`~lidarpkt.writers.mcap.writer.McapWriter`. What a stream is, and how its
packets go to ROS, is its vendor's (the registry's classifier, and the record's
:attr:`~lidarpkt.core.vendor.Vendor.ros`):

* a stream whose packet topic gathers a rotation (Velodyne data packets in a ``VelodyneScan``) is cut
  where the vendor's packet counter says a rotation begins, or after ``max_scan_packets`` if the
  sensor does not turn; log time = host receive time of the rotation's last packet;
* the packets of the other streams with a topic of their own: one message each, log time = host
  receive time;
* anything else goes, unchanged, to ``/lidarpkt/other_packets`` (counted, reported, kept).

Losses and rotations are counted by the vendor's packet counter (:attr:`~lidarpkt.core.vendor.Vendor.counter`).
Sensor descriptions go into MCAP metadata records named ``lidarpkt.sensor``, with the latched messages
of each sensor file given (an Ouster's metadata JSON on ``/ouster/metadata``); messages a vendor decodes
beside the packets (IMU samples) are written too.

:class:`CaptureTimes` measures, from the batches of a capture as they are handed, what frames need
to be logged at the host time of a capture: each sensor's clock offset and the capture's first and
last packet times.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from lidarpkt.containers.rosmsgs import encode_stamped_packet
from lidarpkt.core.decoder import StreamCounter, StreamCounts
from lidarpkt.core.packet import PacketBatch
from lidarpkt.core.vendor import Match, PacketTopic
from lidarpkt.errors import PacketFormatError
from lidarpkt.vendors import registry
from . import schemas
from .writer import McapWriter

_OTHER = PacketTopic(schemas.OTHER_PACKETS, encode=encode_stamped_packet)


@dataclass
class StreamReport:
    """What one stream delivered: its kind (a :class:`~lidarpkt.core.streams.StreamKind` text, ``"other"``),
    endpoints, payload size and counts."""

    kind: str
    src: str
    dst: str
    payload_size: int
    count: StreamCounts = field(default_factory=StreamCounts)
    messages: int = 0


@dataclass
class _Stream:
    """A stream's state in the sink: its match, report, topic, counter and the rotation being gathered."""

    match: Match | None
    report: StreamReport
    topic: PacketTopic
    counter: StreamCounter | None
    pending: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)


class PacketSink:
    """Writes packet batches to MCAP (see the module doc).

    Args:
        writer: the MCAP output.
        metadata: the sensor files of the sensors (as ``lidarpkt.open`` takes them), needed where a vendor
            recognises its streams, or counts their losses, only with them (an Ouster profile).
        max_scan_packets: bound on one rotation's message (memory stays bounded if the azimuth never wraps).
        log_time_ns: log time of the sensor files' latched messages.
    """

    def __init__(self, writer: McapWriter, *, metadata: Any = None, max_scan_packets: int = 2000,
                 log_time_ns: int | None = None) -> None:
        self.writer = writer
        self.sensor_files = registry.load_sensor_files(metadata)
        self.setup = registry.setup(self.sensor_files)
        self.max_scan_packets = max_scan_packets
        self.streams: dict[tuple, StreamReport] = {}
        self._streams: dict[tuple, _Stream] = {}
        self.notes: list[str] = []  # things the user should know about the streams, in order
        self.decoded_messages = 0  # messages decoded from packets (IMU samples, zone states) written
        for f in self.sensor_files:
            self._write_sensor_file(f, log_time_ns or 0)

    # ----------------------------------------------------------------- metadata
    def _write_sensor_file(self, f: registry.SensorFile, log_time_ns: int) -> None:
        write = registry.vendor(f.vendor).ros.sensor_file_messages
        if write is None:
            return
        latched, record = write(f.loaded, log_time_ns)
        for message in latched:
            self.writer.write_latched(message.topic, message.data, log_time_ns, key=message.key)
        self.writer.add_metadata("lidarpkt.sensor", record)

    def _stream(self, batch: PacketBatch) -> _Stream:
        """The state of ``batch``'s stream: classified, described and counted from its first batch."""
        key = (batch.src, batch.dst, batch.payload_size)
        state = self._streams.get(key)
        if state is not None:
            return state
        match = registry.classify(batch, self.setup)
        vendor = registry.vendor(match.vendor) if match is not None else None
        kind = str(match.stream) if match is not None else "other"
        where = f"{batch.payload_size}-byte packets from {batch.src} to {batch.dst}"
        topic, counter = _OTHER, None
        if vendor is not None and match is not None:
            topic = vendor.ros.packet_topics.get(match.kind, _OTHER)
            counter = vendor.counter(batch, match)
            if vendor.ros.stream_record is not None:
                record = vendor.ros.stream_record(batch, str(batch.src))
                if record is not None:
                    self.writer.add_metadata("lidarpkt.sensor", record)
            if not match.decodable and match.lidar:
                what = vendor.sensor_files.what if vendor.sensor_files is not None else "sensor file"
                self.notes.append(f"{where} look like {vendor.title} {match.kind} packets; without their {what} "
                                  "(--metadata) they are recorded but not checked for loss nor counted as frames")
        else:
            self.notes.append(f"{where} are no stream lidarpkt knows (a sensor may need its file, --metadata); "
                              "they are kept on /lidarpkt/other_packets")
        report = self.streams[(kind, batch.src, batch.dst, batch.payload_size)] = StreamReport(
            kind, str(batch.src), str(batch.dst), batch.payload_size)
        state = self._streams[key] = _Stream(match, report, topic, counter)
        return state

    # ------------------------------------------------------------------ packets
    def push(self, batch: PacketBatch) -> None:
        """Write one batch (one stream, one payload size, arrival order)."""
        n = len(batch)
        if n == 0:
            return
        state = self._stream(batch)
        rep = state.report
        starts = None
        if state.counter is not None:
            try:
                starts = state.counter.update(batch.payload, batch.timestamp_ns)
                rep.count = state.counter.count
            except PacketFormatError:  # bytes the counter cannot read (a stream that only looked like the vendor's)
                state.counter = None
        if state.counter is None:  # no layout to find gaps in: counted only
            rep.count.packets += n
        if state.topic.encode_rotation is not None:
            self._gather(state, batch, starts)
            return
        if state.match is not None:
            decoded = registry.vendor(state.match.vendor).ros.decoded
            for topic, data, t in decoded(batch, state.match) if decoded is not None else ():
                self.writer.write(topic, data, t)
                self.decoded_messages += 1
        write, encode, topic = self.writer.write, state.topic.encode, state.topic.topic
        assert encode is not None  # a topic of one message per packet
        for t, row in zip(batch.timestamp_ns.tolist(), batch.payload):
            write(topic, encode(row.tobytes(), t), t)
        rep.messages += n

    def _gather(self, state: _Stream, batch: PacketBatch, starts: np.ndarray | None) -> None:
        """Gather a rotation's packets; write it where the next one starts, or at ``max_scan_packets``."""
        cuts = np.flatnonzero(starts).tolist() if starts is not None else []
        lo = 0
        for cut in cuts + [len(batch)]:
            if cut > lo:
                state.pending.append((batch.payload[lo:cut], batch.timestamp_ns[lo:cut]))
            if cut < len(batch):
                self._flush_rotation(state)
            lo = cut
        if sum(len(t) for _, t in state.pending) >= self.max_scan_packets:
            self._flush_rotation(state)

    def _flush_rotation(self, state: _Stream) -> None:
        pending = state.pending
        if not pending:
            return
        payload = np.concatenate([p for p, _ in pending]) if len(pending) > 1 else pending[0][0]
        host = np.concatenate([t for _, t in pending]) if len(pending) > 1 else pending[0][1]
        pending.clear()
        encode = state.topic.encode_rotation
        assert encode is not None  # a topic of one message per rotation
        self.writer.write(state.topic.topic, encode(payload, host), int(host[-1]))
        state.report.messages += 1

    def finish(self) -> None:
        """Write the rotations still being gathered (the last, partial ones). Does not close the writer."""
        for state in self._streams.values():
            self._flush_rotation(state)

    # ---------------------------------------------------------------- reports
    @property
    def packets(self) -> int:
        return sum(r.count.packets for r in self.streams.values())

    @property
    def lost(self) -> int:
        return sum(r.count.lost for r in self.streams.values())

    @property
    def out_of_order(self) -> int:
        return sum(r.count.out_of_order for r in self.streams.values())

    @property
    def frames(self) -> int:
        """Rotations completed, over the lidar streams (the largest of them)."""
        return max((s.report.count.frames for s in self._streams.values() if s.match is not None and s.match.lidar),
                   default=0)

    def report_lines(self) -> list[str]:
        """One line per stream for the end-of-run summary."""
        out = []
        for r in self.streams.values():
            c = r.count
            out.append(f"  {r.kind:<18} {r.src} -> {r.dst} {r.payload_size} B: {c.packets} packets, "
                       f"{c.lost} lost, {c.out_of_order} out of order, {c.frames} rotations"
                       + (f", {c.interruptions} interruptions" if c.interruptions else "")
                       + (f", {c.corrupted} corrupted" if c.corrupted else ""))
        return out


class CaptureTimes:
    """What frames need to be logged at the host time of a capture, measured from its packet batches as one
    pass hands them (:meth:`add`, in capture order): each lidar source's clock offset and the capture's first
    and last packet host times.

    The offset of each lidar source (:attr:`offsets`, by source name) is host receive time minus sensor time
    (ns) on its first packet among the first :data:`LOOK_AHEAD` batches (the vendor's
    :attr:`~lidarpkt.core.vendor.Vendor.sensor_time_ns`; sources whose packets carry no time it reads have
    none). Some sensors' clocks count from boot, others from the hour: frames are logged at sensor time + this
    offset, i.e. when their last packet was received, kept inside the capture's span (:attr:`start_ns`,
    :attr:`end_ns`: its first and last packet, final once the last batch has been added).
    """

    LOOK_AHEAD = 64  # batches among which the offsets are measured

    def __init__(self) -> None:
        self.offsets: dict[str, int] = {}
        self.start_ns: int | None = None
        self.end_ns: int | None = None
        self.batches = 0

    @property
    def offsets_final(self) -> bool:
        """No later batch can add an offset."""
        return self.batches >= self.LOOK_AHEAD

    def add(self, batch: PacketBatch, sensor_files: Sequence[registry.SensorFile] = ()) -> None:
        """Measure one batch; ``sensor_files``: the loaded sensor files of the sensors
        (:func:`lidarpkt.vendors.registry.load_sensor_files`), for the streams recognised only with them."""
        k = self.batches
        self.batches += 1
        if len(batch) == 0:
            return
        t0, t1 = int(batch.timestamp_ns.min()), int(batch.timestamp_ns.max())
        self.start_ns = t0 if self.start_ns is None else min(self.start_ns, t0)
        self.end_ns = t1 if self.end_ns is None else max(self.end_ns, t1)
        src = str(batch.src) if batch.src is not None else "unknown source"
        if k >= self.LOOK_AHEAD or src in self.offsets:
            return
        match = registry.classify(batch, registry.setup(sensor_files))
        if match is None:
            return
        sensor_ns = registry.vendor(match.vendor).sensor_time_ns(batch, match)
        if sensor_ns is not None:
            self.offsets[src] = int(batch.timestamp_ns[0]) - sensor_ns
