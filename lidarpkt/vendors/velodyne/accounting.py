"""Counting a Velodyne stream's packets on their way to the frames: what :class:`VelodyneDecoder
<lidarpkt.vendors.velodyne.frames.VelodyneDecoder>` skipped, reordered, dropped or found lost
(:class:`DecoderStats`), and the rules it counts by (:class:`PacketAccounting`).

Malformed packets (a bad block flag or azimuth, an unknown return mode) are skipped; a packet whose time
jumps further than the capture time allows, off the packets on both sides, is skipped as corrupted; a
jump the packets after it agree with restarts the stream (:mod:`lidarpkt.core.continuity`). Packets out
of order inside a batch are put back in order (counted); duplicates, and packets older than the last
packet of an earlier batch, are dropped and counted. A time gap of k packet periods lost k − 1 packets,
never more than the capture time holds; gaps at the same azimuth sector every rotation are a restricted
field of view, not losses.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from lidarpkt.core.continuity import StreamContinuity
from lidarpkt.core.frame import FrameCounters
from lidarpkt.core.packet import PacketBatch
from lidarpkt.core.readahead import warn  # warnings.warn, or handed to the caller's thread when decoding ahead
from lidarpkt.errors import SkippedPacketWarning
from .decode import DataPackets, flags_ok
from .packet import known_return_mode
from .stream import packets_lost

if TYPE_CHECKING:
    from .models import VelodyneModel


@dataclass
class DecoderStats:
    """What a :class:`VelodyneDecoder` saw, counted."""

    packets: int = 0  # data packets pushed
    decoded_packets: int = 0
    malformed_size: int = 0  # data batches of another payload size
    malformed_flag: int = 0  # a block flag other than 0xEEFF or an azimuth ≥ 360°
    unknown_return_mode: int = 0
    duplicate_packets: int = 0  # same sensor timestamp as an earlier packet
    out_of_order_packets: int = 0  # older than an earlier packet (put back in order within a batch)
    late_packets: int = 0  # older than the last packet of an earlier batch: dropped
    lost_packets: int = 0  # inferred from time gaps, never more than the capture time holds
    corrupted_packets: int = 0  # off both neighbours by more than the capture time allows: skipped
    restarts: int = 0  # the stream's clock jumped (or paused more than INTERRUPTION_S) and went on from there
    outside_fov_packets: int = 0  # not sent: the sensor's field of view leaves out a sector (a gap at the same
    # azimuths every rotation), so not lost
    long_gaps: int = 0  # gaps longer than max_gap_s (frame cut, nothing inserted)
    overlong_frames: int = 0  # frames released without an azimuth wrap (max_frame_columns)
    position_packets: int = 0
    position_malformed: int = 0
    nmea_errors: int = 0
    gps_fixes: int = 0
    gps_fixes_ignored: int = 0  # fixes that would have moved the hour of packets already placed
    frames: int = 0

    @property
    def malformed(self) -> int:
        """Packets skipped as malformed (size, flag, return mode)."""
        return self.malformed_size + self.malformed_flag + self.unknown_return_mode


class PacketAccounting:
    """The counting half of the Velodyne decoder: the packets a batch keeps, in order, and those lost
    before each (the decoder's :attr:`stats` and the pending frame's counters say what went)."""

    stats: DecoderStats
    model: VelodyneModel
    source: str | None
    continuity: StreamContinuity
    _pending_counters: FrameCounters
    _last_abs_ns: int | None  # sensor time of the last packet kept
    _last_host_ns: int  # capture time of the last packet kept (0: unknown)
    _last_packet_az_cdeg: int | None  # azimuth of the last packet's last block
    _gap_sectors: list[tuple[tuple[int, int], int]]  # ((az before, az after), lost) of wide gaps

    def _keep_sound(self, batch: PacketBatch, raw: DataPackets
                    ) -> tuple[DataPackets, np.ndarray, np.ndarray, np.ndarray] | None:
        """``(raw, capture times, ordinals, restart)`` of the packets of ``batch`` that are neither malformed
        nor corrupted (``restart``: ``bool[N]``, the stream restarts at the packet), counted; ``None`` when
        none is left."""
        ok = raw.flag_ok if self.model.blocks_per_column == 1 else flags_ok(raw, self.model)
        known = known_return_mode(raw.return_mode)
        bad_flag = int(np.count_nonzero(~ok))
        bad_mode = int(np.count_nonzero(ok & ~known))
        if bad_flag or bad_mode:
            self.stats.malformed_flag += bad_flag
            self.stats.unknown_return_mode += bad_mode
            self._pending_counters.malformed_packets += bad_flag + bad_mode
            warn(SkippedPacketWarning(
                f"{self.source or self.model.name}: skipped {bad_flag} packets with a bad block flag or azimuth and "
                f"{bad_mode} with an unknown return mode"), stacklevel=4)
            keep = ok & known
            raw = raw.select(keep)
            times = batch.timestamp_ns[keep]
            index = batch.index[keep]
        else:
            times, index = batch.timestamp_ns, batch.index
        if len(raw) == 0:
            return None
        st = self.continuity.check(raw.timestamp_us.astype(np.int64), times)
        restart = st.restart
        if st.corrupted:
            self.stats.corrupted_packets += st.corrupted
            self._pending_counters.malformed_packets += st.corrupted
            warn(SkippedPacketWarning(
                f"{self.source or self.model.name}: skipped {st.corrupted} packets whose time jumped further than the "
                "capture time allows (corrupted)"), stacklevel=4)
            raw, times, index, restart = raw.select(st.keep), times[st.keep], index[st.keep], restart[st.keep]
            if len(raw) == 0:
                return None
        self.stats.restarts += st.restarts
        return raw, times, index, restart

    def _in_order(self, raw: DataPackets, abs_ns: np.ndarray, index: np.ndarray, host_ns: np.ndarray
                  ) -> tuple[DataPackets, np.ndarray, np.ndarray, np.ndarray] | None:
        """``(raw, abs_ns, index, host_ns)`` of a run of packets in time order, without duplicates and
        packets older than the last one kept, counted; ``None`` when none is left."""
        # Packets out of order inside a batch are put back in order (counted, kept); duplicates and
        # packets older than the last one of an earlier batch (its frame may be gone) are dropped, counted.
        last = self._last_abs_ns if self._last_abs_ns is not None else np.iinfo(np.int64).min
        running = np.maximum.accumulate(np.concatenate([[last], abs_ns]))[:-1]
        ooo = int(np.count_nonzero(abs_ns < running))
        if ooo:
            order = np.argsort(abs_ns, kind="stable")
            raw, abs_ns, index, host_ns = raw.select(order), abs_ns[order], index[order], host_ns[order]
            self.stats.out_of_order_packets += ooo
            self._pending_counters.out_of_order_packets += ooo
        late = abs_ns < last
        dup = np.concatenate([[False], abs_ns[1:] == abs_ns[:-1]]) | (abs_ns == last)
        if late.any() or dup.any():
            n_late, n_dup = int(np.count_nonzero(late)), int(np.count_nonzero(dup & ~late))
            self.stats.late_packets += n_late
            self.stats.duplicate_packets += n_dup
            self._pending_counters.late_packets += n_late
            self._pending_counters.duplicate_packets += n_dup
            fresh = ~(late | dup)
            raw, abs_ns, index, host_ns = raw.select(fresh), abs_ns[fresh], index[fresh], host_ns[fresh]
            if len(raw) == 0:
                return None
        return raw, abs_ns, index, host_ns

    def _lost(self, raw: DataPackets, abs_ns: np.ndarray, host_ns: np.ndarray, mode: str
              ) -> tuple[np.ndarray, np.ndarray]:
        """``(gaps, missing)``: ``int64[N]`` ns since the packet before each of a run, and the packets lost
        just before each (bounded by the capture time, less a field of view's sectors)."""
        period_ns = self.model.packet_period_ns(mode)
        gaps = np.diff(np.concatenate([[abs_ns[0] if self._last_abs_ns is None else self._last_abs_ns], abs_ns]))
        prev_host = np.concatenate([[self._last_host_ns if self._last_abs_ns is not None else 0], host_ns[:-1]])
        missing = self.continuity.bound_lost(packets_lost(gaps, period_ns), host_ns - prev_host,
                                             (host_ns != 0) & (prev_host != 0), period_ns)
        return gaps, self._outside_fov(raw, missing)

    #: a gap of fewer packets is a loss wherever it falls; a field-of-view sector is tens of packets wide
    FOV_MIN_PACKETS = 8
    #: two gaps are the same sector when both edges agree within this (a few packets' azimuth step)
    FOV_EDGE_CDEG = 200

    def _outside_fov(self, raw: DataPackets, missing: np.ndarray) -> np.ndarray:
        """``missing`` less the gaps of a restricted field of view: a sensor set to send only part of its
        rotation leaves a gap at the same azimuth sector (from the last azimuth before it to the first after)
        every rotation; lost packets fall anywhere. The first gap of a sector is counted lost until the
        next rotation shows the same sector; then it is moved from lost to ``outside_fov_packets``."""
        wide = np.flatnonzero(missing >= self.FOV_MIN_PACKETS)
        if wide.size == 0:
            return missing
        missing = missing.copy()
        last = self._last_packet_az_cdeg
        for i in wide.tolist():
            before = int(raw.azimuth_cdeg[i - 1, -1]) if i > 0 else last
            if before is None:
                continue
            sector = (before, int(raw.azimuth_cdeg[i, 0]))
            same = [k for k, (known, _) in enumerate(self._gap_sectors)
                    if all(abs((a - b + 18000) % 36000 - 18000) <= self.FOV_EDGE_CDEG for a, b in zip(known, sector))]
            n = int(missing[i])
            if not same:
                self._gap_sectors = (self._gap_sectors + [(sector, n)])[-8:]  # counted lost for now
                continue
            k = same[0]
            first = self._gap_sectors[k][1]
            if first:  # the sector's first gap, counted lost then: a field of view after all
                self.stats.lost_packets -= first
                self.stats.outside_fov_packets += first
                self._gap_sectors[k] = (self._gap_sectors[k][0], 0)
            self.stats.outside_fov_packets += n
            missing[i] = 0
        return missing
