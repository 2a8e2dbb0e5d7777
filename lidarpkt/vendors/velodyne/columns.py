"""The columns of Velodyne frames: :class:`Columns`, a run of columns of one return mode (the pieces a
frame is concatenated from), and :func:`finish_columns`, which adds their times and packet ordinals and
the invalid columns standing for lost packets (azimuth interpolated, one lost count at the first column
of each lost packet)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from lidarpkt.core.lost_columns import interpolated_azimuth, received_places, spread

if TYPE_CHECKING:
    from .decode import Empty
    from .models import VelodyneModel

#: columns made at a time (a piece; ``VelodyneDecoder._push_run``): 1024 VLP-16 packets, more where a packet has
#: fewer, so that frames seldom straddle two pieces (a frame within one holds views of its arrays)
PIECE_COLUMNS = 24_576
#: the buffers of pieces no frame refers to any more, kept for the next pieces (``BufferPool``; a VLP-16 piece
#: takes 3.5 MB, a VLS-128 one 22 MB)
POOL_BYTES = 64 << 20


@dataclass
class Columns:
    """A run of columns of one return mode (the pieces a frame is concatenated from)."""

    range_mm: np.ndarray  # uint32 [R, 16, w]
    reflectivity: np.ndarray  # uint8 [R, 16, w]
    azimuth_px: np.ndarray  # uint16 [16, w]
    azimuth_cdeg: np.ndarray  # float64 [w]
    valid: np.ndarray  # bool [w]
    timestamp_ns: np.ndarray  # int64 [w]
    packet_index: np.ndarray  # int64 [w]
    lost: np.ndarray  # int32 [w]: packets lost just before this column

    def __len__(self) -> int:
        return int(self.valid.shape[0])

    def split(self, at: list[int]) -> list["Columns"]:
        """The runs of columns between the cuts ``at`` (ascending column indices): views, as ``np.split``'s."""
        arrays = [getattr(self, k) for k in self.__dataclass_fields__]
        bounds = [0, *at, len(self)]
        return [Columns(*(a[..., lo:hi] for a in arrays)) for lo, hi in zip(bounds[:-1], bounds[1:])]

    @staticmethod
    def concat(parts: list["Columns"], empty: Empty = np.empty) -> "Columns":
        """The runs one after the other (the one run itself when there is one; else new arrays from ``empty``)."""
        if len(parts) == 1:
            return parts[0]
        joined = {}
        for k in Columns.__dataclass_fields__:
            arrays = [getattr(p, k) for p in parts]
            first = arrays[0]
            out = empty((*first.shape[:-1], sum(a.shape[-1] for a in arrays)), first.dtype)
            joined[k] = np.concatenate(arrays, axis=-1, out=out)
        return Columns(**joined)


def finish_columns(rng: np.ndarray, refl: np.ndarray, az_px: np.ndarray, abs_ns: np.ndarray, index: np.ndarray,
                   miss: np.ndarray, per_packet: int, model: VelodyneModel, lasers: np.ndarray,
                   last_az_cdeg: float | None, empty: Empty = np.empty) -> Columns:
    """Column times, packet ordinals and the columns standing for lost packets (``miss[i]`` before packet
    i), around the pixels of ``n`` packets (``rng``, ``refl``: ``[R, lasers, n · per_packet]``; ``az_px``:
    ``uint16[lasers, n · per_packet]``). ``lasers``: the laser of each row; ``last_az_cdeg``: the
    azimuth of the column before (interpolation anchor of leading lost columns), ``None`` at a start.
    ``empty`` makes the arrays of a run without lost packets (``numpy.empty``, or a decoder's
    :meth:`~lidarpkt.core.buffers.BufferPool.empty`)."""
    n = len(abs_ns)
    w = n * per_packet
    col_az = empty(w, np.float64)
    np.copyto(col_az, az_px[int(np.flatnonzero(lasers == 0)[0])])  # laser 0 fires first
    seq = np.rint(model.column_offset_ns + np.arange(per_packet) * float(model.sequence_ns)).astype(np.int64)
    ts = np.add(abs_ns[:, None], seq[None, :], out=empty((n, per_packet), np.int64)).reshape(-1)
    pidx = empty((n, per_packet), np.int64)
    pidx[...] = index[:, None]
    pidx = pidx.reshape(-1)
    total_missing = int(miss.sum())
    if total_missing == 0:
        lost = empty(w, np.int32)
        lost.fill(0)
        valid = empty(w, np.bool_)
        valid.fill(True)
        return Columns(rng, refl, az_px, col_az, valid, ts, pidx, lost)
    # the packets' columns among invalid columns standing for the lost packets
    cols, w = received_places(miss, per_packet)
    slot = np.arange(n) + np.cumsum(miss)
    # one count at the first column of each lost packet, so that a frame cut inside a gap
    # counts exactly the packets lost on its side
    lost_slot = np.repeat(slot - miss, miss) + (np.arange(total_missing) - np.repeat(np.cumsum(miss) - miss, miss))
    lost = np.zeros(w, np.int32)
    lost[lost_slot * per_packet] = 1
    return Columns(spread(rng, cols, w), spread(refl, cols, w), spread(az_px, cols, w),
                   interpolated_azimuth(col_az, cols, w, last_az_cdeg), spread(np.ones(n * per_packet, bool), cols, w),
                   spread(ts, cols, w), spread(pidx, cols, w, -1), lost)
