"""An Ouster lidar stream's packets counted: how many packets a gap lost, where a frame ends. The
recorder's live path uses :class:`PacketCounter` (the registry record's ``counter``);
:class:`~lidarpkt.vendors.ouster.OusterDecoder` ends a frame at the same place (a change of frame id) and
places packets by the same measurement ids.

The (frame id, measurement id) of each packet's first column gives its place in the stream; a jump
of k packets means k − 1 lost. A step back (or a repeat) is out of order, never loss; a step the
capture time cannot explain is a corrupted packet or a restart (:mod:`lidarpkt.core.continuity`), counted
on its own, and losses are never more than the capture time can hold.
"""

from __future__ import annotations

import numpy as np

from lidarpkt.core.continuity import StreamContinuity
from lidarpkt.core.decoder import StreamCounts
from .metadata import OusterMetadata
from .bitfield import read_bits

def window_packets(metadata: OusterMetadata) -> int:
    """Packets per frame in the metadata's column window (all of the frame's without a window)."""
    first, last = metadata.column_window
    w = metadata.columns_per_frame
    return -(-(((last - first) % w) + 1) // metadata.columns_per_packet)


def packet_period_ns(metadata: OusterMetadata) -> float:
    """The time one packet of the window stands for: a frame's time over its window packets (10 or
    20 frames per second by lidar_mode; 10 when unknown)."""
    return 1e9 / ((metadata.frequency_hz or 10) * window_packets(metadata))


def frame_id_modulus(metadata: OusterMetadata) -> int:
    """Where the frame id wraps: its header field's width (16 bits for LEGACY, in the column header)."""
    prof = metadata.profile
    if prof.legacy:
        return 1 << 16
    return 1 << next(f for f in prof.header_fields if f.name == "frame_id").width


def packet_places(frame_id: np.ndarray, first_measurement_id: np.ndarray, metadata: OusterMetadata) -> np.ndarray:
    """``int64[N]``: each packet's place in the stream, in window packets: frame id × packets per frame
    + the packet's index in the window (from its first column's measurement id)."""
    first = metadata.column_window[0]
    idx = ((np.asarray(first_measurement_id, np.int64) - first) % metadata.columns_per_frame) // metadata.columns_per_packet
    return np.asarray(frame_id, np.int64) * window_packets(metadata) + idx


def stream_continuity(metadata: OusterMetadata) -> StreamContinuity:
    """The :class:`~lidarpkt.core.continuity.StreamContinuity` of a stream of :func:`packet_places`."""
    return StreamContinuity(packet_period_ns(metadata), frame_id_modulus(metadata) * window_packets(metadata))


class PacketCounter:
    """Loss and frame counting of one Ouster lidar stream, from its metadata (batches in arrival order)."""

    def __init__(self, metadata: OusterMetadata) -> None:
        self.md = metadata
        self.count = StreamCounts()
        prof = metadata.profile
        self._dtype = prof.packet_dtype(metadata.pixels_per_column, metadata.columns_per_packet)
        self._frame_field = None if prof.legacy else next(f for f in prof.header_fields if f.name == "frame_id")
        self._frame_modulus = frame_id_modulus(metadata)
        self._period_ns = packet_period_ns(metadata)
        self.continuity = stream_continuity(metadata)
        self._last_fid: int | None = None

    def update(self, payload: np.ndarray, host_ns: np.ndarray | None = None) -> np.ndarray:
        """Count ``uint8[N, L]`` lidar payloads captured at ``host_ns`` (``int64[N]`` ns, 0 or ``None``:
        unknown); returns ``bool[N]``, True where the frame id changes. Corrupted packets (see
        :mod:`lidarpkt.core.continuity`) are counted and take no part in losses or frames."""
        n = payload.shape[0]
        self.count.packets += n
        new_frame = np.zeros(n, bool)
        if n == 0:
            return new_frame
        fid, mid = self._ids(payload)
        host = np.zeros(n, np.int64) if host_ns is None else np.asarray(host_ns, np.int64)
        st = self.continuity.check(packet_places(fid, mid, self.md), host)
        self.count.corrupted += st.corrupted
        self.count.interruptions += st.restarts
        keep = st.keep
        steps = st.step_ticks.copy()
        steps[st.begins] = 1
        lost = np.where(keep, np.clip(steps - 1, 0, None), 0)
        self.count.lost += int(self.continuity.bound_lost(lost, st.host_step_ns, st.host_known, self._period_ns).sum())
        self.count.out_of_order += int(np.count_nonzero(keep & (steps <= 0)))
        kept = np.flatnonzero(keep)
        if kept.size:
            kfid = fid[kept]
            prev = np.concatenate([[kfid[0] if self._last_fid is None else self._last_fid], kfid[:-1]])
            dfid = (kfid - prev) % self._frame_modulus
            new_frame[kept] = (dfid != 0) & (dfid < self._frame_modulus // 2)
            self.count.frames += int(np.count_nonzero(new_frame))
            self._last_fid = int(kfid[-1])
        return new_frame

    def _ids(self, payload: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``int64[N]`` frame ids and first columns' measurement ids."""
        pk = np.ascontiguousarray(payload).view(self._dtype)[:, 0]
        first_col = pk["columns"][:, 0]
        mid = first_col["measurement_id"].astype(np.int64)
        if self._frame_field is None:
            fid = first_col["frame_id"].astype(np.int64)
        else:
            fid = read_bits(pk["header"], self._frame_field).astype(np.int64)
        return fid, mid
