"""Raw packets into MCAP topics, losslessly, with loss accounting: what ``record`` writes live and
the MCAP frame writer writes of a capture (``decode``).

:class:`PacketSink` takes packet batches (one stream, one payload size, in arrival order)
and writes them to a :class:`~lidarpkt.writers.mcap.writer.McapWriter`:

* VLP-16 data packets are gathered into one ``VelodyneScan`` per rotation (cut where the
  first block's azimuth wraps, or after ``max_scan_packets`` if the sensor does not turn);
  log time = host receive time of the scan's last packet, ``header.stamp`` = sensor time of
  its first packet, each packet's ``stamp`` = its host receive time;
* VLP-16 position packets, Ouster lidar and IMU packets: one message each, log time = host
  receive time;
* anything else goes, unchanged, to ``/lidarpkt/other_packets`` (counted, reported, kept).

Sensor descriptions go into MCAP metadata records named ``lidarpkt.sensor``; the Ouster
metadata JSON also goes to the latched ``/ouster/metadata`` topic.

:class:`CaptureTimes` measures, from the batches of a capture as they are handed, what frames need
to be logged at the host time of a capture: each sensor's clock offset and the capture's first and
last packet times.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from lidarpkt.core import streams
from lidarpkt.core.decoder import StreamCounter
from lidarpkt.core.packet import PacketBatch
from lidarpkt.vendors.velodyne import packet as vlp
from lidarpkt.vendors.velodyne.clock import in_nearest_hour_ns
from lidarpkt.vendors.velodyne.models import HDL32E_PACKET_PERIOD_US, PRODUCT_NAMES

from . import schemas
from .writer import McapWriter


def velodyne_sensor_time_ns(timestamp_us: np.ndarray, host_time_ns: np.ndarray) -> np.ndarray:
    """Sensor time (ns since the epoch) of VLP-16 packets: their µs past the hour, in the hour
    nearest their host receive time (the convention of velodyne_decoder; ±30 min), as the decoder
    resolves it (:func:`lidarpkt.vendors.velodyne.clock.in_nearest_hour_ns`)."""
    return in_nearest_hour_ns(timestamp_us, host_time_ns)


@dataclass
class StreamReport:
    """What one stream delivered: its kind, endpoints, payload size and counts."""

    kind: str
    src: str
    dst: str
    payload_size: int
    count: streams.LossCount = field(default_factory=streams.LossCount)
    messages: int = 0


class PacketSink:
    """Writes packet batches to MCAP (see the module doc).

    Args:
        writer: the MCAP output.
        ouster_metadata: :class:`lidarpkt.vendors.ouster.metadata.OusterMetadata` of the Ouster sensor,
            if any (needed for non-legacy profiles and for Ouster loss accounting), or a list of
            them, one per sensor: a batch uses the one whose lidar or IMU port is its
            destination port, else the first.
        max_scan_packets: bound on one ``VelodyneScan`` (memory stays bounded if the
            azimuth never wraps).
    """

    def __init__(self, writer: McapWriter, *, ouster_metadata=None, max_scan_packets: int = 2000,
                 log_time_ns: int | None = None) -> None:
        self.writer = writer
        if isinstance(ouster_metadata, (list, tuple)):
            self._ouster_mds = list(ouster_metadata)
        else:
            self._ouster_mds = [ouster_metadata] if ouster_metadata is not None else []
        self.ouster_metadata = self._ouster_mds[0] if self._ouster_mds else None  # the first sensor's
        self.max_scan_packets = max_scan_packets
        self.streams: dict[tuple, StreamReport] = {}
        self._trackers: dict[tuple, StreamCounter] = {}
        self._pending: dict[tuple, list[tuple[np.ndarray, np.ndarray]]] = {}
        self._described: set[tuple] = set()
        self.notes: list[str] = []  # things the user should know about the streams, in order
        self.decoded_messages = 0  # /ouster/imu and /ouster/zone_states messages written
        for md in self._ouster_mds:
            self._write_ouster_metadata(md, log_time_ns or 0)

    def _metadata_for(self, batch: PacketBatch):
        """The Ouster metadata of the sensor sending ``batch`` (by destination port), else the first."""
        return metadata_for(batch, self._ouster_mds)

    # ----------------------------------------------------------------- metadata
    def _write_ouster_metadata(self, md, log_time_ns: int) -> None:
        text = json.dumps(md.raw)
        self.writer.write_latched(schemas.OUSTER_METADATA, schemas.encode(
            schemas.STRING, schemas.typestore().types[schemas.STRING](data=text)), log_time_ns,
            key=f"{md.serial}:{md.lidar_port}")
        info = md.sensor_info().describe()
        self.writer.add_metadata("lidarpkt.sensor", {
            "vendor": "ouster", "model": str(info["model"]), "profile": md.profile.name,
            "columns_per_frame": str(md.columns_per_frame), "pixels_per_column": str(md.pixels_per_column),
            "lidar_port": str(md.lidar_port), "imu_port": str(md.imu_port),
            "serial": str(md.serial), "firmware": str(md.firmware),
            "sensor_info": json.dumps(info), "metadata_json": text,
        })

    def _describe_velodyne(self, batch: PacketBatch, src: str) -> None:
        from lidarpkt.errors import LidarpktError
        from lidarpkt.vendors.velodyne.decode import decode_packets
        from lidarpkt.vendors.velodyne.detect import describe_stream, detect_model

        p = vlp.as_data_packets(batch.payload[:1])[0]
        mode = vlp.RETURN_MODES.get(int(p["return_mode"]), f"0x{int(p['return_mode']):02x}")
        product = PRODUCT_NAMES.get(int(p["product_id"]), f"0x{int(p['product_id']):02x}")
        described = describe_stream(batch) or {}
        try:  # the model's own stock elevations (an HDL-32E's 32, not the VLP-16's 16)
            model = detect_model(decode_packets(batch.payload, copy=False), src)
        except LidarpktError:  # an unknown or ambiguous factory byte: the decoder says so; no elevations here
            model = None
        self.writer.add_metadata("lidarpkt.sensor", {
            "vendor": "velodyne", "model": model.name if model is not None else
            described.get("kind", "Velodyne data").replace(" data", ""),
            "return_mode": mode, "product_id": f"0x{int(p['product_id']):02x} ({product})", "source": src,
            **({"laser_elevation_deg": json.dumps([float(e) for e in model.elevation_deg])} if model is not None else {}),
            "stream": json.dumps(described, default=str),
        })

    # ------------------------------------------------------------------ packets
    def push(self, batch: PacketBatch) -> None:
        """Write one batch (one stream, one payload size, arrival order)."""
        n = len(batch)
        if n == 0:
            return
        md = self._metadata_for(batch)
        kind = streams.classify_size(batch.payload_size, md)
        key = (kind, batch.src, batch.dst, batch.payload_size)
        rep = self.streams.get(key)
        if rep is None:
            rep = self.streams[key] = StreamReport(kind, str(batch.src), str(batch.dst), batch.payload_size)
            where = f"{batch.payload_size}-byte packets from {batch.src} to {batch.dst}"
            if kind == streams.OUSTER_LIDAR and md is None:
                self.notes.append(f"{where} look like Ouster LEGACY lidar packets; without --metadata they are "
                                  "recorded but not checked for loss nor counted as frames")
            elif kind == streams.OTHER and not (md is not None and batch.payload_size == md.zone_packet_size):
                self.notes.append(f"{where} are no stream lidarpkt knows (an Ouster profile needs --metadata); "
                                  "they are kept on /lidarpkt/other_packets")
        host = batch.timestamp_ns
        if kind == streams.VELODYNE_DATA:
            self._push_velodyne(key, rep, batch)
            return
        if kind == streams.OUSTER_LIDAR and md is not None:
            tracker = self._trackers.get(key)
            if tracker is None:
                tracker = self._trackers[key] = streams.OusterLoss(md)
            tracker.update(batch.payload, batch.timestamp_ns)
            rep.count = tracker.count
        elif kind == streams.HESAI_DATA and self._hesai_counted(key, rep, batch):
            pass  # kept on /lidarpkt/other_packets (nebula's packet message), read back by lidarpkt.open
        else:  # no layout to find gaps in: counted only
            rep.count.packets += n
        if kind == streams.OUSTER_LIDAR:
            topic = schemas.OUSTER_LIDAR
        elif kind == streams.OUSTER_IMU:
            topic = schemas.OUSTER_IMU
        else:
            topic = schemas.VELODYNE_POSITION if kind == streams.VELODYNE_POSITION else schemas.OTHER_PACKETS
        write = self.writer.write
        self._write_decoded_ouster(kind, md, batch)
        if topic.msgtype == schemas.PACKET_MSG:
            for t, row in zip(host.tolist(), batch.payload):
                write(topic, schemas.encode_packet_msg(row.tobytes()), t)
        else:
            for t, row in zip(host.tolist(), batch.payload):
                write(topic, schemas.encode_stamped_packet(row.tobytes(), t), t)
        rep.messages += n

    def _hesai_counted(self, key: tuple, rep: StreamReport, batch: PacketBatch) -> bool:
        """Count a Pandar stream's losses and rotations; False (counted as packets only) if its bytes are no Pandar's."""
        from lidarpkt.errors import PacketFormatError

        tracker = self._trackers.get(key)
        if tracker is None:
            tracker = self._trackers[key] = streams.HesaiLoss()
        try:
            tracker.update(batch.payload)
        except PacketFormatError:
            return False
        rep.count = tracker.count
        return True

    def _write_decoded_ouster(self, kind: str, md, batch: PacketBatch) -> None:
        """Beside the raw packets: one ``sensor_msgs/Imu`` per IMU sample (log time: its packet's receive time),
        and the zone states of zone-monitoring packets (their port, size and header say so) as JSON."""
        if md is None:
            return
        from lidarpkt.vendors.ouster.detect import classify

        match = classify(batch, [md]) if kind in (streams.OUSTER_IMU, streams.OTHER) else None
        if match is None:
            return
        host = batch.timestamp_ns
        if match[0] == "imu" and batch.payload_size == md.imu_packet_size:
            from lidarpkt.vendors.ouster.imu import imu_samples

            samples = imu_samples(batch.payload, md, str(batch.src))
            times = host[samples.extra["packet_index"]].tolist()
            for t, data in zip(times, schemas.encode_imu_samples(samples, "os_imu")):
                self.writer.write(schemas.OUSTER_IMU_SAMPLES, data, t)
            self.decoded_messages += len(samples)
        elif match[0] == "zone":
            from lidarpkt.vendors.ouster.zone import decode_zone_packets

            states = decode_zone_packets(batch.payload, md.header_type or "STANDARD")
            string_t = schemas.typestore().types[schemas.STRING]
            for t, record in zip(host.tolist(), states.records()):
                self.writer.write(schemas.OUSTER_ZONE_STATES,
                                  schemas.encode(schemas.STRING, string_t(data=json.dumps(record))), t)
            self.decoded_messages += len(states)

    def _push_velodyne(self, key: tuple, rep: StreamReport, batch: PacketBatch) -> None:
        if key not in self._described:
            self._described.add(key)
            self._describe_velodyne(batch, rep.src)
        tracker = self._trackers.get(key)
        if tracker is None:
            from lidarpkt.vendors.velodyne.detect import data_kind

            kind = data_kind(batch)
            period = None if kind is None else {"vlp16": vlp.SINGLE_PACKET_PERIOD_US, "hdl32e": HDL32E_PACKET_PERIOD_US}.get(kind)
            tracker = self._trackers[key] = streams.VelodyneLoss(period)
        starts = tracker.update(batch.payload, batch.timestamp_ns)
        rep.count = tracker.count
        pending = self._pending.setdefault(key, [])
        cuts = np.flatnonzero(starts).tolist()
        lo = 0
        for cut in cuts + [len(batch)]:
            if cut > lo:
                pending.append((batch.payload[lo:cut], batch.timestamp_ns[lo:cut]))
            if cut < len(batch):
                self._flush_scan(key, rep)
            lo = cut
        if sum(len(t) for _, t in pending) >= self.max_scan_packets:
            self._flush_scan(key, rep)

    def _flush_scan(self, key: tuple, rep: StreamReport) -> None:
        pending = self._pending.get(key)
        if not pending:
            return
        payload = np.concatenate([p for p, _ in pending]) if len(pending) > 1 else pending[0][0]
        host = np.concatenate([t for _, t in pending]) if len(pending) > 1 else pending[0][1]
        pending.clear()
        ts_us = vlp.as_data_packets(payload[:1])["timestamp_us"]
        stamp = int(velodyne_sensor_time_ns(ts_us, host[:1])[0])
        self.writer.write(schemas.VELODYNE_PACKETS, schemas.encode_velodyne_scan(payload, host, stamp),
                          int(host[-1]))
        rep.messages += 1

    def finish(self) -> None:
        """Write the scans still being gathered (the last, partial rotation). Does not close the writer."""
        for key, rep in self.streams.items():
            if key[0] == streams.VELODYNE_DATA:
                self._flush_scan(key, rep)

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
        return max((r.count.frames for r in self.streams.values()
                    if r.kind in (streams.VELODYNE_DATA, streams.OUSTER_LIDAR, streams.HESAI_DATA)), default=0)

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


def metadata_for(batch: PacketBatch, ouster_metadata: Sequence[Any]):
    """Of the Ouster metadata given (one per sensor), the one whose lidar or IMU port is ``batch``'s
    destination port, else the first; None when none is given."""
    if len(ouster_metadata) > 1 and batch.dst is not None:
        for md in ouster_metadata:
            if batch.dst.port in (md.lidar_port, md.imu_port, md.zm_port):
                return md
    return ouster_metadata[0] if ouster_metadata else None


class CaptureTimes:
    """What frames need to be logged at the host time of a capture, measured from its packet batches as one
    pass hands them (:meth:`add`, in capture order): each lidar source's clock offset and the capture's first
    and last packet host times.

    The offset of each lidar source (:attr:`offsets`, by source name) is host receive time minus sensor time
    (ns) on its first packet among the first :data:`LOOK_AHEAD` batches. Ouster clocks often count from boot,
    VLP-16 ones from the hour: frames are logged at sensor time + this offset, i.e. when their last packet was
    received, kept inside the capture's span (:attr:`start_ns`, :attr:`end_ns`: its first and last packet,
    final once the last batch has been added).
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

    def add(self, batch: PacketBatch, ouster_metadata: Sequence[Any] = ()) -> None:
        """Measure one batch; ``ouster_metadata``: loaded Ouster metadata, one per sensor (which batches are
        Ouster lidar packets, and their layout)."""
        k = self.batches
        self.batches += 1
        if len(batch) == 0:
            return
        t0, t1 = int(batch.timestamp_ns.min()), int(batch.timestamp_ns.max())
        self.start_ns = t0 if self.start_ns is None else min(self.start_ns, t0)
        self.end_ns = t1 if self.end_ns is None else max(self.end_ns, t1)
        src = str(batch.src) if batch.src is not None else "unknown source"
        offsets = self.offsets
        if k >= self.LOOK_AHEAD or src in offsets:
            return
        md = metadata_for(batch, ouster_metadata)
        kind = streams.classify_size(batch.payload_size, md)
        host = int(batch.timestamp_ns[0])
        if kind == streams.VELODYNE_DATA:
            ts_us = vlp.as_data_packets(batch.payload[:1])["timestamp_us"]
            offsets[src] = host - int(velodyne_sensor_time_ns(ts_us, batch.timestamp_ns[:1])[0])
        elif kind == streams.OUSTER_LIDAR and md is not None:
            dtype = md.profile.packet_dtype(md.pixels_per_column, md.columns_per_packet)
            first = np.ascontiguousarray(batch.payload[:1]).view(dtype)[0, 0]["columns"][0]
            offsets[src] = host - int(first["timestamp_ns"])
