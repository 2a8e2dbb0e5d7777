"""RoboSense frame assembly: MSOP packets → range-image columns (:mod:`lidarpkt.vendors.robosense.columns`) →
frames cut where the block azimuth wraps.

The sensor first. What the MSOP cannot say, the DIFOP does: the return mode of the RS-LiDAR-16/32,
RS-Bpearl and Helios families, and the sensor's own calibration. So the decoder holds the first
packets of a stream until a DIFOP comes (a sensor sends one a second), ``difop_wait_s`` of packets
at most, then settles, once: the model (``model=``, else the MSOP header, else the returns:
:func:`lidarpkt.vendors.robosense.detect.detect_model`), the return mode (the DIFOP's; without one:
RS-Ruby's ``wave_mode``, block pairs of equal azimuth for dual return, else single return labelled
``unknown``) and the calibration (the DIFOP's; without one the angle CSV given as ``calibration``;
without either, frames have no XYZ and rows are lasers in packet order). Nothing is dropped while
waiting. A later DIFOP changes the return mode (the frame is cut), and gives a calibration to a
stream that had none.

Rows: lasers sorted by elevation, highest first. Columns: firing sequences in time order; every
column a packet delivered (``column_valid`` is True throughout; lost packets leave no columns and
:meth:`Frame.on_grid` shows them as invalid bins). Per column: ``azimuth_deg`` (its first firing),
``column_timestamp_ns`` (its first firing, the sensor's clock); ``pixel_time_offset_ns`` each laser's
firing after it. ``frame.extra``: ``azimuth_cdeg`` (``uint16[H, W]``, each firing's azimuth, 0.01°,
the input of XYZ) and ``packet_index`` (``int64[W]``). ``range_mm`` is the distance rounded to the
millimetre (half up; the 2.5 mm unit of the Helios family has half millimetres), the exact one being
what :mod:`lidarpkt.vendors.robosense.geometry` computes from it.

Cuts: where a block's azimuth (minus the cut angle) wraps, between blocks (a block's two columns stay
together), as rs_driver and nebula cut; a return-mode or distance-unit change, a stretch of more than
``max_gap_s`` without packets, or ``max_frame_columns`` columns without a wrap end a frame too.
``partial`` as for the Hesai decoder (:func:`lidarpkt.core.rotation.rotation_is_whole`).

Order and loss: packets are put in time order (counted); duplicates and packets older than an earlier
batch's are dropped and counted. Losses come from the header's packet counter where the model has
one (RS-Helios family, RS-Bpearl), else from steps of the packet time; a jump the capture time cannot
explain is a corrupted packet or a restart (:mod:`lidarpkt.core.continuity`), never a loss, and losses
never exceed what the capture time can hold.
"""

from __future__ import annotations

import itertools

import numpy as np

from lidarpkt.core.frame import Frame, FrameCounters
from lidarpkt.core.median import median
from lidarpkt.core.sensor import SensorInfo
from lidarpkt.core.packet import PacketBatch
from lidarpkt.core.readahead import warn
from lidarpkt.core.rotation import modulo_turn, rotation_is_whole, wrapped
from lidarpkt.errors import SkippedPacketWarning, UnknownSensorError
from . import packet as P
from .calibration import RobosenseCalibration, from_device, load_calibration
from .columns import Columns, RubyDualColumns, build_columns, nominal_step_cdeg, plan
from .decode import RobosensePackets, decode_packets
from .detect import FAMILY_NAMES, detect_model, is_difop, model_from_header, msop_family
from .difop import DeviceInfo, decode_difop
from .models import FAMILIES, ROTATION_RPM, RobosenseModel, model_named
from .sensor import describe_sensor
from .stream import DecoderStats, StreamLoss, packet_period_ns


class RobosenseDecoder:
    """Frames of one RoboSense sensor from its MSOP and DIFOP packets (a :class:`lidarpkt.core.decoder.Decoder`).

    Args:
        model: a :class:`~lidarpkt.vendors.robosense.models.RobosenseModel` or its name; by default
            detected (see the module docstring).
        calibration: the sensor's angle CSV (path) or a loaded
            :class:`~lidarpkt.vendors.robosense.calibration.RobosenseCalibration`, used when the capture
            holds no DIFOP.
        cut_angle_deg: cut frames where the block azimuth passes this angle instead of 0°.
        source: a name for reports.
        max_gap_s: a stretch longer than this without packets ends the frame.
        max_frame_columns: a frame without a wrap after this many columns is released as partial.
        difop_wait_s: how long the first packets wait for a DIFOP, counted in packets (as many as the
            model sends in that time in dual return, its fastest).
        difop: a DIFOP packet (bytes) taken as if it came first (the capture's, for a reader starting past it):
            the first packets need not wait.

    Raises:
        UnknownSensorError: a model name not in the table.
        CalibrationError: an unreadable calibration.
    """

    def __init__(self, *, model: RobosenseModel | str | None = None, calibration=None,
                 cut_angle_deg: float | None = None, source: str | None = None, max_gap_s: float = 0.2,
                 max_frame_columns: int = 65536, difop_wait_s: float = 1.2, difop: bytes | None = None) -> None:
        self.model: RobosenseModel | None = model_named(model) if isinstance(model, str) else model
        self._model_given = self.model is not None
        self._csv: RobosenseCalibration | None = None if calibration is None else load_calibration(calibration)
        self.cut_cdeg = 0.0 if cut_angle_deg is None else float(cut_angle_deg) % 360.0 * 100.0
        self.source = source
        self.max_gap_ns = int(max_gap_s * 1e9)
        self.max_frame_columns = int(max_frame_columns)
        self.difop_wait_ns = int(difop_wait_s * 1e9)
        self.stats = DecoderStats()
        self.device: DeviceInfo | None = None  # the last DIFOP taken
        self.calibration: RobosenseCalibration | None = None
        self._settled = False
        self._held: list[tuple[RobosensePackets, np.ndarray, np.ndarray]] = []
        self._held_payload: list[np.ndarray] = []
        self._difop_rows: list[np.ndarray] = []  # DIFOPs that came before the first MSOP packet
        self._mode: tuple[int, int | None] | None = None  # (returns per firing, the DIFOP's mode byte)
        self._rotation_hz: int | None = None
        self._unit_um: int | None = None
        self._loss: StreamLoss | None = None
        self._ruby_dual: RubyDualColumns | None = None
        self._pending: list[Columns] = []
        self._pending_columns = 0
        self._pending_counters = FrameCounters()
        self._start_unknown = True
        self._last_key: float | None = None
        self._last_ts: int | None = None
        self._last_run_ts: int | None = None
        self._sensors: dict[tuple, SensorInfo] = {}
        self._frame_id = 0
        if difop is not None:
            self._take_difop(np.frombuffer(difop, np.uint8)[None, :])
            self.stats.difop_packets -= 1  # given, not a packet of this read

    # ------------------------------------------------------------------ packets in
    def push(self, batch: PacketBatch) -> list[Frame]:
        """Decode a batch of the sensor's packets (MSOP; DIFOPs among them are taken as by
        :meth:`push_auxiliary`); returns the frames it completed."""
        n = len(batch)
        if n == 0:
            return []
        if batch.payload_size != P.PACKET_SIZE:
            self.stats.packets += n
            return self._skip(n, f"{n} packets of {batch.payload_size} B, which no RoboSense model sends", size=True)
        difop = is_difop(batch.payload)
        if difop.any():
            self._take_difop(batch.payload[difop])
            if difop.all():
                return self._release() if self._ready() else []
            batch = batch.select(~difop)
            n = len(batch)
        self.stats.packets += n
        if self.model is None:
            family = msop_family(batch.payload[:16])
            family = family[family >= 0]
            if family.size * 2 <= min(n, 16):
                return self._skip(n, f"{n} packets that are no RoboSense MSOP packets lidarpkt knows", size=True)
            name = FAMILY_NAMES[int(np.bincount(family).argmax())]
            self.model = model_from_header(batch.payload, name) or FAMILIES[name][0]
            waiting, self._difop_rows = self._difop_rows, []
            for rows in waiting:
                self.stats.difop_packets -= len(rows)  # counted when they came
                self._take_difop(rows)
        raw = decode_packets(batch.payload, self.model)
        times, index, payload = batch.timestamp_ns, batch.index, batch.payload
        bad = int(np.count_nonzero(~raw.valid))
        if bad:
            self.stats.malformed_fields += bad
            self._pending_counters.malformed_packets += bad
            warn(SkippedPacketWarning(f"{self.source or self.model.name}: skipped {bad} {self.model.name} packets with "
                                      "impossible fields (header id, block flag, azimuth, distance unit, return id "
                                      "or time)"), stacklevel=2)
            raw, times, index, payload = raw.select(raw.valid), times[raw.valid], index[raw.valid], payload[raw.valid]
            if len(raw) == 0:
                return []
        if not self._settled:
            self._held.append((raw, index, times))
            self._held_payload.append(payload)
            return self._release() if self._ready() else []
        return self._process(raw, index, times)

    def push_auxiliary(self, batch: PacketBatch) -> None:
        """Take a batch of DIFOP packets: the return mode and calibration they carry (refused ones are counted)."""
        rows = batch.payload[is_difop(batch.payload)] if batch.payload_size == P.PACKET_SIZE else batch.payload[:0]
        if len(rows) < len(batch):
            self.stats.difop_malformed += len(batch) - len(rows)
        if len(rows):
            self._take_difop(rows)

    def finish(self) -> list[Frame]:
        """The frames still held or being filled at the end of the capture (the last one partial unless
        it reaches the cut angle)."""
        frames = self._settle() if not self._settled else []
        frames += self._cut()
        self._last_key = None
        return frames

    # ------------------------------------------------------------------ DIFOP and settling
    def _take_difop(self, rows: np.ndarray) -> None:
        self.stats.difop_packets += len(rows)
        if self.model is None:  # its layout is the model's: read it once an MSOP packet tells the model
            self._difop_rows.append(np.array(rows, copy=True))
            return
        for row in rows:
            info = decode_difop(row, self.model)
            if info is None:
                self.stats.difop_malformed += 1
                warn(SkippedPacketWarning(f"{self.source or self.model.name}: skipped a DIFOP packet with an "
                                          "impossible identifier, tail, return mode or angles"), stacklevel=3)
                continue
            self.device = info
            if self._settled:
                self._device_changed(info)

    def _ready(self) -> bool:
        """Settle now: a DIFOP came, or the packets held span ``difop_wait_s`` (counted in the shortest
        packet period of the model, so that a packet's damaged time cannot end the wait early)."""
        if not self._held:
            return False
        if self.device is not None:
            return True
        assert self.model is not None
        held = sum(len(h[0]) for h in self._held)
        return bool(held * packet_period_ns(self.model, 2) >= self.difop_wait_ns)

    def _release(self) -> list[Frame]:
        return self._settle()

    def _settle(self) -> list[Frame]:
        """Decide the model, return mode and calibration from what is held, then decode the held packets."""
        self._settled = True
        held, self._held = self._held, []
        payload = np.concatenate(self._held_payload) if self._held_payload else None
        self._held_payload = []
        if not held:
            return []
        assert self.model is not None
        if not self._model_given and payload is not None and model_from_header(payload, self.model.family) is None:
            found = detect_model(payload, self.model.family)
            if found is not None and found.layout == self.model.layout:
                self.model = found
        raw = RobosensePackets.concatenate([h[0] for h in held])
        index = np.concatenate([h[1] for h in held])
        times = np.concatenate([h[2] for h in held])
        self._choose_calibration()
        if self.device is not None:
            self._rotation_hz = max(1, self.device.motor_speed_rpm // 60)
        return self._process(raw, index, times)

    def _choose_calibration(self) -> None:
        model = self.model
        assert model is not None
        if self.device is not None:
            self.calibration = from_device(self.device.elevation_deg, self.device.azimuth_offset_deg)
        elif self._csv is not None:
            self.calibration = self._csv.first(model.lasers)

    def _device_changed(self, info: DeviceInfo) -> None:
        if self.calibration is None:
            self.calibration = from_device(info.elevation_deg, info.azimuth_offset_deg)
        self._rotation_hz = max(1, info.motor_speed_rpm // 60)

    # ------------------------------------------------------------------ decoding
    def _mode_of(self, raw: RobosensePackets) -> np.ndarray:
        """``int8[N]`` returns per firing of each packet."""
        model = self.model
        assert model is not None
        n = len(raw)
        if raw.wave_mode is not None:
            return np.where(raw.wave_mode == 3, 2, 1).astype(np.int8)
        if self.device is not None:
            return np.full(n, len(model.return_modes[self.device.return_mode]), np.int8)
        if model.dual_layout == "block_pairs":
            az = raw.azimuth_cdeg
            return np.where(np.all(az[:, 0::2] == az[:, 1::2], axis=1), 2, 1).astype(np.int8)
        return np.ones(n, np.int8)

    def _process(self, raw: RobosensePackets, index: np.ndarray, times: np.ndarray) -> list[Frame]:
        model = self.model
        assert model is not None
        if self._loss is None:
            self._loss = StreamLoss(model)
        st = self._loss.check_arrival(raw, times)
        keep = st.keep
        if st.corrupted:
            self.stats.corrupted_packets += st.corrupted
            self._pending_counters.malformed_packets += st.corrupted
            warn(SkippedPacketWarning(f"{self.source or model.name}: skipped {st.corrupted} packets whose time jumped "
                                      "further than the capture time allows (corrupted)"), stacklevel=3)
            raw, index, times = raw.select(keep), index[keep], times[keep]
        self.stats.restarts += st.restarts
        restart, begins = st.restart[keep], st.begins[keep]
        frames: list[Frame] = []
        for a, b in itertools.pairwise(sorted({0, *np.flatnonzero(restart).tolist(), len(raw)})):
            if restart[a]:  # the clock jumped and went on from there: a new stream, nothing lost or late
                frames += self._cut()
                self._last_key = self._last_ts = self._last_run_ts = None
            frames += self._process_run(raw.select(slice(a, b)), index[a:b], times[a:b], begins[a:b])
        return frames

    def _process_run(self, raw: RobosensePackets, index: np.ndarray, times: np.ndarray,
                     begins: np.ndarray) -> list[Frame]:
        raw, index, times, begins = self._in_order(raw, index, times, begins)
        if len(raw) == 0:
            return []
        assert self._loss is not None
        returns = self._mode_of(raw)
        lost = self._loss.lost(raw, times, returns, begins)
        self.stats.decoded_packets += len(raw)
        if self._rotation_hz is None:
            self._rotation_hz = self._estimate_rotation(raw, int(returns[0]))
        frames: list[Frame] = []
        change = np.flatnonzero((np.diff(returns) != 0) | (np.diff(raw.distance_unit_um) != 0)) + 1
        gaps = np.flatnonzero(np.diff(raw.timestamp_ns) > self.max_gap_ns) + 1
        for a, b in itertools.pairwise(sorted({0, *change.tolist(), *gaps.tolist(), len(raw)})):
            mode = (int(returns[a]), self.device.return_mode if self.device is not None else None)
            unit = int(raw.distance_unit_um[a])
            first_ts = int(raw.timestamp_ns[a])
            if self._mode is not None and (mode != self._mode or unit != self._unit_um):
                self.stats.mode_changes += 1
                frames += self._cut()
                self._last_key = None
            elif self._last_run_ts is not None and first_ts - self._last_run_ts > self.max_gap_ns:
                self.stats.long_gaps += 1
                frames += self._cut()
                self._last_key = None
            self._mode, self._unit_um = mode, unit
            lost_here = int(lost[a:b].sum())
            self.stats.lost_packets += lost_here
            self._pending_counters.lost_packets += lost_here
            frames += self._append(self._columns(raw.select(slice(a, b)), index[a:b], mode[0]))
            self._last_run_ts = int(raw.timestamp_ns[b - 1])
        return frames

    def _estimate_rotation(self, raw: RobosensePackets, n_returns: int) -> int:
        """The rotation rate (Hz, one of the sensors' rates) from the azimuth steps between block groups."""
        model = self.model
        assert model is not None
        p = plan(model, n_returns) if not (n_returns == 2 and model.dual_layout == "ret_id") else plan(model, 1)
        az = raw.azimuth_cdeg[:, p.first_block].astype(np.int64)
        steps = (az[:, 1:] - az[:, :-1]) % 36000 if az.shape[1] > 1 else np.zeros((0,), np.int64)
        steps = steps[(steps > 0) & (steps <= 100)] if steps.size else steps
        if steps.size == 0:
            return 10
        hz = median(steps) / (36000 * p.period_ns * 1e-9)
        return min((r // 60 for r in ROTATION_RPM), key=lambda rate: abs(rate - hz))

    def _columns(self, raw: RobosensePackets, index: np.ndarray, n_returns: int) -> Columns:
        model = self.model
        assert model is not None and self._rotation_hz is not None
        if n_returns == 2 and model.dual_layout == "ret_id":
            if self._ruby_dual is None:
                self._ruby_dual = RubyDualColumns(model)
            return self._ruby_dual.build(raw, index, nominal_step_cdeg(self._rotation_hz, model.block_period_ns))
        nominal = nominal_step_cdeg(self._rotation_hz, model.group_period_ns(n_returns))
        return build_columns(raw, index, model, n_returns, nominal)

    def _cut(self) -> list[Frame]:
        """End the frame being filled (after the RS-Ruby's dual-return column still waiting for its second return)."""
        frames: list[Frame] = []
        if self._ruby_dual is not None and self._mode is not None and self._mode[0] == 2:
            model = self.model
            assert model is not None and self._rotation_hz is not None
            empty = decode_packets(np.zeros((0, P.PACKET_SIZE), np.uint8), model)
            frames += self._append(self._ruby_dual.build(
                empty, np.zeros(0, np.int64), nominal_step_cdeg(self._rotation_hz, model.block_period_ns), final=True))
        return frames + self._flush(end="cut")

    def _in_order(self, raw: RobosensePackets, index: np.ndarray, times: np.ndarray, begins: np.ndarray):
        """Packets in time order (those put back counted out of order); duplicates and packets older
        than the last one of an earlier batch dropped and counted."""
        ts = raw.timestamp_ns
        if ts.size > 1 and np.any(np.diff(ts) < 0):
            back = int(np.count_nonzero(np.diff(ts) < 0))
            order = np.argsort(ts, kind="stable")
            self.stats.out_of_order_packets += back
            self._pending_counters.out_of_order_packets += back
            raw, index, times, begins, ts = raw.select(order), index[order], times[order], begins[order], ts[order]
        keep = np.ones(ts.size, bool)
        keep[1:] = ts[1:] != ts[:-1]
        dup = int(np.count_nonzero(~keep))
        if self._last_ts is not None:
            late = ts < self._last_ts
            dup += int(np.count_nonzero(ts == self._last_ts))
            keep &= ts > self._last_ts
            self.stats.late_packets += int(np.count_nonzero(late))
            self._pending_counters.late_packets += int(np.count_nonzero(late))
        self.stats.duplicate_packets += dup
        self._pending_counters.duplicate_packets += dup
        if not keep.all():
            raw, index, times, begins = raw.select(keep), index[keep], times[keep], begins[keep]
        if len(raw):
            self._last_ts = int(raw.timestamp_ns[-1])
        return raw, index, times, begins

    def _skip(self, n: int, why: str, size: bool = False) -> list[Frame]:
        if size:
            self.stats.malformed_size += n
        self._pending_counters.malformed_packets += n
        warn(SkippedPacketWarning(f"{self.source or 'RoboSense stream'}: skipped {why}"), stacklevel=3)
        return []

    # ------------------------------------------------------------------ frames
    def _append(self, cols: Columns) -> list[Frame]:
        if cols.count == 0:
            return []
        key = modulo_turn(cols.block_azimuth_cdeg - self.cut_cdeg)
        cut_at = np.flatnonzero(wrapped(key, self._last_key)).tolist()
        self._last_key = float(key[-1])
        frames: list[Frame] = []
        start = 0
        for at in cut_at:
            if at > start:
                self._pending.append(cols.take(slice(start, at)))
            frames += self._flush(end="wrap")
            start = at
        self._pending.append(cols.take(slice(start, None)))
        self._pending_columns = sum(p.count for p in self._pending)
        if self._pending_columns > self.max_frame_columns:
            self.stats.overlong_frames += 1
            frames += self._flush(end="overlong")
        return frames

    def _flush(self, *, end: str) -> list[Frame]:
        parts = [p for p in self._pending if p.count]
        counters, start_unknown = self._pending_counters, self._start_unknown
        self._pending, self._pending_columns = [], 0
        self._pending_counters = FrameCounters()
        self._start_unknown = end != "wrap"
        if not parts:
            return []
        cols = Columns.concatenate(parts)
        whole = end != "overlong" and self._is_whole(cols, start_unknown, end == "cut")
        return [self._make_frame(cols, not whole, counters)]

    def _is_whole(self, cols: Columns, check_start: bool, check_end: bool) -> bool:
        model = self.model
        assert model is not None and self._mode is not None
        two = model.columns_per_block(self._mode[0]) == 2
        return rotation_is_whole(cols.azimuth_cdeg.astype(np.float64), self.cut_cdeg, check_start=check_start,
                                 check_end=check_end, by_block=two,
                                 fallback_step_cdeg=model.grid_resolution_deg(self._rotation_hz or 10) * 100)

    def sensor_info(self, mode: str | None = None) -> SensorInfo:
        """The :class:`SensorInfo` of the current return mode (``mode``, ``"single"`` or ``"dual"``, picks one).

        Raises :class:`~lidarpkt.errors.UnknownSensorError` before the first packet when no model was given."""
        model = self.model
        if model is None:
            raise UnknownSensorError(f"{self.source or 'RoboSense stream'}: no packet yet to tell the model")
        current = self._mode or (1, self.device.return_mode if self.device is not None else None)
        if mode is not None:
            current = (2 if mode == "dual" else 1, current[1] if (2 if mode == "dual" else 1) == current[0] else None)
        unit = self._unit_um or model.distance_unit_um or 2500
        key = (current, unit, id(self.calibration), self._rotation_hz, self.source)
        info = self._sensors.get(key)
        if info is None:
            info = self._sensors[key] = describe_sensor(model, current[0], current[1], self.calibration, unit,
                                                        self._rotation_hz, self.device, self.source)
        return info

    def _make_frame(self, cols: Columns, partial: bool, counters: FrameCounters) -> Frame:
        model = self.model
        assert model is not None and self._mode is not None
        info = self.sensor_info()
        rows = self.calibration.rows() if self.calibration is not None else np.arange(model.lasers)
        n_returns = self._mode[0]
        unit_um = int(cols.unit_um[0])  # one a frame: a change cuts it
        # millimetres rounded half up: (raw · 2u/1000 + 1) / 2, u/1000 being whole or half millimetres
        range_mm = cols.distance[:, rows, :].astype(np.uint32)
        range_mm *= np.uint32(unit_um // 500)
        range_mm += np.uint32(1)
        range_mm >>= np.uint32(1)
        table = plan(model, 1 if model.dual_layout == "ret_id" else n_returns).time_table[:, rows]  # [K, H]
        frame = Frame(
            sensor=info, frame_id=self._frame_id, range_mm=range_mm, reflectivity=cols.reflectivity[:, rows, :],
            return_labels=info.return_labels, column_valid=np.ones(cols.count, bool),
            column_timestamp_ns=cols.timestamp_ns, azimuth_deg=cols.azimuth_cdeg / 100.0,
            pixel_time_offset_ns=np.ascontiguousarray(table[cols.time_key.astype(np.intp)].T), partial=partial,
            counters=counters, extra={"azimuth_cdeg": cols.pixel_azimuth_cdeg[rows, :],
                                      "packet_index": cols.packet_index},
        )
        self._frame_id += 1
        self.stats.frames += 1
        return frame
