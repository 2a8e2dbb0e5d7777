"""A RoboSense stream's place, losses and rotations: the rules of the decoder
(:class:`StreamLoss`, its counts :class:`DecoderStats`) and the recorder's live counter
(:class:`PacketCounter`, a :class:`lidarpkt.core.decoder.StreamCounter`).

A packet's place is its timestamp (µs): a jump the capture time cannot explain is a corrupted packet
or a restart (:mod:`lidarpkt.core.continuity`), never packets lost. Losses come from the header's
packet counter (RS-Helios family: ``bottom_board_packet_count``; RS-Bpearl: ``packet_count``) where it
agrees with the time step, else from the time step in packet periods (:func:`packet_period_ns`); a
step back or a repeat is out of order, never a loss; losses never exceed what the capture time can
hold. A rotation ends where a block's azimuth wraps.
"""

from __future__ import annotations

import numpy as np

from lidarpkt.core.continuity import StreamContinuity, Steps
from lidarpkt.core.decoder import StreamCounts
from lidarpkt.core.rotation import wrapped
from lidarpkt.errors import PacketFormatError
from . import packet as P
from .decode import RobosensePackets, decode_packets
from .detect import detect_model, is_difop
from .models import RobosenseModel

def packet_period_ns(model: RobosenseModel, n_returns: np.ndarray | int) -> np.ndarray:
    """``float64[...]``: time a packet spans in a mode of ``n_returns`` returns per firing."""
    single = float(model.blocks * model.block_period_ns)
    dual: float
    if model.dual_layout == "in_block":
        dual = float(model.blocks * model.dual_block_period_ns)
    else:  # block pairs, or RS-Ruby's one return a block
        dual = model.blocks * model.block_period_ns / 2
    return np.where(np.asarray(n_returns) == 2, float(dual), float(single))


class DecoderStats:
    """What a :class:`RobosenseDecoder` saw, counted (attributes are counts of packets unless named)."""

    def __init__(self) -> None:
        self.packets = 0  # MSOP packets pushed
        self.decoded_packets = 0
        self.difop_packets = 0
        self.malformed_size = 0  # batches of a size (or content) no RoboSense model sends
        self.malformed_fields = 0  # header id, block flags, azimuth, unit, ret_id or time impossible
        self.difop_malformed = 0  # DIFOPs refused (identifier, tail, return mode or angles impossible)
        self.duplicate_packets = 0
        self.out_of_order_packets = 0
        self.late_packets = 0
        self.lost_packets = 0
        self.corrupted_packets = 0
        self.restarts = 0
        self.long_gaps = 0  # frames cut by a stretch without packets
        self.overlong_frames = 0
        self.mode_changes = 0
        self.frames = 0

    @property
    def malformed(self) -> int:
        """Packets skipped as malformed (MSOP and DIFOP)."""
        return self.malformed_size + self.malformed_fields + self.difop_malformed

    def drops(self) -> dict[str, int]:
        """Packets dropped, by the reasons of :data:`lidarpkt.core.dropped.REASONS`."""
        return {"lost": self.lost_packets, "late": self.late_packets, "duplicate": self.duplicate_packets,
                "malformed": self.malformed, "corrupted": self.corrupted_packets}

    def __repr__(self) -> str:
        return f"DecoderStats({', '.join(f'{k}={v}' for k, v in vars(self).items())})"


class StreamLoss:
    """The place of one stream's packets, batch after batch: corrupted packets, restarts, losses."""

    def __init__(self, model: RobosenseModel) -> None:
        self.model = model
        self.continuity = StreamContinuity(1000)  # places: the packet timestamp in µs
        self._last: tuple[int, int, int] | None = None  # (timestamp ns, counter, host ns) of the last packet counted

    def check_arrival(self, raw: RobosensePackets, host_ns: np.ndarray) -> Steps:
        """Judge packets in arrival order (:meth:`StreamContinuity.check`); a restart forgets the place."""
        st = self.continuity.check(raw.timestamp_ns // 1000, np.asarray(host_ns, np.int64))
        if st.restarts:
            self._last = None
        return st

    def lost(self, raw: RobosensePackets, host_ns: np.ndarray, n_returns: np.ndarray, begins: np.ndarray) -> np.ndarray:
        """``int64[N]`` packets lost before each of ``raw`` (time order, no duplicates); ``begins``: packets
        after which nothing counts as lost (a restart, the stream's first)."""
        ts = raw.timestamp_ns
        host = np.asarray(host_ns, np.int64)
        counter = raw.packet_count
        last = self._last
        prev_ts = np.concatenate([[ts[0] if last is None else last[0]], ts[:-1]])
        prev_host = np.concatenate([[0 if last is None else last[2]], host[:-1]])
        period = packet_period_ns(self.model, n_returns)
        by_time = np.maximum(np.rint((ts - prev_ts) / period).astype(np.int64) - 1, 0)
        lost = by_time
        if counter is not None:
            prev_c = np.concatenate([[counter[0] - 1 if last is None else last[1]], counter[:-1]])
            step = (counter - prev_c) % (1 << 32)
            # the counter where it agrees with the time step (a damaged counter does not count)
            lost = np.where((step >= 1) & (step - 1 <= by_time + 1), step - 1, by_time)
        lost = np.where(begins, 0, lost)
        if last is None:
            lost[0] = 0
        known = (host != 0) & (prev_host != 0)
        lost = self.continuity.bound_lost(lost, np.where(known, host - prev_host, 0), known, period)
        self._last = (int(ts[-1]), int(counter[-1]) if counter is not None else 0, int(host[-1]))
        return lost


class PacketCounter:
    """Loss and rotation counting of one RoboSense MSOP stream (feed batches in arrival order); DIFOP
    packets in a batch are passed over.

    ``model``: the sensor's row, or ``None`` to detect it from the first payloads.
    """

    def __init__(self, model: RobosenseModel | None = None) -> None:
        self.model = model
        self.count = StreamCounts()
        self._loss: StreamLoss | None = None
        self._last_az: int | None = None

    def update(self, payload: np.ndarray, host_ns: np.ndarray | None = None) -> np.ndarray:
        """Count ``uint8[N, 1248]`` payloads captured at ``host_ns`` (``int64[N]`` ns; ``None`` or 0:
        unknown); returns ``bool[N]``, True where a packet's first block starts a new rotation.

        Raises :class:`~lidarpkt.errors.PacketFormatError` for payloads of no RoboSense model."""
        n = len(payload)
        new_rotation = np.zeros(n, bool)
        if n == 0:
            return new_rotation
        if payload.ndim != 2 or payload.shape[1] != P.PACKET_SIZE:
            raise PacketFormatError(f"{payload.shape[-1]}-byte payloads are no RoboSense packets (1248 B)")
        msop = ~is_difop(payload)
        self.count.packets += int(np.count_nonzero(msop))
        if self.model is None:
            self.model = detect_model(payload[msop])
            if self.model is None:
                raise PacketFormatError("1248-byte payloads of no RoboSense model lidarpkt knows")
        if self._loss is None:
            self._loss = StreamLoss(self.model)
        raw = decode_packets(payload, self.model)
        good = msop & raw.valid
        self.count.corrupted += int(np.count_nonzero(msop & ~raw.valid))
        host = np.zeros(n, np.int64) if host_ns is None else np.asarray(host_ns, np.int64)
        idx = np.flatnonzero(good)
        if idx.size == 0:
            return new_rotation
        raw, host = raw.select(idx), host[idx]
        st = self._loss.check_arrival(raw, host)
        self.count.corrupted += st.corrupted
        self.count.interruptions += st.restarts
        keep = st.keep
        raw, host, idx, begins = raw.select(keep), host[keep], idx[keep], st.begins[keep]
        if len(raw) == 0:
            return new_rotation
        back = np.diff(raw.timestamp_ns) <= 0
        self.count.out_of_order += int(np.count_nonzero(back))
        forward = np.concatenate([[True], ~back])
        az = raw.azimuth_cdeg
        returns = np.where(np.all(az[:, 0::2] == az[:, 1::2], axis=1) & (az.shape[1] > 1), 2, 1) \
            if self.model.dual_layout == "block_pairs" else np.ones(len(raw), np.int64)
        if raw.wave_mode is not None:
            returns = np.where(raw.wave_mode == 3, 2, 1)
        sel = np.flatnonzero(forward)
        self.count.lost += int(self._loss.lost(raw.select(sel), host[sel], returns[sel], begins[sel]).sum())
        first = az[:, 0].astype(np.int64)
        new_rotation[idx] = wrapped(first, self._last_az)
        self.count.frames += int(np.count_nonzero(new_rotation))
        self._last_az = int(first[-1])
        return new_rotation


def stream_kind(payload_size: int) -> str | None:
    """``"msop"`` for the payload size RoboSense sensors send (the recorder's cheap test; DIFOPs share it
    and are told apart by content), else ``None``."""
    return "msop" if payload_size == P.PACKET_SIZE else None
