"""A Pandar stream's packets counted, for the recorder's live path (a :class:`lidarpkt.core.decoder.StreamCounter`).

The rules are the decoder's (:mod:`lidarpkt.vendors.hesai.frames`): a packet is lost where the UDP sequence
number skips (models whose protocol has one), else where the packet time advances by more than one
packet period (the median step); a step back or a repeat is out of order, never loss; a jump of more
than :data:`~lidarpkt.core.continuity.INTERRUPTION_S` is an interruption; a rotation ends where the first
block's azimuth wraps.
"""

from __future__ import annotations

import numpy as np

from lidarpkt.core.continuity import INTERRUPTION_S
from lidarpkt.core.decoder import StreamCounts
from lidarpkt.errors import PacketFormatError
from lidarpkt.core.median import median
from lidarpkt.core.rotation import wrapped
from .decode import decode_packets
from .detect import detect_model
from .models import HesaiModel


class PacketCounter:
    """Loss and rotation counting of one Pandar data stream (feed batches in arrival order).

    ``model``: the sensor's row, or ``None`` to detect it from the first payloads.
    """

    def __init__(self, model: HesaiModel | None = None) -> None:
        self.model = model
        self.count = StreamCounts()
        self._last_seq: int | None = None
        self._last_ts: int | None = None
        self._last_az: int | None = None
        self._period_ns: float | None = None

    def update(self, payload: np.ndarray, host_ns: np.ndarray | None = None) -> np.ndarray:
        """Count ``uint8[N, L]`` payloads; returns ``bool[N]``, True where a packet starts a new rotation.
        ``host_ns`` (the :class:`~lidarpkt.core.decoder.StreamCounter` protocol's capture times) is not used yet:
        losses are not bounded by capture time here as the Pandar decoder bounds them.

        Raises :class:`~lidarpkt.errors.PacketFormatError` for payloads of no Pandar model."""
        n = len(payload)
        self.count.packets += n
        if n == 0:
            return np.zeros(0, bool)
        if self.model is None:
            self.model = detect_model(payload)
            if self.model is None:
                raise PacketFormatError(f"{payload.shape[1]}-byte payloads of no Pandar model lidarpkt knows")
        raw = decode_packets(payload, self.model)
        ts = raw.timestamp_ns
        dt = np.diff(ts, prepend=ts[0] if self._last_ts is None else self._last_ts)
        jump = np.abs(dt) > INTERRUPTION_S * 1e9
        self.count.interruptions += int(np.count_nonzero(jump))
        if raw.udp_sequence is not None:
            seq = raw.udp_sequence.astype(np.int64)
            step = np.diff(seq, prepend=seq[0] - 1 if self._last_seq is None else self._last_seq)
            self._last_seq = int(seq[-1])
        else:
            positive = dt[(dt > 0) & ~jump]
            if positive.size:
                self._period_ns = median(positive)
            period = self._period_ns or 1.0
            step = np.rint(dt / period).astype(np.int64)
            if self._last_ts is None:
                step[0] = 1
        step = np.where(jump, 1, step)
        if self._period_ns is not None or raw.udp_sequence is not None:
            self.count.lost += int(np.maximum(step - 1, 0).sum())
        self.count.out_of_order += int(np.count_nonzero(step <= 0))
        az = raw.azimuth_cdeg[:, 0].astype(np.int64)
        new_rotation = wrapped(az, self._last_az)
        self.count.frames += int(np.count_nonzero(new_rotation))
        self._last_ts, self._last_az = int(ts[-1]), int(az[-1])
        return new_rotation
