"""A VLP-16 stream's packets counted: what a payload size is, how many packets a gap lost, where a
rotation ends. The decoder (:mod:`lidarpkt.vendors.velodyne.frames`) and the recorder's live path
(:class:`PacketCounter`, the registry record's ``counter``) both use these rules, so that they cannot
disagree about packet periods and rotations.

* Packet period: the model table's (:meth:`VelodyneModel.packet_period_us`: 1327.104 µs in the
  single-return modes, 663.552 µs in dual). A gap of k periods between consecutive packets means
  k − 1 packets lost (:func:`packets_lost`), whatever the rotation rate and the replay speed.
* Rotation: a rotation ends where the azimuth (minus the cut angle) drops by more than half a turn
  (:func:`wrapped`): the decoder asks it of every firing sequence, the live path of every block, so
  both count the same wraps (a wrap inside the last packet of a capture too). A frame that does
  not begin or end at a wrap is whole when it reaches the cut within one firing interval
  (:func:`rotation_is_whole`).
* A step back (or a repeat) is out of order, never loss; a step the capture time cannot explain
  is a corrupted packet or a restart (:mod:`lidarpkt.core.continuity`), counted on its own, and losses
  are never more than the capture time can hold.
"""

from __future__ import annotations

import numpy as np

from lidarpkt.core.continuity import StreamContinuity
from lidarpkt.core.decoder import StreamCounts
from lidarpkt.core.rotation import wrapped
from .clock import HOUR_US
from .models import VLP16
from .packet import DATA_PACKET_SIZE, POSITION_PACKET_SIZE, RETURN_MODE_CODES, as_data_packets



def stream_kind(payload_size: int) -> str | None:
    """``"data"`` or ``"position"`` by payload size alone (the live path's cheap test; :func:`classify`
    also checks the content), ``None`` for another size."""
    return {DATA_PACKET_SIZE: "data", POSITION_PACKET_SIZE: "position"}.get(payload_size)


def packets_lost(step: np.ndarray, period: float) -> np.ndarray:
    """``int64``: packets lost in a step between consecutive packets (same unit as ``period``): the
    number of whole periods it spans, minus one; 0 for a step back or a repeat."""
    return np.maximum(np.rint(np.asarray(step) / period).astype(np.int64) - 1, 0)


class PacketCounter:
    """Loss and rotation counting of one VLP-16 data stream from its payloads (feed batches in arrival order).

    ``single_period_us`` is the packet period in single-return modes (half of it in dual mode): the
    VLP-16's by default, the HDL-32E's for that sensor; ``None`` for a model whose timing is not
    known here (then packets and rotations are counted, gaps are not).
    """

    def __init__(self, single_period_us: float | None = VLP16.packet_period_us("strongest")) -> None:
        self.single_period_us = single_period_us
        self.count = StreamCounts()
        self.continuity = StreamContinuity(1000, HOUR_US)  # places: µs past the hour
        self._last_az: int | None = None  # first block of the last packet
        self._last_block_az: int | None = None  # last block of the last packet

    def update(self, payload: np.ndarray, host_ns: np.ndarray | None = None) -> np.ndarray:
        """Count ``uint8[N, 1206]`` payloads captured at ``host_ns`` (``int64[N]`` ns, 0 or ``None``:
        unknown); returns ``bool[N]``, True where a packet is the first of a new rotation (its first
        block's azimuth wrapped from the previous packet's). ``count.frames`` counts the rotations
        completed: the wraps between any two consecutive blocks. Corrupted packets (see
        :mod:`lidarpkt.core.continuity`) are counted and take no part in losses or rotations.

        Raises :class:`~lidarpkt.errors.PacketFormatError` for payloads of another size.
        """
        p = as_data_packets(payload)
        n = len(p)
        self.count.packets += n
        if n == 0:
            return np.zeros(0, bool)
        host = np.zeros(n, np.int64) if host_ns is None else np.asarray(host_ns, np.int64)
        st = self.continuity.check(p["timestamp_us"].astype(np.int64), host)
        self.count.corrupted += st.corrupted
        self.count.interruptions += st.restarts
        new_rotation = np.zeros(n, bool)
        keep = st.keep
        if not keep.all():
            p, st_steps = p[keep], st.step_ticks[keep]
        else:
            st_steps = st.step_ticks
        if len(p) == 0:
            return new_rotation
        blocks_az = p["blocks"]["azimuth_cdeg"].astype(np.int64)
        az = blocks_az[:, 0]
        if self.single_period_us is not None:
            period_us = np.where(p["return_mode"] == RETURN_MODE_CODES["dual"], self.single_period_us / 2,
                                 self.single_period_us)
            steps = np.rint(st_steps / period_us).astype(np.int64)
            steps[st.begins[keep]] = 1  # a restart, and the first packet of a stream, lose nothing
            lost = np.zeros(n, np.int64)
            lost[keep] = packets_lost(steps, 1)
            period_ns = np.full(n, self.single_period_us * 1000.0)
            period_ns[keep] = period_us * 1000.0
            self.count.lost += int(self.continuity.bound_lost(lost, st.host_step_ns, st.host_known, period_ns).sum())
            self.count.out_of_order += int(np.count_nonzero(steps <= 0))
        new_rotation[keep] = wrapped(az, self._last_az)
        self.count.frames += int(np.count_nonzero(wrapped(blocks_az.ravel(), self._last_block_az)))
        self._last_az, self._last_block_az = int(az[-1]), int(blocks_az[-1, -1])
        return new_rotation
