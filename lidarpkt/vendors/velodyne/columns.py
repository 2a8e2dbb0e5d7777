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
    from .models import VelodyneModel


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
        arrays = [getattr(self, k) for k in _FIELDS]
        bounds = [0, *at, len(self)]
        return [Columns(*(a[..., lo:hi] for a in arrays)) for lo, hi in zip(bounds[:-1], bounds[1:])]

    @staticmethod
    def concat(parts: list["Columns"]) -> "Columns":
        if len(parts) == 1:
            return parts[0]
        return Columns(**{k: np.concatenate([getattr(p, k) for p in parts], axis=-1) for k in _FIELDS})


_FIELDS = tuple(Columns.__dataclass_fields__)


def finish_columns(rng: np.ndarray, refl: np.ndarray, az_px: np.ndarray, abs_ns: np.ndarray, index: np.ndarray,
                   miss: np.ndarray, per_packet: int, model: VelodyneModel, lasers: np.ndarray,
                   last_az_cdeg: float | None) -> Columns:
    """Column times, packet ordinals and the columns standing for lost packets (``miss[i]`` before packet
    i), around the pixels of ``n`` packets (``rng``, ``refl``: ``[R, lasers, n · per_packet]``; ``az_px``:
    ``uint16[lasers, n · per_packet]``). ``lasers``: the laser of each row; ``last_az_cdeg``: the
    azimuth of the column before (interpolation anchor of leading lost columns), ``None`` at a start."""
    n = len(abs_ns)
    col_az = az_px[int(np.flatnonzero(lasers == 0)[0])].astype(np.float64)  # laser 0 fires first
    seq = np.rint(model.column_offset_ns + np.arange(per_packet) * float(model.sequence_ns)).astype(np.int64)
    ts = (abs_ns[:, None] + seq[None, :]).reshape(-1)
    pidx = np.repeat(index.astype(np.int64), per_packet)
    total_missing = int(miss.sum())
    if total_missing == 0:
        lost = np.zeros(n * per_packet, np.int32)
        return Columns(rng, refl, az_px, col_az, np.ones(n * per_packet, bool), ts, pidx, lost)
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
