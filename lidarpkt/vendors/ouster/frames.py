"""Ouster frame assembly: packets of one sensor → :class:`~lidarpkt.core.frame.Frame` objects.

Conventions (those of ouster-sdk's scan batcher):

* Packets are grouped by frame id (packet header, or the first column's for LEGACY) and
  init_id; a change of either ends the current frame.
* Columns are placed by measurement id (staggered, as on the wire): ``[R, H, W]`` pixels.
* A frame is released as soon as every column of ``column_window`` has arrived, or when a
  packet of another frame arrives (then it is ``partial``), or at :meth:`OusterDecoder.finish`.
* Columns that never arrived have zero fields, zero timestamp/measurement_id/status and
  ``column_valid`` False. So have columns that arrived with their status saying invalid
  (non-legacy status bit 0 clear; LEGACY status word ≠ 0xFFFFFFFF), as in ouster-sdk.
* Packets of an already released frame are dropped and counted as late; a packet whose first
  measurement id already arrived in its frame is a duplicate (dropped, counted). A packet whose
  frame or measurement id jumps further than the capture time allows, off the packets on both
  sides, is skipped and counted as corrupted (:mod:`lidarpkt.core.continuity`); a frame's holes never
  count more lost packets than its capture time holds.
* ``Frame.azimuth_deg[c] = 360 · (1 − c / W) mod 360``: the nominal encoder angle of column c in
  ouster-sdk's sensor-frame convention (the angle its XYZ table uses; it decreases with c).
* ``Frame.column_timestamp_ns`` is the column timestamp as the packets carry it: the sensor
  clock, which is Unix time only when the sensor is synchronised (PTP, GPS); with
  ``TIME_FROM_INTERNAL_OSC`` it counts from the sensor's boot. ouster-sdk reports the same.
* ``Frame.status``: LEGACY status word, else the 16-bit column status; ``Frame.encoder_count``:
  LEGACY only (90112 ticks per turn).
* ``Frame.extra``: every pixel field of the profile that is not a return-slot field or NEAR_IR,
  ``[H, W]``, under its name lower-cased: ``"window"`` (WINDOW), ``"zone_mask"`` (ZONE_MASK),
  ``"r"``, ``"g"``, ``"b"`` (RGB16 profiles). Non-legacy profiles add the packet-header status of
  each column's packet, ``[W]``: ``"alert_flags"``, ``"shot_limiting"``, ``"thermal_shutdown"``,
  ``"countdown_shot_limiting"``, ``"countdown_thermal_shutdown"`` (firmware 3.x; zero before).
* ``Frame.return_labels`` follow the metadata's ``return_order`` (``farthest``, ``second_farthest``
  for FARTHEST_TO_NEAREST ...).
* Columns outside ``column_window`` (the sensor's ``azimuth_window``) are never sent: they are not
  lost packets and do not make a frame partial.
* The last 16 released frames are remembered to recognise late packets; a packet of an older
  frame starts a new (partial) frame.
* IMU packets carry no sensor identity: :func:`~lidarpkt.vendors.ouster.classify` gives them to the
  metadata whose IMU port they were sent to (the first metadata when several share the port).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, fields as dc_fields

import numpy as np

from lidarpkt.core.readahead import warn  # warnings.warn, or handed to the caller's thread when decoding ahead
from lidarpkt.core.continuity import CAPTURE_RESOLUTION_S, packets_spanned
from lidarpkt.errors import SensorMismatchError, SkippedPacketWarning
from lidarpkt.core.frame import Frame, FrameCounters
from lidarpkt.core.sensor import SensorInfo
from lidarpkt.core.packet import PacketBatch
from .decode import OusterPacketFields, decode_packets
from lidarpkt.core.imu import ImuSamples
from .imu import imu_samples
from .zone import OusterZoneStates, decode_zone_packets
from .metadata import OusterMetadata
from .builder import FrameBuilder, zero_missing
from .fieldplan import SLOT_ATTRS
from .profiles import HEADER_STATUS_FIELDS, LEGACY_STATUS_VALID
from .stream import packet_period_ns, packet_places, stream_continuity



@dataclass
class OusterDecoderStats:
    """Counters of one :class:`OusterDecoder` (packets, not columns, unless said otherwise)."""

    packets: int = 0  # lidar packets pushed
    accepted: int = 0  # lidar packets placed in frames
    size_mismatch: int = 0  # wrong payload size for the metadata: skipped
    id_mismatch: int = 0  # init_id / serial differ from the metadata: skipped
    crc_failures: int = 0  # CRC-64/XZ wrong (firmware ≥ 2.5): skipped
    bad_measurement_id: int = 0  # a measurement id ≥ columns_per_frame: skipped
    late: int = 0  # of a frame already released: dropped
    duplicates: int = 0  # first measurement id already received in the frame: dropped
    out_of_order: int = 0  # measurement id lower than the previous packet's (kept)
    lost_packets: int = 0  # holes between the first and last received columns of a frame (at most what its capture time holds)
    corrupted: int = 0  # frame/measurement ids off both neighbours by more than the capture time allows: skipped
    restarts: int = 0  # the ids jumped (or paused more than INTERRUPTION_S) and went on from there
    frames: int = 0
    partial_frames: int = 0
    imu_packets: int = 0
    imu_dropped: int = 0  # IMU samples beyond max_imu_samples (oldest dropped)
    imu_invalid: int = 0  # ACCEL32_GYRO32_NMEA measurements whose status says invalid: skipped
    zone_packets: int = 0
    shot_limiting_packets: int = 0  # lidar packets whose header says shot limiting is imminent or active
    thermal_shutdown_packets: int = 0  # lidar packets whose header says thermal shutdown is imminent

    def as_dict(self) -> dict[str, int]:
        return {f.name: getattr(self, f.name) for f in dc_fields(self)}


class OusterDecoder:
    """Frames of one Ouster sensor from its lidar (and IMU) packets (a :class:`lidarpkt.core.decoder.Decoder`).

    Args:
        metadata: the sensor's :class:`OusterMetadata`.
        source: where the packets come from (``"192.168.1.10:7502"``), for reports.
        verify_crc: check the CRC-64/XZ of packets whose firmware writes one (≥ 2.5) and skip
            (count) those that fail.
        soft_id_check: accept packets whose init_id differs from the metadata (the serial is
            still checked); by default they are skipped and counted.
        max_imu_samples: IMU samples kept (the oldest are dropped and counted beyond that); as many
            zone-monitoring packets are kept.

    ``push(batch)`` returns the frames completed by the batch; ``finish()`` the last partial one.
    :attr:`stats` counts what was skipped and why; each frame's ``counters`` what happened to it.
    """

    def __init__(
        self,
        metadata: OusterMetadata,
        *,
        source: str | None = None,
        verify_crc: bool = True,
        soft_id_check: bool = False,
        max_imu_samples: int = 100_000,
        **options,
    ) -> None:
        if options:
            raise TypeError(f"OusterDecoder: unknown options {sorted(options)}")
        self.metadata = metadata
        self._source = source
        self.verify_crc = verify_crc and metadata.footer_kind == "crc"
        self.soft_id_check = soft_id_check
        self.sensor = metadata.sensor_info(source)
        self.stats = OusterDecoderStats()
        self._current: FrameBuilder | None = None
        self._spare_planes: np.ndarray | None = None  # the last released frame's word planes, for the next
        self._released: deque[tuple[int, int]] = deque(maxlen=16)
        self._pending_counters = FrameCounters()  # skips seen while no frame was open
        self._window = metadata.window_mask
        self._azimuth_deg = np.mod(360.0 * (1.0 - np.arange(metadata.columns_per_frame) / metadata.columns_per_frame), 360.0)
        self._imu: deque[ImuSamples] = deque()
        self._zones: deque[OusterZoneStates] = deque()
        self.continuity = stream_continuity(metadata)  # corrupted packets, restarts
        self._period_ns = packet_period_ns(metadata)
        self._imu_count = 0
        self._max_imu = max_imu_samples

    # ------------------------------------------------------------------ lidar
    def push(self, batch: PacketBatch) -> list[Frame]:
        """Decode a batch of this sensor's lidar packets; return the frames it completed (capture order)."""
        md = self.metadata
        n = len(batch)
        self.stats.packets += n
        if n == 0:
            return []
        if batch.payload_size != md.packet_size:
            self.stats.size_mismatch += n
            self._count_skipped(n)
            warn(SkippedPacketWarning(
                f"Ouster {self.source or 'stream'}: skipped {n} packets of {batch.payload_size} B; the metadata "
                f"({md.profile.name}, {md.pixels_per_column} px) expects {md.packet_size} B"), stacklevel=2)
            return []
        # the status fields of firmware 3.x are read only where a packet has one set (zero before 3.x)
        status = md.profile.header_status_bytes
        with_status = status is not None and bool(batch.payload[:, status[0]:status[1]].any())
        f = decode_packets(batch.payload, md, verify_crc=self.verify_crc, fields=(),
                           header_fields=("frame_id", "init_id", "prod_sn") + (HEADER_STATUS_FIELDS if with_status else ()))
        payload = batch.payload if batch.payload.strides[1] == 1 else np.ascontiguousarray(batch.payload)
        keep = np.ones(n, bool)
        if f.crc_ok is not None:
            bad = ~f.crc_ok
            self.stats.crc_failures += int(bad.sum())
            keep &= f.crc_ok
        if not md.profile.legacy:
            ok = np.ones(n, bool)
            if md.serial_int is not None:
                ok &= f.header["prod_sn"] == np.uint64(md.serial_int)
            if md.init_id and not self.soft_id_check:
                ok &= f.header["init_id"] == md.init_id
            self.stats.id_mismatch += int((keep & ~ok).sum())
            keep &= ok
        bad_mid = (f.measurement_id >= md.columns_per_frame).any(axis=1)
        self.stats.bad_measurement_id += int((keep & bad_mid).sum())
        keep &= ~bad_mid
        skipped = n - int(keep.sum())
        host = batch.timestamp_ns
        if skipped:
            self._count_skipped(skipped)
            f = f.select(keep)
            payload = payload[keep]
            host = host[keep]
        if len(f) == 0:
            return []
        st = self.continuity.check(packet_places(f.frame_id, f.measurement_id[:, 0], md), host)
        self.stats.restarts += st.restarts
        if st.corrupted:
            self.stats.corrupted += st.corrupted
            self._count_skipped(st.corrupted)
            warn(SkippedPacketWarning(
                f"Ouster {self.source or 'stream'}: skipped {st.corrupted} packets whose frame or measurement id "
                "jumped further than the capture time allows (corrupted)"), stacklevel=2)
            f, payload, host = f.select(st.keep), payload[st.keep], host[st.keep]
            if len(f) == 0:
                return []
        if with_status:
            self.stats.shot_limiting_packets += int(np.count_nonzero(f.header["shot_limiting"]))
            self.stats.thermal_shutdown_packets += int(np.count_nonzero(f.header["thermal_shutdown"]))

        frame_id = f.frame_id
        init = f.init_id.astype(np.int64) if f.init_id is not None else np.zeros(len(f), np.int64)
        keys = (init << 32) | frame_id
        starts = np.concatenate([[0], np.flatnonzero(keys[1:] != keys[:-1]) + 1, [len(f)]])
        out: list[Frame] = []
        for s, e in zip(starts[:-1], starts[1:]):  # one iteration per frame in the batch
            key = (int(init[s]), int(frame_id[s]))
            if key in self._released:
                self.stats.late += int(e - s)
                target = self._current.counters if self._current is not None else self._pending_counters
                target.late_packets += int(e - s)
                continue
            if self._current is None or self._current.key != key:
                if self._current is not None:
                    out.append(self._release())
                self._current = FrameBuilder(self.metadata, key, key[1], self._spare_planes)
                self._spare_planes = None  # the builder's now (the NumPy path), or not needed
                self._current.counters = self._current.counters.add(self._pending_counters)
                self._pending_counters = FrameCounters()
            self._add(f.select(slice(s, e)), payload[s:e], host[s:e])
            if self._current.received[self._window].all():
                out.append(self._release())
        return out

    def _add(self, f: OusterPacketFields, payload: np.ndarray, host_ns: np.ndarray) -> None:
        b = self._current
        assert b is not None  # push opens the frame before adding to it
        if host_ns[0] and host_ns[-1]:
            b.host_ns = [b.host_ns[0] or int(host_ns[0]), int(host_ns[-1])]
        mid0 = f.measurement_id[:, 0].astype(np.intp)
        if int(mid0[0]) > b.last_mid0 and (mid0[1:] > mid0[:-1]).all() and not b.received[mid0].any():
            # the common case: packets in order, none seen before (no sort, no unique)
            b.last_mid0 = int(mid0[-1])
            self.stats.accepted += len(f)
            b.packets += len(f)
            b.add(f, payload, self.metadata)
            return
        order = np.concatenate([[b.last_mid0], mid0])
        b.counters.out_of_order_packets += int((np.diff(order) < 0).sum())
        self.stats.out_of_order += int((np.diff(order) < 0).sum())
        b.last_mid0 = int(mid0[-1])
        fresh = np.zeros(len(f), bool)
        fresh[np.unique(mid0, return_index=True)[1]] = True
        fresh &= ~b.received[mid0]
        dup = len(f) - int(fresh.sum())
        if dup:
            b.counters.duplicate_packets += dup
            self.stats.duplicates += dup
            f = f.select(fresh)
            payload = payload[fresh]
        self.stats.accepted += len(f)
        b.packets += len(f)
        b.add(f, payload, self.metadata)

    def _count_skipped(self, n: int) -> None:
        target = self._current.counters if self._current is not None else self._pending_counters
        target.malformed_packets += n

    def _release(self) -> Frame:
        b = self._current
        assert b is not None
        self._current = None
        self._released.append(b.key)
        md = self.metadata
        if b.received.all():  # the common case: every column arrived
            complete, got = True, None
        else:
            window_received = b.received[self._window]
            complete = bool(window_received.all())
            # holes between the first and last received column (in window order) are lost packets;
            # missing columns before/after them are the edges of the capture (the frame is partial)
            order = np.flatnonzero(self._window)
            if md.column_window[0] > md.column_window[1]:
                order = np.concatenate([order[order >= md.column_window[0]], order[order <= md.column_window[1]]])
            got = b.received[order]
        if got is not None and got.any():
            first, last = np.flatnonzero(got)[[0, -1]]
            holes = order[first : last + 1][~got[first : last + 1]]
            lost = int(np.unique(holes // md.columns_per_packet).size) if holes.size else 0
        else:
            lost = 0
        if lost and b.host_ns[0] and b.host_ns[1]:
            # never more than the frame's capture time holds beside the packets that arrived
            span = abs(b.host_ns[1] - b.host_ns[0]) + CAPTURE_RESOLUTION_S * 1e9
            lost = min(lost, max(int(packets_spanned(span, self._period_ns)) + 1 - b.packets, 0))
        b.counters.lost_packets += lost
        self.stats.lost_packets += lost
        self.stats.frames += 1
        self.stats.partial_frames += int(not complete)
        if md.profile.legacy:
            status_ok = b.status == LEGACY_STATUS_VALID
        else:
            status_ok = (b.status & 1).astype(bool)
        valid = b.received & status_ok
        if not valid.all():
            # a column whose status says invalid holds nothing (a sensor sends them around an azimuth
            # window, with timestamps): zero, as a column that never arrived (ouster-sdk drops them too)
            zero_missing([b.timestamp_ns, b.measurement_id]
                          + (list(b.header_status.values()) if b.header_status is not None else [])
                          + ([b.encoder_count] if b.encoder_count is not None else []), valid)
        px = b.fields(md.profile, valid)
        if b.planes is not None:
            self._spare_planes, b.planes = b.planes, None
        extra = {k: v for k, v in px.items() if k not in SLOT_ATTRS and k != "near_ir" and v is not None}
        if b.header_status is not None:  # zero where no column arrived (filled only from received packets)
            extra.update(b.header_status)
        range_mm, reflectivity = px["range_mm"], px["reflectivity"]
        assert range_mm is not None and reflectivity is not None  # every profile has them
        return Frame(
            sensor=self.sensor,
            frame_id=b.frame_id,
            range_mm=range_mm,
            reflectivity=reflectivity,
            return_labels=md.return_labels,
            column_valid=valid,
            column_timestamp_ns=b.timestamp_ns,
            azimuth_deg=self._azimuth_deg.copy(),
            signal=px["signal"],
            near_ir=px["near_ir"],
            flags=px["flags"],
            measurement_id=b.measurement_id,
            status=b.status,
            encoder_count=b.encoder_count,
            partial=not complete,
            counters=b.counters,
            extra=extra,
        )

    def holds_packet(self, frame: Frame, batch: PacketBatch) -> bool:
        """Does ``frame`` (one of this decoder's) hold the first packet of ``batch``: is it of the frame's id?"""
        fields = decode_packets(batch.payload[:1], self.metadata, verify_crc=False, fields=(), header_fields=("frame_id",))
        return int(fields.frame_id[0]) == frame.frame_id

    @property
    def source(self) -> str | None:
        """Where the packets come from, for reports; its :class:`SensorInfo` carries it (a new name is a new one)."""
        return self._source

    @source.setter
    def source(self, name: str | None) -> None:
        if name != self._source:
            self._source = name
            self.sensor = self.metadata.sensor_info(name)

    def finish(self) -> list[Frame]:
        """The frame still being filled (partial), if any.

        Raises:
            SensorMismatchError: lidar packets were pushed but none matched the metadata
                (size, init_id or serial): the metadata file is not this sensor's.
        """
        out = [self._release()] if self._current is not None else []
        st = self.stats
        if st.packets and not st.accepted and (st.size_mismatch or st.id_mismatch):
            md = self.metadata
            raise SensorMismatchError(
                f"Ouster {self.source or 'stream'}: none of {st.packets} lidar packets matches the metadata "
                f"{md.path or 'given'} ({md.profile.name}, {md.packet_size} B, init_id {md.init_id}, "
                f"serial {md.serial}): "
                f"{st.size_mismatch} of the wrong size, {st.id_mismatch} with another init_id/serial. "
                "Pass this sensor's metadata JSON."
            )
        return out

    def sensor_info(self, mode: str | None = None) -> SensorInfo:
        """The sensor's :class:`~lidarpkt.core.sensor.SensorInfo` (one profile per sensor: ``mode`` is ignored)."""
        return self.sensor

    # ------------------------------------------------------------------ IMU
    def push_auxiliary(self, batch: PacketBatch) -> None:
        """The :class:`~lidarpkt.core.decoder.Decoder` name of :meth:`push_imu` (:meth:`push_zone` for zone packets)."""
        if batch.payload_size == self.metadata.zone_packet_size and batch.payload_size != self.metadata.imu_packet_size:
            self.push_zone(batch)
        else:
            self.push_imu(batch)

    def push_imu(self, batch: PacketBatch) -> None:
        """Keep this sensor's IMU samples (see :meth:`imu_samples`), either IMU profile; packets of the wrong
        size (or of an IMU profile lidarpkt does not know) are counted and skipped."""
        md = self.metadata
        if batch.payload_size != md.imu_packet_size:
            self.stats.size_mismatch += len(batch)
            return
        self.stats.imu_packets += len(batch)
        samples = imu_samples(batch.payload, md, self.source)
        if md.imu_profile != "LEGACY":
            self.stats.imu_invalid += len(batch) * md.imu_measurements_per_packet - len(samples)
        self._imu.append(samples)
        self._imu_count += len(samples)
        while self._imu_count > self._max_imu:
            drop = self._imu_count - self._max_imu
            head = self._imu[0]
            if len(head) <= drop:
                self._imu.popleft()
                self._imu_count -= len(head)
                self.stats.imu_dropped += len(head)
            else:
                self._imu[0] = head.select(slice(drop, None))
                self._imu_count -= drop
                self.stats.imu_dropped += drop

    def imu_samples(self) -> ImuSamples:
        """The IMU samples kept so far (:class:`~lidarpkt.core.imu.ImuSamples`, m/s², rad/s), in arrival order."""
        return ImuSamples.concatenate(list(self._imu)) if self._imu else ImuSamples.empty(self.source)

    # ------------------------------------------------------------------ zone monitoring
    def push_zone(self, batch: PacketBatch) -> None:
        """Keep this sensor's zone-monitoring packets, decoded (see :meth:`zone_states`); wrong sizes are
        counted and skipped."""
        md = self.metadata
        if batch.payload_size != md.zone_packet_size:
            self.stats.size_mismatch += len(batch)
            return
        self.stats.zone_packets += len(batch)
        self._zones.append(decode_zone_packets(batch.payload, md.profile.header_type or "STANDARD"))
        while sum(len(z) for z in self._zones) > self._max_imu:
            self._zones.popleft()

    def zone_states(self) -> list[OusterZoneStates]:
        """The zone-monitoring packets kept so far, decoded, one :class:`OusterZoneStates` per batch pushed."""
        return list(self._zones)
