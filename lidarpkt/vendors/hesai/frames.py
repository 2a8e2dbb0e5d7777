"""Hesai Pandar frame assembly: packets → range-image columns → frames cut where the azimuth wraps.

Columns. One column per firing: a packet of B blocks in a mode of n returns per firing holds B / n
columns (blocks k·n … k·n + n − 1 are the n returns of column k). Return slot r of a column is
block k·n + r, labelled as the return mode says (:data:`lidarpkt.vendors.hesai.models.RETURN_MODES`,
:meth:`HesaiModel.labels`); frames have as many slots as the mode has returns.

Rows. Row 0 is the channel of highest elevation in the calibration (the angle-correction CSV),
down to the lowest; without a calibration rows are the channels in packet order (row h = channel h)
and ``beam_altitude_deg`` is NaN.

Per column: ``azimuth_deg`` is the block azimuth (0.01°); ``column_timestamp_ns`` the time of the
column's first firing: the packet time (UTC second + µs of its tail) plus the earliest firing
offset of the column's channels (:mod:`lidarpkt.vendors.hesai.timing`); ``pixel_time_offset_ns``
(``int64[H, W]``) each channel's firing after it.

``frame.extra``: ``packet_index`` (``int64[W]``, ordinal of the column's packet in the source),
``motor_speed_rpm`` (``uint16[W]``), and in Last+Strongest / First+Strongest modes
``second_strongest`` (``bool[H, W]``): slot 1 holds the second strongest return because slot 0 is the
strongest (its reflectivity is higher; see :mod:`lidarpkt.vendors.hesai.models` for the rule).

Cuts. A frame ends before the first column whose azimuth (minus the cut angle) wrapped past 0; a
return-mode change, a stretch of more than ``max_gap_s`` without packets, or ``max_frame_columns``
columns without a wrap end it too. ``partial`` as for every vendor
(:func:`~lidarpkt.core.rotation.rotation_is_whole`): True where columns of the rotation are missing, i.e.
where two columns lie further apart than the firing interval allows (packets lost inside the frame), or a
frame that does not begin (end) at a wrap has its first (last) column further than one firing interval
after (before) the cut angle.

Order and loss. Packets are put in time order within a batch (counted as out of order);
duplicates (the same packet time) and packets older than the last one of an earlier batch are
dropped and counted. Lost packets are counted from the UDP sequence number where the protocol has
one, else from gaps in packet time; their columns are put in the frame as the Velodyne decoder puts them
(``column_valid`` False, zero range, zero time, the azimuth interpolated between the columns around
them), so a frame with lost packets holds the columns of its rotation.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from lidarpkt.core.median import median
from lidarpkt.core.readahead import warn
from lidarpkt.core.continuity import StreamContinuity
from lidarpkt.errors import CalibrationError, SkippedPacketWarning
from lidarpkt.core.frame import Frame, FrameCounters
from lidarpkt.core.lost_columns import interpolated_azimuth, received_places, spread
from lidarpkt.core.sensor import SensorInfo
from lidarpkt.core.packet import PacketBatch
from lidarpkt.core.rotation import modulo_turn, rotation_is_whole, wrapped
from .calibration import HesaiCalibration, load_calibration
from .decode import HesaiPackets, decode_packets, returns_of
from .detect import detect_model
from .geometry import HesaiGeometry
from .models import MARKED_MODES, RETURN_MODE_NAMES, HesaiModel, model_named
from .timing import firing_offsets_ns


@dataclass
class DecoderStats:
    """What a :class:`HesaiDecoder` saw, counted."""

    packets: int = 0  # packets pushed
    decoded_packets: int = 0
    malformed_size: int = 0  # batches of a size (or content) that is not the model's
    malformed_fields: int = 0  # start bytes, header, azimuth, return mode, distance unit or UTC impossible
    duplicate_packets: int = 0
    out_of_order_packets: int = 0
    late_packets: int = 0
    lost_packets: int = 0
    long_gaps: int = 0
    overlong_frames: int = 0
    mode_changes: int = 0
    frames: int = 0

    @property
    def malformed(self) -> int:
        """Packets skipped as malformed."""
        return self.malformed_size + self.malformed_fields


_COLUMN_KEYS = ("range_mm", "reflectivity", "azimuth_cdeg", "timestamp_ns", "time_key", "packet_index", "rpm",
                "valid")


class HesaiDecoder:
    """Frames of one Pandar from its packets (a :class:`lidarpkt.core.decoder.Decoder`).

    Args:
        model: a :class:`~lidarpkt.vendors.hesai.models.HesaiModel` or its name; by default detected from the
            first packets.
        calibration: the sensor's angle-correction CSV (path) or a loaded
            :class:`~lidarpkt.vendors.hesai.calibration.HesaiCalibration`; without one frames have no XYZ.
        cut_angle_deg: cut frames where the azimuth passes this angle instead of 0°.
        source: a name for reports.
        max_gap_s: a stretch longer than this without packets ends the frame.
        max_frame_columns: a frame without a wrap after this many columns is released as partial.

    Raises:
        UnknownSensorError: a model name not in the table.
        CalibrationError: an unreadable calibration, or one with another number of channels.
    """

    def __init__(self, *, model: HesaiModel | str | None = None, calibration=None, cut_angle_deg: float | None = None,
                 source: str | None = None, max_gap_s: float = 0.2, max_frame_columns: int = 16384) -> None:
        self.model: HesaiModel | None = model_named(model) if isinstance(model, str) else model
        self.calibration: HesaiCalibration | None = None if calibration is None else load_calibration(calibration)
        self.cut_cdeg = 0.0 if cut_angle_deg is None else float(cut_angle_deg) % 360.0 * 100.0
        self.source = source
        self.max_gap_ns = int(max_gap_s * 1e9)
        self.max_frame_columns = int(max_frame_columns)
        self.stats = DecoderStats()
        self.geometry: HesaiGeometry | None = None
        self._row_channel: np.ndarray | None = None
        self._pending: list[dict[str, np.ndarray]] = []
        self._pending_columns = 0
        self._pending_counters = FrameCounters()
        self._start_unknown = True
        self._mode: int | None = None
        self._last_ts: int | None = None
        self._last_seq: int | None = None
        self._last_key: float | None = None
        self._period_ns: float | None = None
        self._last_host_ns = 0  # capture time of the last packet counted (0: unknown)
        self._last_column: float | None = None  # azimuth (0.01°) of the last column appended
        self._continuity = StreamContinuity(1.0)  # only its capture-time credit: losses the capture can hold
        self._rpm: int | None = None
        self._sensors: dict[int, SensorInfo] = {}
        self._time_table = np.zeros((0, 0), np.int64)  # [H, 2·G] firing offsets of the current mode (see _columns)
        self._frame_id = 0
        if self.model is not None:
            self._set_model(self.model)

    # ------------------------------------------------------------------ model and calibration
    def _set_model(self, model: HesaiModel) -> None:
        self.model = model
        cal = self.calibration
        if cal is None:
            self._row_channel = np.arange(model.channels)
            return
        if cal.channels != model.channels:
            rows = (f"channel {cal.channels + 1} has no line" if cal.channels < model.channels else
                    f"the lines of channels {model.channels + 1}-{cal.channels} are too many")
            raise CalibrationError(f"{cal.source}: a calibration of {cal.channels} channels for a {model.name}, "
                                   f"which has {model.channels} ({rows}); give the sensor's own angle-correction CSV "
                                   "(--metadata FILE; metadata=... in Python)")
        self._row_channel = np.argsort(-cal.elevation_deg, kind="stable")
        self.geometry = HesaiGeometry(cal, self._row_channel)

    # ------------------------------------------------------------------ packets
    def push_auxiliary(self, batch: PacketBatch) -> None:
        """Pandar GPS packets are not decoded; they are counted by the source as auxiliary."""

    def push(self, batch: PacketBatch) -> list[Frame]:
        """Decode a batch of one stream's packets; returns the frames it completed."""
        n = len(batch)
        self.stats.packets += n
        if n == 0:
            return []
        model = self.model
        if model is None:
            found = detect_model(batch.payload)
            if found is None:
                return self._skip_size(batch, "are no Pandar packets lidarpkt knows")
            self._set_model(found)
            model = found
        if batch.payload_size not in model.sizes:
            return self._skip_size(batch, f"do not have the size of a {model.name} packet ({model.sizes[0]} B)")
        raw = decode_packets(batch.payload, model)
        times, index = batch.timestamp_ns, batch.index
        bad = int(np.count_nonzero(~raw.valid))
        if bad:
            self.stats.malformed_fields += bad
            self._pending_counters.malformed_packets += bad
            warn(SkippedPacketWarning(f"{self.source or model.name}: skipped {bad} {model.name} packets with impossible "
                                      "fields (start bytes, header, azimuth, return mode, distance unit or time)"),
                 stacklevel=2)
            raw, times, index = raw.select(raw.valid), times[raw.valid], index[raw.valid]
        raw, index = self._in_order(raw, index)
        if len(raw) == 0:
            return []
        self.stats.decoded_packets += len(raw)
        order = np.argsort(batch.index, kind="stable")  # the kept packets' capture times, by their ordinals
        lost = self._count_lost(raw, batch.timestamp_ns[order[np.searchsorted(batch.index[order], index)]])
        frames: list[Frame] = []
        change = np.flatnonzero(np.diff(raw.return_mode.astype(np.int16))) + 1
        gaps = np.flatnonzero(np.diff(raw.timestamp_ns) > self.max_gap_ns) + 1
        bounds = sorted({0, *change.tolist(), *gaps.tolist(), len(raw)})
        for a, b in itertools.pairwise(bounds):
            mode = int(raw.return_mode[a])
            first_ts = int(raw.timestamp_ns[a])
            if self._mode is not None and mode != self._mode:
                self.stats.mode_changes += 1
                frames += self._flush(end="cut")
                self._last_column = None
            elif self._last_run_ts is not None and first_ts - self._last_run_ts > self.max_gap_ns:
                self.stats.long_gaps += 1
                frames += self._flush(end="cut")
                self._last_key = self._last_column = None
            self._mode = mode
            self._rpm = int(raw.motor_speed_rpm[b - 1])
            cols = self._columns(raw.select(slice(a, b)), index[a:b], mode)
            frames += self._append(_with_lost_columns(cols, lost[a:b], len(cols["valid"]) // (b - a), self._last_column))
            self._last_run_ts = int(raw.timestamp_ns[b - 1])
        self.stats.frames += len(frames)
        return frames

    _last_run_ts: int | None = None

    def _skip_size(self, batch: PacketBatch, why: str) -> list[Frame]:
        n = len(batch)
        self.stats.malformed_size += n
        self._pending_counters.malformed_packets += n
        warn(SkippedPacketWarning(f"{self.source or 'Hesai stream'}: skipped {n} packets of {batch.payload_size} B that "
                                  f"{why}"), stacklevel=3)
        return []

    def _in_order(self, raw: HesaiPackets, index: np.ndarray) -> tuple[HesaiPackets, np.ndarray]:
        ts = raw.timestamp_ns
        if ts.size > 1 and np.any(np.diff(ts) < 0):
            order = np.argsort(ts, kind="stable")
            self.stats.out_of_order_packets += int(np.count_nonzero(np.diff(ts) < 0))
            self._pending_counters.out_of_order_packets += int(np.count_nonzero(np.diff(ts) < 0))
            raw, index, ts = raw.select(order), index[order], ts[order]
        keep = np.ones(ts.size, bool)
        keep[1:] = ts[1:] != ts[:-1]
        dup = int(np.count_nonzero(~keep))
        late = np.zeros(ts.size, bool)
        if self._last_ts is not None:
            late = ts < self._last_ts
            dup += int(np.count_nonzero(ts == self._last_ts))
            keep &= ts > self._last_ts
        self.stats.duplicate_packets += dup
        self.stats.late_packets += int(np.count_nonzero(late))
        self._pending_counters.duplicate_packets += dup
        self._pending_counters.late_packets += int(np.count_nonzero(late))
        if not keep.all():
            raw, index = raw.select(keep), index[keep]
        if len(raw):
            self._last_ts = int(raw.timestamp_ns[-1])
        return raw, index

    def _count_lost(self, raw: HesaiPackets, host_ns: np.ndarray) -> np.ndarray:
        """Packets lost between these and the ones before, by the UDP sequence number where the model sends
        one, else by the sensor's time steps; never more than the capture time between them can hold
        (:meth:`lidarpkt.core.continuity.StreamContinuity.bound_lost`). Returns how many were lost before each
        packet, ``int64[N]``."""
        dt = np.diff(raw.timestamp_ns).astype(np.float64)
        if dt.size:
            med = median(dt)
            self._period_ns = med if med > 0 else self._period_ns
        if raw.udp_sequence is not None:
            seq = raw.udp_sequence.astype(np.int64)
            prev = np.concatenate([[seq[0] - 1 if self._last_seq is None else self._last_seq], seq[:-1]])
            step = (seq - prev) % (1 << 32)
            lost = np.where((step > 1) & (step < 1 << 20), step - 1, 0)  # a restart (huge step) is no loss
            self._last_seq = int(seq[-1])
        else:
            if not self._period_ns or dt.size == 0:
                return np.zeros(len(raw), np.int64)
            lost = np.concatenate([[0], np.maximum(np.rint(dt / self._period_ns).astype(np.int64) - 1, 0)])
            lost[1:][dt > self.max_gap_ns] = 0
        host = np.asarray(host_ns, np.int64)
        prev_host = np.concatenate([[self._last_host_ns], host[:-1]])
        known = (host > 0) & (prev_host > 0)
        if self._period_ns and lost.any():
            lost = self._continuity.bound_lost(lost, np.where(known, host - prev_host, 0), known, self._period_ns)
        self._last_host_ns = int(host[-1])
        total = int(lost.sum())
        self.stats.lost_packets += total
        self._pending_counters.lost_packets += total
        return np.asarray(lost, np.int64)

    # ------------------------------------------------------------------ columns
    def _columns(self, raw: HesaiPackets, index: np.ndarray, mode: int) -> dict[str, np.ndarray]:
        model = self.model
        assert model is not None and self._row_channel is not None
        n, nret = len(raw), returns_of(mode)
        groups = model.blocks // nret
        c = model.channels
        rows = self._row_channel
        # [N, B, C] → [N, G, R, C(rows)] (gathered along the contiguous axis) → one strided copy to [R, C, N·G]
        dist = raw.distance.reshape(n, groups, nret, c)[..., rows]
        rng = np.empty((nret, c, n * groups), np.uint32)
        rng.reshape(nret, c, n, groups)[...] = dist.transpose(2, 3, 0, 1)
        unit = raw.dis_unit_mm
        if np.all(unit == unit[0]):
            rng *= np.uint32(unit[0])
        else:  # the header's unit changed within the batch
            rng.reshape(nret, c, n, groups)[...] *= unit.astype(np.uint32)[None, None, :, None]
        refl = np.empty((nret, c, n * groups), np.uint8)
        refl.reshape(nret, c, n, groups)[...] = raw.reflectivity.reshape(n, groups, nret, c)[..., rows].transpose(2, 3, 0, 1)
        az = raw.azimuth_cdeg[:, ::nret].reshape(-1)
        # firing times: one table per firing group and loop (the QT128's mode_flag; 0 elsewhere), [2, G, C];
        # a column keeps its row of the table (2·G at most), the frame gathers its [H, W] from it
        table = np.broadcast_to(firing_offsets_ns(model, nret, np.array([0, 1], np.uint8)), (2, groups, c))
        first = table.min(axis=2)  # [2, G]
        self._time_table = (table - first[:, :, None]).reshape(2 * groups, c)[:, rows].T  # [H, 2·G]
        loop = np.zeros(n, np.int64) if raw.mode_flag is None else (raw.mode_flag & 1).astype(np.int64)
        key = loop[:, None] * groups + np.arange(groups)[None, :]  # [N, G]
        ts = (raw.timestamp_ns[:, None] + first.reshape(-1)[key]).reshape(-1)
        return {"range_mm": rng, "reflectivity": refl,
                "azimuth_cdeg": az.astype(np.float64), "timestamp_ns": ts, "time_key": key.reshape(-1),
                "packet_index": np.repeat(index.astype(np.int64), groups),
                "rpm": np.repeat(raw.motor_speed_rpm, groups), "valid": np.ones(n * groups, bool)}

    def _append(self, cols: dict[str, np.ndarray]) -> list[Frame]:
        key = modulo_turn(cols["azimuth_cdeg"] - self.cut_cdeg)
        cut_at = np.flatnonzero(wrapped(key, self._last_key)).tolist()
        self._last_key = float(key[-1])
        self._last_column = float(cols["azimuth_cdeg"][-1])
        frames: list[Frame] = []
        start = 0
        for at in cut_at:
            if at > start:
                self._pending.append({k: v[..., start:at] for k, v in cols.items()})
            frames += self._flush(end="wrap")
            start = at
        self._pending.append({k: v[..., start:] for k, v in cols.items()})
        self._pending_columns = sum(p["azimuth_cdeg"].shape[0] for p in self._pending)
        if self._pending_columns > self.max_frame_columns:
            self.stats.overlong_frames += 1
            frames += self._flush(end="overlong")
        return frames

    def _flush(self, *, end: str) -> list[Frame]:
        parts = [p for p in self._pending if p["azimuth_cdeg"].shape[0]]
        counters, start_unknown = self._pending_counters, self._start_unknown
        self._pending, self._pending_columns = [], 0
        self._pending_counters = FrameCounters()
        self._start_unknown = end != "wrap"
        if not parts:
            return []
        cols = parts[0] if len(parts) == 1 else {k: np.concatenate([p[k] for p in parts], axis=-1) for k in _COLUMN_KEYS}
        whole = end != "overlong" and self._is_whole(cols["azimuth_cdeg"], start_unknown, end == "cut",
                                                     not cols["valid"].all())
        return [self._make_frame(cols, not whole, counters)]

    def _is_whole(self, azimuth_cdeg: np.ndarray, check_start: bool, check_end: bool, lost: bool) -> bool:
        fallback = self.model.grid_resolution_deg * 100.0 if self.model is not None else None
        return rotation_is_whole(azimuth_cdeg, self.cut_cdeg, check_start=check_start, check_end=check_end,
                                 fallback_step_cdeg=fallback, lost_columns=lost)

    def finish(self) -> list[Frame]:
        """The last frame, if any columns are pending (partial unless it reaches the cut angle)."""
        frames = self._flush(end="cut")
        self._last_key = None
        self.stats.frames += len(frames)
        return frames

    # ------------------------------------------------------------------ frames
    def sensor_info(self, mode: str | int | None = None) -> SensorInfo:
        """The :class:`SensorInfo` of this sensor in return mode ``mode`` (its byte or name; the current
        one by default, Last+Strongest before any packet).

        Raises :class:`~lidarpkt.errors.UnknownSensorError` before the first packet when no model was given."""
        if isinstance(mode, str):
            mode = {v: k for k, v in RETURN_MODE_NAMES.items()}[mode]
        code = int(mode if mode is not None else (self._mode if self._mode is not None else 0x39))
        info = self._sensors.get(code)
        if info is not None:
            return info
        model = self.model
        if model is None:
            from lidarpkt.errors import UnknownSensorError

            raise UnknownSensorError(f"{self.source or 'Hesai stream'}: no packet yet to tell the Pandar model")
        rows = self._row_channel
        cal = self.calibration
        hz = self._rpm / 60.0 if self._rpm else None
        nan = np.full(model.channels, np.nan)
        nominal_hz = max(5, 5 * round(hz / 5)) if hz else 10  # the rates the sensors offer: 5, 10, 20 Hz
        grid = model.grid_resolution_deg * nominal_hz / 10.0  # firings spread with the rate; divides 360°
        columns = round(360.0 / grid)
        info = SensorInfo(
            vendor="hesai", model=model.name, rows=model.channels, columns_per_frame=columns,
            return_mode=RETURN_MODE_NAMES[code], return_labels=model.labels(code),
            beam_altitude_deg=cal.elevation_deg[rows] if cal is not None else nan,
            beam_azimuth_deg=cal.azimuth_offset_deg[rows] if cal is not None else nan,
            frequency_hz=hz, grid_resolution_deg=grid,
            geometry=self.geometry, source=self.source, profile=RETURN_MODE_NAMES[code],
            metadata={"protocol": "{}.{}".format(*model.protocol) if model.protocol else None},
        )
        if self._mode is not None:
            self._sensors[code] = info
        return info

    def _make_frame(self, cols: dict[str, np.ndarray], partial: bool, counters: FrameCounters) -> Frame:
        mode = self._mode if self._mode is not None else 0x39
        assert self.model is not None
        extra = {"packet_index": cols["packet_index"], "motor_speed_rpm": cols["rpm"]}
        rng, refl = cols["range_mm"], cols["reflectivity"]
        if mode in MARKED_MODES:
            extra["second_strongest"] = (rng[1] > 0) & (refl[1] < refl[0])
        frame = Frame(
            sensor=self.sensor_info(mode), frame_id=self._frame_id, range_mm=rng, reflectivity=refl,
            return_labels=self.model.labels(mode), column_valid=cols["valid"].copy(),
            column_timestamp_ns=cols["timestamp_ns"], azimuth_deg=cols["azimuth_cdeg"] / 100.0,
            pixel_time_offset_ns=np.take(self._time_table, cols["time_key"], axis=1), partial=partial, counters=counters,
            extra=extra,
        )
        self._frame_id += 1
        return frame


def _with_lost_columns(cols: dict[str, np.ndarray], lost: np.ndarray, groups: int,
                       before: float | None) -> dict[str, np.ndarray]:
    """``cols`` (the columns of N packets, ``groups`` each) with the columns of the packets lost before each
    (``lost``, ``int64[N]``) put in as invalid columns (:mod:`lidarpkt.core.lost_columns`): no returns, zero
    time, the azimuth (0.01°) interpolated between the received columns around them, the rotation rate of
    the packet after them (``before``: the azimuth of the last column before these, for a loss before the
    first packet; without it that loss is counted, not put in)."""
    lost = lost.copy()
    if before is None:
        lost[0] = 0
    if not lost.any():
        return cols
    places, width = received_places(lost, groups)
    out = {k: spread(v, places, width, -1 if k == "packet_index" else 0) for k, v in cols.items()}
    out["azimuth_cdeg"] = interpolated_azimuth(cols["azimuth_cdeg"], places, width, before)
    out["rpm"] = cols["rpm"][np.searchsorted(places, np.arange(width))]  # each lost column: the next packet's
    return out
