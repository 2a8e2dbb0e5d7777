"""The columns of Velodyne frames: :class:`Columns`, a run of columns of one return mode (the pieces a
frame is concatenated from), and :func:`finish_columns`, which adds their times and packet ordinals and
the invalid columns standing for lost packets (azimuth interpolated, one lost count at the first column
of each lost packet)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

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
        arrays = [getattr(self, k) for k in self.__dataclass_fields__]
        bounds = [0, *at, len(self)]
        return [Columns(*(a[..., lo:hi] for a in arrays)) for lo, hi in zip(bounds[:-1], bounds[1:])]

    @staticmethod
    def concat(parts: list["Columns"]) -> "Columns":
        if len(parts) == 1:
            return parts[0]
        return Columns(**{k: np.concatenate([getattr(p, k) for p in parts], axis=-1) for k in Columns.__dataclass_fields__})


def finish_columns(rng: np.ndarray, refl: np.ndarray, az_px: np.ndarray, abs_ns: np.ndarray, index: np.ndarray,
                   miss: np.ndarray, per_packet: int, model: VelodyneModel, lasers: np.ndarray,
                   last_az_cdeg: float | None) -> Columns:
    """Column times, packet ordinals and the columns standing for lost packets (``miss[i]`` before packet
    i), around the pixels of ``n`` packets (``rng``, ``refl``: ``[R, lasers, n · per_packet]``; ``az_px``:
    ``uint16[lasers, n · per_packet]``). ``lasers``: the laser of each row; ``last_az_cdeg``: the
    azimuth of the column before (interpolation anchor of leading lost columns), ``None`` at a start."""
    n, n_lasers = len(abs_ns), model.lasers
    col_az = az_px[int(np.flatnonzero(lasers == 0)[0])].astype(np.float64)  # laser 0 fires first
    seq = np.rint(model.column_offset_ns + np.arange(per_packet) * float(model.sequence_ns)).astype(np.int64)
    ts = (abs_ns[:, None] + seq[None, :]).reshape(-1)
    pidx = np.repeat(index.astype(np.int64), per_packet)
    total_missing = int(miss.sum())
    if total_missing == 0:
        lost = np.zeros(n * per_packet, np.int32)
        return Columns(rng, refl, az_px, col_az, np.ones(n * per_packet, bool), ts, pidx, lost)
    # scatter the packets' columns among invalid columns standing for the lost packets
    slot = np.arange(n) + np.cumsum(miss)
    w = (n + total_missing) * per_packet
    cols = (slot[:, None] * per_packet + np.arange(per_packet)[None, :]).reshape(-1)
    r_out = np.zeros(rng.shape[:2] + (w,), np.uint32)
    f_out = np.zeros(refl.shape[:2] + (w,), np.uint8)
    a_out = np.zeros((n_lasers, w), np.uint16)
    r_out[..., cols], f_out[..., cols], a_out[:, cols] = rng, refl, az_px
    valid = np.zeros(w, bool)
    valid[cols] = True
    ts_out = np.zeros(w, np.int64)
    ts_out[cols] = ts
    p_out = np.full(w, -1, np.int64)
    p_out[cols] = pidx
    # one count at the first column of each lost packet, so that a frame cut inside a gap
    # counts exactly the packets lost on its side
    lost_slot = np.repeat(slot - miss, miss) + (np.arange(total_missing) - np.repeat(np.cumsum(miss) - miss, miss))
    lost = np.zeros(w, np.int32)
    lost[lost_slot * per_packet] = 1
    # azimuth of lost columns: interpolated along the unwrapped azimuth of the valid ones
    anchor_idx = [] if last_az_cdeg is None else [-1]
    anchor_az = [] if last_az_cdeg is None else [last_az_cdeg]
    known_idx = np.concatenate([anchor_idx, cols]).astype(np.float64)
    known_az = np.concatenate([anchor_az, col_az])
    step = np.diff(known_az) % 36000.0
    unwrapped = known_az[0] + np.concatenate([[0.0], np.cumsum(step)])
    az_all = np.interp(np.arange(w, dtype=np.float64), known_idx, unwrapped) % 36000.0
    az_all[cols] = col_az
    return Columns(r_out, f_out, a_out, az_all, valid, ts_out, p_out, lost)
