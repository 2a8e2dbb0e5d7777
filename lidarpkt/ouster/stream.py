"""An Ouster lidar stream's packets counted: what a payload size is, how many packets a gap lost,
where a frame ends. The recorder's live path (:mod:`lidarpkt.streams`) uses :class:`PacketCounter`;
:class:`~lidarpkt.ouster.OusterDecoder` ends a frame at the same place (a change of frame id) and
places packets by the same measurement ids.

The (frame id, measurement id) of each packet's first column gives its place in the stream; a jump
of k packets means k − 1 lost. A step back (or a repeat) is out of order, never loss; a jump of more
than :data:`~lidarpkt.decoder.INTERRUPTION_S` of frames is an interruption, counted on its own.
"""

from __future__ import annotations

import numpy as np

from ..decoder import INTERRUPTION_S, StreamCounts
from .metadata import OusterMetadata
from .profiles import IMU_PACKET_SIZE, LEGACY, read_bits

# LEGACY lidar packets of 16, 32, 64, 128 beams: recognisable without metadata
LEGACY_SIZES = frozenset(LEGACY.packet_size(h) for h in (16, 32, 64, 128))


def stream_kind(payload_size: int, metadata: OusterMetadata | None = None) -> str | None:
    """``"lidar"`` or ``"imu"`` by payload size alone (the live path's cheap test; :func:`classify`
    also checks the content), ``None`` for another size. ``metadata`` makes the non-legacy profiles
    recognisable; without it only the LEGACY sizes of 16 to 128 beams are."""
    if metadata is not None and payload_size == metadata.packet_size:
        return "lidar"
    if payload_size == IMU_PACKET_SIZE or (metadata is not None and payload_size == metadata.imu_packet_size):
        return "imu"
    if metadata is None and payload_size in LEGACY_SIZES:
        return "lidar"
    return None


class PacketCounter:
    """Loss and frame counting of one Ouster lidar stream, from its metadata (batches in arrival order)."""

    def __init__(self, metadata: OusterMetadata) -> None:
        self.md = metadata
        self.count = StreamCounts()
        prof = metadata.profile
        self._dtype = prof.packet_dtype(metadata.pixels_per_column, metadata.columns_per_packet)
        self._frame_field = None if prof.legacy else next(f for f in prof.header_fields if f.name == "frame_id")
        first, last = metadata.column_window
        w = metadata.columns_per_frame
        self._first = first
        self._per_frame = -(-(((last - first) % w) + 1) // metadata.columns_per_packet)
        self._frame_modulus = 1 << (16 if self._frame_field is None else self._frame_field.width)
        self._last: tuple[int, int] | None = None  # (unwrapped frame id, packet index in frame)

    def update(self, payload: np.ndarray) -> np.ndarray:
        """Count ``uint8[N, L]`` lidar payloads; returns ``bool[N]``, True where the frame id changes."""
        n = payload.shape[0]
        self.count.packets += n
        if n == 0:
            return np.zeros(0, bool)
        pk = np.ascontiguousarray(payload).view(self._dtype)[:, 0]
        first_col = pk["columns"][:, 0]
        mid = first_col["measurement_id"].astype(np.int64)
        if self._frame_field is None:
            fid = first_col["frame_id"].astype(np.int64)
        else:
            fid = read_bits(pk["header"], self._frame_field).astype(np.int64)
        idx = ((mid - self._first) % self.md.columns_per_frame) // self.md.columns_per_packet
        m = self._frame_modulus
        prev_fid = np.concatenate([[fid[0] if self._last is None else self._last[0] % m], fid[:-1]])
        dfid = (fid - prev_fid) % m
        dfid = np.where(dfid > m // 2, dfid - m, dfid)
        base = fid[0] if self._last is None else self._last[0]
        fid_unwrapped = base + np.cumsum(dfid)
        pos = fid_unwrapped * self._per_frame + idx
        prev_pos = np.concatenate([[pos[0] - 1 if self._last is None else
                                    self._last[0] * self._per_frame + self._last[1]], pos[:-1]])
        steps = pos - prev_pos
        # frames per second: 10 or 20 (lidar_mode); unknown → 10
        limit = INTERRUPTION_S * (self.md.frequency_hz or 10) * self._per_frame
        jump = np.abs(steps) > limit
        self.count.interruptions += int(np.count_nonzero(jump))
        steps[jump] = 1
        self.count.lost += int(np.clip(steps - 1, 0, None).sum())
        self.count.out_of_order += int(np.count_nonzero(steps <= 0))
        new_frame = dfid > 0
        self.count.frames += int(np.count_nonzero(new_frame))
        self._last = (int(fid_unwrapped[-1]), int(idx[-1]))
        return new_frame
