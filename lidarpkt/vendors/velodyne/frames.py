"""VLP-16 frame assembly: packets → lossless range-image columns → frames cut at the azimuth wrap.

Columns. One column per firing sequence, in firing order: 24 per packet in single-return
modes (block b → columns 2b, 2b+1), 12 per packet in dual mode (block pair 2k, 2k+1 →
columns 2k, 2k+1). Rows: row 0 = the highest laser (+15°, laser 15), row 15 = laser 0
(−15°), as the calibration's elevations order them.

Dual mode (``return_labels = ("last", "strongest")``): slot 0 holds block 2k (the last
return), slot 1 block 2k+1: the strongest return, or — when the strongest return was also
the last — the second strongest. Such pixels are marked in ``frame.extra["second_strongest"]``
(``bool[16, W]``): slot 1's range differs from slot 0's and slot 0 (the last return) has the
strictly higher signal at the detector, estimated from the packet as reflectivity / range²
(:func:`lidarpkt.core.dual.second_strongest_mark`, which documents the model, the tie rule
and what the mark cannot know). Where the sensor saw one return both slots hold it, as the
sensor sends it.

``frame.extra`` keys: ``azimuth_cdeg`` (``uint16[16, W]``, the azimuth of each firing in
0.01°, interpolated as velodyne_decoder does; used by the XYZ), ``packet_index``
(``int64[W]``, index of the packet in the source, −1 for lost columns), and in dual mode
``second_strongest``.

Cuts. A frame ends before the first column whose azimuth (minus the cut angle) wrapped
past 0, i.e. dropped by more than half a turn. ``partial`` means columns of the rotation are
missing (:func:`~lidarpkt.core.rotation.rotation_is_whole`, the rule of every vendor): a frame holding
lost columns is partial; so is a frame that does not begin at a wrap (the first of a stream, the first after a long
loss of packets, a return-mode change or an overlong frame) is whole only if its first column
fires within one firing interval (the azimuth advance of one firing sequence; of one block with
``cut_on_block``) after the cut angle, and a frame that does not end at a wrap (the last one,
:meth:`VelodyneDecoder.finish`, or one cut by a long loss or a mode change) only if its last
column fires within one firing interval before it. Frames released by ``max_frame_columns``
are always partial. Lost packets (time gaps between packets, shorter than
``max_gap_s``) become invalid columns (no sample: ``column_valid`` False, zero range, zero
timestamp, azimuth interpolated in time for :meth:`Frame.on_grid`) and are counted in the
frame's ``counters.lost_packets``.

Time. Packets carry µs past the hour. The hour is the one that puts a packet nearest its
reference: the GPS time of the last position packet with a valid $GPRMC/$GPGGA fix (moved
forward by the capture clock), else the packet's capture time, else (raw payloads without
capture times) the previous packet. ``column_timestamp_ns`` is the time of the column's first
firing (packet time + 55.296 µs × sequence); ``pixel_time_offset_ns`` adds 2.304 µs × laser id.

Order. Packets out of order inside a batch are put back in order (counted); duplicates, and
packets older than the last packet of an earlier batch, are dropped and counted
(``duplicate_packets``, ``late_packets``). A packet whose time jumps further than the capture time
allows, off the packets on both sides, is skipped (``corrupted_packets``); a jump the packets after
it agree with restarts the stream (``restarts``: the frame is cut, nothing lost or late); a gap never
counts more lost packets than the capture time holds (:mod:`lidarpkt.core.continuity`).

VeloView. VeloView (2014, ``vlp-16.test``) splits frames where a *block* azimuth wraps, so
the second firing sequence of the block that crosses 0° stays in the old frame. With
``cut_on_block=True`` our frame i is VeloView's frame i (52 frames of the test capture,
both partial ends counted, identical point counts). With the default per-sequence cut the
frame indices are the same and a frame boundary moves by at most one firing sequence (16
points). VeloView also gives both sequences of a block one azimuth each (no per-laser
interpolation): ``azimuth_deg`` per column reproduces its points within 1e-4 m.
"""

from __future__ import annotations

import numpy as np

from lidarpkt.core.continuity import StreamContinuity
from lidarpkt.errors import CalibrationError, SkippedPacketWarning
from lidarpkt.core.median import median
from lidarpkt.core.readahead import warn  # warnings.warn, or handed to the caller's thread when decoding ahead
from lidarpkt.core.frame import Frame, FrameCounters
from lidarpkt.core.sensor import SensorInfo
from lidarpkt.core.packet import PacketBatch
from .clock import HOUR_US, SensorClock
from .accounting import DecoderStats, PacketAccounting
from .columns import Columns, finish_columns
from .decode import DataPackets, column_pixels, decode_packets, decode_position_packets, layout_pixels
from .detect import check_product, detect_model, hdl64e_modes, vls128_sequence_ns
from .layout import packet_layout
from lidarpkt.core.dual import second_strongest_mark
from .geometry import VelodyneGeometry
from .calibration import VelodyneCalibration, load_calibration
from .models import VLP16, VelodyneModel, model_named
from .packet import DATA_PACKET_SIZE, POSITION_PACKET_SIZE, RETURN_MODE_CODES, RETURN_MODES
from lidarpkt.core.rotation import modulo_turn, rotation_is_whole, wrapped
from .timing import (firing_dt_s, interpacket_rate_cdeg_s, packet_rate_cdeg_s, packet_rate_cdeg_s_vlp16,
                     rotation_frequency_hz, row_offsets_ns)

DUAL = RETURN_MODE_CODES["dual"]
#: columns made at a time (_push_run): 1024 VLP-16 packets; more where a packet has fewer, so frames seldom straddle
PIECE_COLUMNS = 24_576
MAX_HELD_PACKETS = 16_384  #: HDL-64E packets held while its status cycle brings the calibration (~4 cycles, ~12 MB)
LABELS = {"strongest": ("strongest",), "last": ("last",), "dual": ("last", "strongest")}


class VelodyneDecoder(PacketAccounting):
    """Frames of one VLP-16 (one source address) from its data and position packets
    (a :class:`lidarpkt.core.decoder.Decoder`).

    Args:
        calibration: a :class:`~lidarpkt.vendors.velodyne.calibration.VelodyneCalibration`, a path to a ROS
            YAML / VeloView XML, several of them (the first that is the model's serves), or ``None`` for
            the stock calibration.
        cut_angle_deg: cut frames where the azimuth passes this angle instead of 0°.
        source: a name for reports (``"192.168.1.201:2368"``).
        max_gap_s: lost stretches shorter than this become invalid columns; longer ones end the
            frame (partial unless it reached the cut angle) without inserting anything. Default 0.2 s.
        cut_on_block: cut only where a *block* azimuth wraps, so that both firing sequences of a
            block stay in one frame (VeloView's convention; its per-frame point counts need it).
            By default a frame is cut at the first firing sequence whose azimuth wrapped.
        max_frame_columns: a frame still without a wrap after this many columns (8192 ≈ 0.45 s; a
            rotation at the slowest 5 Hz has 3617) is released as partial, so that a sensor that stops
            turning cannot grow memory without bound (counted in ``stats.overlong_frames``).
        model: the sensor's row of the model table (:mod:`lidarpkt.vendors.velodyne.models`) or its name;
            the VLP-16, the only row today, by default.

    Raises:
        UnknownSensorError: a model name not in the table.
        CalibrationError: an unreadable calibration, or one for another number of lasers.

    ``push`` returns the frames completed by a batch; ``finish`` the last one (see "Cuts" above for
    when a frame is ``partial``).
    Malformed packets (wrong size, bad block flag, unknown return mode) are counted in
    :attr:`stats` and skipped with one :class:`~lidarpkt.errors.SkippedPacketWarning` per batch.
    """

    def __init__(self, *, calibration=None, cut_angle_deg: float | None = None, source: str | None = None,
                 max_gap_s: float = 0.2, cut_on_block: bool = False, max_frame_columns: int = 8192,
                 model: VelodyneModel | str | None = None, **options) -> None:
        if options:
            raise TypeError(f"unknown VelodyneDecoder options: {sorted(options)}")
        self._calibration_arg = calibration
        self.geometry: VelodyneGeometry | None = None
        self.calibration: VelodyneCalibration | None = None
        self._sensors: dict[str, SensorInfo] = {}
        self._held: list[PacketBatch] = []
        self._held_packets = 0
        self._model_given = model is not None
        self._model_arg_named = model is not None
        if model is None and calibration is not None:  # its model is known once packets name it
            self._calibration_arg = None
            self._set_model(VLP16)
            self._calibration_arg = calibration
        else:
            self._set_model(VLP16 if model is None else model_named(model) if isinstance(model, str) else model)
        self.cut_cdeg = 0.0 if cut_angle_deg is None else float(cut_angle_deg) % 360.0 * 100.0
        self.source = source
        self.max_gap_ns = int(max_gap_s * 1e9)
        self.cut_on_block = bool(cut_on_block)
        self.max_frame_columns = int(max_frame_columns)
        self._pending_columns = 0
        self.stats = DecoderStats()
        self._pending: list[Columns] = []
        self._start_unknown = True  # the pending frame does not begin at a wrap (the first of a stream)
        self._pending_counters = FrameCounters()
        self._mode: str | None = None
        self._last_abs_ns: int | None = None  # sensor time of the last packet kept
        self._last_packet_az_cdeg: int | None = None  # azimuth of the last packet's last block
        self._gap_sectors: list[tuple[tuple[int, int], int]] = []  # ((az before, az after), lost) of wide gaps
        self._last_key: float | None = None  # cut key of the last column
        self._last_az_cdeg: float | None = None
        self.clock = SensorClock()  # the hour of the packet stamps
        self.continuity = StreamContinuity(1000, HOUR_US)  # corrupted packets, restarts, the loss bound
        self._last_host_ns = 0  # capture time of the last packet kept (0: unknown)
        self._product_id: int | None = None
        self._frame_id = 0
        self._frequency_hz: float | None = None
        self._timing_set = False
        self._prev_first_az: int | None = None  # VLS-128: first block azimuth of the last packet
        self._prev_stamp_us: int | None = None

    def _set_model(self, model: VelodyneModel) -> None:
        """Take ``model`` and its calibration (the one given, else the packets' own for the HDL-64E, else stock)."""
        self.model = model
        if not model.default_calibration and self._calibration_arg is None:
            from .hdl64e import StatusCycle  # the HDL-64E's alone
            self.geometry = None  # read from the packets' status cycle (lidarpkt.vendors.velodyne.hdl64e)
            self.calibration = None
            self._row_laser = np.arange(model.lasers)
            self._status = StatusCycle()
            self._held = []
            self._held_packets = 0
            self._sensors = {}
            return
        cal = load_calibration(self._calibration_arg, model)
        self.geometry = VelodyneGeometry(cal, model)
        self.calibration = self.geometry.calibration
        self._row_laser = self.geometry.row_laser
        self._sensors = {}

    def _await_calibration(self, batch: PacketBatch, raw: DataPackets) -> list[Frame]:
        """Hold the packets of an HDL-64E until its status cycle brought its calibration, then decode them.

        Raises :class:`CalibrationError` when :data:`MAX_HELD_PACKETS` passed without one (a cycle takes
        about 4200 packets: the calibration does not come, or comes corrupt)."""
        cal = self._status.push(raw.return_mode, raw.product_id)  # status type and value bytes
        if cal is None:
            self._held.append(batch)
            self._held_packets += len(batch)
            if self._held_packets > MAX_HELD_PACKETS:
                self._held = []
                raise CalibrationError(
                    f"{self.source or self.model.name}: no calibration in the status bytes of {self._held_packets} "
                    f"{self.model.name} packets ({self._status.bad_blocks} blocks with a bad checksum); pass the "
                    "unit's calibration (calibration=, --calibration)")
            return []
        if self._status.s3 != (self.model.name == "HDL-64E S3") and not self._model_arg_named:
            from .models import HDL64E_S2, HDL64E_S3

            self.model = HDL64E_S3 if self._status.s3 else HDL64E_S2
        self.geometry = VelodyneGeometry(cal, self.model)
        self.calibration = cal
        self._row_laser = self.geometry.row_laser
        self._sensors = {}
        held, self._held, self._held_packets = self._held, [], 0
        frames: list[Frame] = []
        for b in held + [batch]:
            frames += self._push_data(b)
        return frames

    def _resolve_model(self, raw: DataPackets, batch_times_us: np.ndarray) -> None:
        """On the first data packets: the model they name (when none was given), the VLS-128's firmware timing."""
        if not self._model_given:
            model = detect_model(raw)
            if model is not self.model or self._calibration_arg is not None:
                self._set_model(model)
            self._model_given = True
        elif self.model.product_ids and len(raw):
            check_product(raw, self.model, self.source)
        if self.model.dual_layout != "banks":
            self._timing_set = True
        elif not self._timing_set:
            seq = vls128_sequence_ns(raw, self.model)
            if seq is not None:
                self.model = self.model.with_sequence_ns(seq)
                if self.geometry is not None:
                    self.geometry.model = self.model
                self._sensors = {}
            self._timing_set = True

    # ------------------------------------------------------------------ time
    def absolute_time_ns(self, timestamp_us: np.ndarray, host_ns: np.ndarray) -> np.ndarray:
        """``int64[N]`` ns since the epoch for hour-relative packet times, updating the decoder's clock
        (see :class:`~lidarpkt.vendors.velodyne.clock.SensorClock`: GPS, else capture time, else the previous packet)."""
        return self.clock.absolute_ns(timestamp_us, host_ns)

    # ------------------------------------------------------------------ position packets
    def push_position(self, batch: PacketBatch) -> None:
        """Position packets: the GPS time of a valid fix anchors the hour of later data packets."""
        n = len(batch)
        self.stats.position_packets += n
        if batch.payload_size != POSITION_PACKET_SIZE:
            self.stats.position_malformed += n
            return
        pos = decode_position_packets(batch.payload)
        has = np.flatnonzero(pos.nmea[:, 0] != 0)
        if has.size == 0:
            return
        from lidarpkt.core.nmea import fix_time_ns, parse_sentence_rows  # imported when position packets come
        fixes, inverse = parse_sentence_rows(pos.nmea[has])
        ok = np.array([f is not None for f in fixes])[inverse]
        valid = np.array([f is not None and f.valid for f in fixes])[inverse]
        self.stats.nmea_errors += int(np.count_nonzero(~ok))
        self.stats.gps_fixes += int(np.count_nonzero(valid))
        if not valid.any():
            return
        last = int(np.flatnonzero(valid)[-1])
        i = int(has[last])
        fix = fixes[int(inverse[last])]
        host = int(batch.timestamp_ns[i])
        utc = fix_time_ns(fix, host)  # $GPGGA has no date: the capture clock's, to the nearest midnight
        if utc is not None and not self.clock.anchor(host, int(pos.timestamp_us[i]), utc):
            self.stats.gps_fixes_ignored += 1

    def push_auxiliary(self, batch: PacketBatch) -> None:
        """The :class:`~lidarpkt.core.decoder.Decoder` name of :meth:`push_position`."""
        self.push_position(batch)

    # ------------------------------------------------------------------ data packets
    def push(self, batch: PacketBatch) -> list[Frame]:
        """Decode a batch of data packets; returns the frames it completed (possibly none)."""
        n = len(batch)
        self.stats.packets += n
        if n == 0:
            return []
        if batch.payload_size != DATA_PACKET_SIZE:
            self.stats.malformed_size += n
            self._pending_counters.malformed_packets += n
            warn(SkippedPacketWarning(
                f"{self.source or self.model.name}: skipped {n} packets of {batch.payload_size} B (a "
                f"{self.model.name} data packet has {DATA_PACKET_SIZE} B)"), stacklevel=2)
            return []
        return self._push_data(batch)

    def _push_data(self, batch: PacketBatch) -> list[Frame]:
        raw = decode_packets(batch.payload, copy=False)
        if not self._model_given or not self._timing_set or self.model.product_ids:
            self._resolve_model(raw, raw.timestamp_us)
        if self.geometry is None:  # an HDL-64E whose calibration its status cycle has not yet brought
            return self._await_calibration(batch, raw)
        if not self.model.product_ids and self.model.dual_layout == "upper_lower":
            raw = hdl64e_modes(raw)
        kept = self._keep_sound(batch, raw)
        if kept is None:
            return []
        raw, times, index, restart = kept
        if self._product_id is None:
            self._product_id = int(raw.product_id[0])
        abs_ns = self.absolute_time_ns(raw.timestamp_us, times)
        frames: list[Frame] = []
        # runs of one return mode, and of one stream between restarts
        change = np.flatnonzero(np.diff(raw.return_mode.astype(np.int16))) + 1
        bounds = sorted({0, *change.tolist(), *np.flatnonzero(restart).tolist(), len(raw)})
        for a, b in zip(bounds[:-1], bounds[1:]):
            if restart[a]:  # the clock jumped and went on from there: a new stream, nothing lost or late
                frames += self._flush(end="cut")
                self._last_abs_ns = self._last_key = self._last_az_cdeg = None
            frames += self._push_run(raw.select(slice(a, b)), abs_ns[a:b], index[a:b], times[a:b])
        self.stats.frames += len(frames)
        return frames

    def _push_run(self, raw: DataPackets, abs_ns: np.ndarray, index: np.ndarray, host_ns: np.ndarray) -> list[Frame]:
        mode = RETURN_MODES[int(raw.return_mode[0])]
        frames: list[Frame] = []
        if self._mode is not None and mode != self._mode:
            frames += self._flush(end="cut")
            self._last_abs_ns = None
            self._last_key = None
            self._last_az_cdeg = None
        self._mode = mode
        if self._frequency_hz is None:
            self._frequency_hz = rotation_frequency_hz(raw.azimuth_cdeg, raw.return_mode == DUAL, self.model)
            if self._frequency_hz is None and self.model.dual_layout == "banks" and len(raw) > 1:
                rate = median(interpacket_rate_cdeg_s(raw.azimuth_cdeg[:, 0], raw.timestamp_us,
                                                      packet_layout(self.model, mode),
                                                      self.model.packet_period_us(mode), None, None)[0])
                self._frequency_hz = round(float(rate) / 36000.0, 2) or None
        ordered = self._in_order(raw, abs_ns, index, host_ns)
        if ordered is None:
            return frames
        raw, abs_ns, index, host_ns = ordered
        self.stats.decoded_packets += len(raw)
        gaps, missing = self._lost(raw, abs_ns, host_ns, mode)
        long_gap = gaps > self.max_gap_ns
        cuts = np.flatnonzero(long_gap)
        bounds = sorted({0, *cuts.tolist(), len(raw)})
        for a, b in zip(bounds[:-1], bounds[1:]):
            if a in cuts:
                self.stats.long_gaps += 1
                self.stats.lost_packets += int(missing[a])
                self._pending_counters.lost_packets += int(missing[a])
                frames += self._flush(end="cut")
                self._last_key = None
                self._last_az_cdeg = None
                miss = missing[a:b].copy()
                miss[0] = 0
            else:
                miss = missing[a:b]
            self.stats.lost_packets += int(miss.sum())
            # a piece at a time: a frame holds views of its piece's arrays, so memory follows the piece, not the batch
            piece = max(1, PIECE_COLUMNS // self.model.columns_per_packet(mode))
            for lo in range(a, b, piece):
                hi = min(b, lo + piece)
                cols = self._columns(raw.select(slice(lo, hi)), abs_ns[lo:hi], index[lo:hi], miss[lo - a:hi - a], mode)
                frames += self._append(cols)
        self._last_abs_ns = int(abs_ns[-1])
        self._last_host_ns = int(host_ns[-1])
        self._last_packet_az_cdeg = int(raw.azimuth_cdeg[-1, -1])
        return frames

    def _columns(self, raw: DataPackets, abs_ns: np.ndarray, index: np.ndarray, miss: np.ndarray, mode: str) -> Columns:
        if self.model.sequences_per_block != 2:  # not a 16-laser Puck: the table-driven path
            rng, refl, az_px = layout_pixels(raw, packet_layout(self.model, mode), self._packet_rates(raw, mode),
                                             self._row_laser, round(self.model.distance_resolution_m * 1000))
        else:
            dual = mode == "dual"
            slots = 2 if dual else 1
            dt = firing_dt_s(dual)[::slots]  # dual: one block of each pair (the pair shares its firings)
            rng, refl, az_px = column_pixels(raw, packet_rate_cdeg_s_vlp16(raw.azimuth_cdeg, dual), dt,
                                             self._row_laser, slots, self.model.sequences_per_block)
        return finish_columns(rng, refl, az_px, abs_ns, index, miss, self.model.columns_per_packet(mode), self.model,
                              self._row_laser, self._last_az_cdeg)

    def _packet_rates(self, raw: DataPackets, mode: str) -> np.ndarray:
        """``float32[N]`` rotation rate of each packet, 0.01° per second, as velodyne_decoder measures it."""
        lay = packet_layout(self.model, mode)
        if self.model.dual_layout != "banks":
            return packet_rate_cdeg_s(raw.azimuth_cdeg, lay)
        rate, self._prev_first_az, self._prev_stamp_us = interpacket_rate_cdeg_s(
            raw.azimuth_cdeg[:, 0], raw.timestamp_us, lay, self.model.packet_period_us(mode),
            self._prev_first_az, self._prev_stamp_us)
        return rate

    def _append(self, cols: Columns) -> list[Frame]:
        # azimuths are in [0, 36000): with no cut angle the key is the azimuth itself
        key = modulo_turn(cols.azimuth_cdeg - self.cut_cdeg) if self.cut_cdeg else cols.azimuth_cdeg
        if self.cut_on_block:
            key = key.copy()
            key[1::2] = key[0::2]  # runs start at a packet: even columns open a block (or block pair)
        cut_at = np.flatnonzero(wrapped(key, self._last_key)).tolist()
        self._last_key = float(key[-1])
        self._last_az_cdeg = float(cols.azimuth_cdeg[-1])
        frames = []
        pieces = cols.split(cut_at) if cut_at else [cols]
        for piece in pieces[:-1]:
            if len(piece):
                self._pending.append(piece)
            frames += self._flush(end="wrap")
        self._pending.append(pieces[-1])
        self._pending_columns = len(pieces[-1]) if len(pieces) > 1 else self._pending_columns + len(cols)
        if self._pending_columns > self.max_frame_columns:
            # the azimuth never wrapped (sensor not rotating, or a broken encoder): bound the memory
            self.stats.overlong_frames += 1
            frames += self._flush(end="overlong")
        return frames

    def _flush(self, *, end: str) -> list[Frame]:
        """Release the pending columns as a frame. ``end`` says why it ends: ``"wrap"`` (the next
        column wrapped past the cut), ``"cut"`` (a long loss, a mode change, the end of the stream) or
        ``"overlong"`` (no wrap within ``max_frame_columns``: always partial)."""
        parts = [p for p in self._pending if len(p)]
        counters = self._pending_counters
        start_unknown = self._start_unknown
        self._pending, self._pending_columns = [], 0
        self._pending_counters = FrameCounters()
        self._start_unknown = end != "wrap"  # the next frame begins at a wrap only after one
        if not parts:
            return []
        cols = Columns.concat(parts)
        lost = int(cols.lost.sum())  # counts, none negative: any lost when the sum is
        counters.lost_packets += lost
        partial = end == "overlong" or not self._is_whole(cols.azimuth_cdeg, start_unknown, end == "cut", lost > 0)
        frame = self._make_frame(cols, partial, counters)
        return [frame]

    def _is_whole(self, azimuth_cdeg: np.ndarray, check_start: bool, check_end: bool, lost: bool) -> bool:
        """Whether a frame's columns hold its whole rotation (see :func:`~lidarpkt.core.rotation.rotation_is_whole`)."""
        hz = self._frequency_hz
        fallback = hz * 36000.0 * self.model.sequence_ns * 1e-9 if hz else None
        return rotation_is_whole(azimuth_cdeg, self.cut_cdeg, check_start=check_start, check_end=check_end,
                                 by_block=self.cut_on_block, fallback_step_cdeg=fallback, lost_columns=lost)

    def finish(self) -> list[Frame]:
        """The last frame, if any columns are pending (partial unless it reaches the cut angle).

        The decoder can be reused afterwards.

        Raises :class:`CalibrationError` when HDL-64E packets are still held because their status cycle
        never brought a calibration.
        """
        if self.geometry is None and self._held_packets:
            n, self._held, self._held_packets = self._held_packets, [], 0
            raise CalibrationError(
                f"{self.source or self.model.name}: the status bytes of the {n} {self.model.name} packets held no "
                "whole calibration; pass the unit's calibration (calibration=, --calibration)")
        frames = self._flush(end="cut")
        self._last_key = None
        self._last_az_cdeg = None
        self.stats.frames += len(frames)
        return frames

    # ------------------------------------------------------------------ frames
    def sensor_info(self, mode: str | None = None) -> SensorInfo:
        """The :class:`SensorInfo` of this sensor in return mode ``mode`` (default: the current one,
        ``"strongest"`` before any packet)."""
        mode = mode or self._mode or "strongest"
        info = self._sensors.get(mode)
        if info is None:
            cal = self.calibration
            rows = self._row_laser
            freq = self._frequency_hz
            info = SensorInfo(
                vendor="velodyne", model=self.model.name, rows=self.model.lasers,
                columns_per_frame=self.model.columns_per_rotation(freq),
                return_mode=mode, return_labels=LABELS[mode],
                # an HDL-64E before its status cycle brought the calibration: no angles yet
                beam_altitude_deg=cal.elevation_deg[rows] if cal is not None else np.zeros(self.model.lasers),
                beam_azimuth_deg=(np.degrees(np.asarray(cal.rot_correction_rad)[rows]) if cal is not None
                                  else np.zeros(self.model.lasers)),
                frequency_hz=freq, grid_resolution_deg=self.model.grid_resolution_deg, geometry=self.geometry,
                product_id=self._product_id, source=self.source, profile=mode,
            )
            if self._mode is not None and cal is not None:  # kept once packets have told the rate and product id
                self._sensors[mode] = info
        return info

    def _make_frame(self, cols: Columns, partial: bool, counters: FrameCounters) -> Frame:
        mode = self._mode or "strongest"
        # a row's offset in every column, 0 in columns no packet delivered; read-only, and with every column
        # delivered a view of a shared image of them (no [16, W] int64 image written per frame)
        toff = row_offsets_ns(self.model, self._row_laser, len(cols))
        if not cols.valid.all():
            toff = np.where(cols.valid, toff, 0)
            toff.flags.writeable = False
        extra = {"azimuth_cdeg": cols.azimuth_px, "packet_index": cols.packet_index}
        if mode == "dual":
            extra["second_strongest"] = second_strongest_mark(cols.range_mm, cols.reflectivity)
        frame = Frame(
            sensor=self.sensor_info(mode), frame_id=self._frame_id, range_mm=cols.range_mm,
            reflectivity=cols.reflectivity, return_labels=LABELS[mode], column_valid=cols.valid,
            column_timestamp_ns=cols.timestamp_ns, azimuth_deg=cols.azimuth_cdeg / 100.0,
            pixel_time_offset_ns=toff, partial=partial, counters=counters, extra=extra,
        )
        self._frame_id += 1
        return frame
