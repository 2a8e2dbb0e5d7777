"""Columns standing for lost packets, for the vendors whose frames are cut from their packets' columns
(:mod:`lidarpkt.vendors.velodyne`, :mod:`lidarpkt.vendors.hesai`): where the received packets' columns go
among them, each array spread out to make room, and the azimuth each column standing for a lost one
gets (interpolated along the unwrapped azimuth of the received columns around it)."""

from __future__ import annotations

import numpy as np


def received_places(lost: np.ndarray, per_packet: int) -> tuple[np.ndarray, int]:
    """(``int64[N · per_packet]``, width): where the columns of N received packets go when ``lost[i]``
    packets (``int[N]``, ≥ 0) of ``per_packet`` columns each were lost just before packet i, and the width
    of the columns with theirs put in."""
    lost = np.asarray(lost, np.int64)
    n = lost.shape[0]
    places = np.arange(n * per_packet) + np.repeat(np.cumsum(lost) * per_packet, per_packet)
    return places, (n + int(lost.sum())) * per_packet


def spread(values: np.ndarray, places: np.ndarray, width: int, fill: int | bool = 0) -> np.ndarray:
    """``values`` (``[..., N]``) at ``places`` of its last axis, widened to ``width``; ``fill`` elsewhere."""
    out = np.full(values.shape[:-1] + (width,), fill, values.dtype)
    out[..., places] = values
    return out


def interpolated_azimuth(azimuth_cdeg: np.ndarray, places: np.ndarray, width: int,
                         before_cdeg: float | None = None) -> np.ndarray:
    """``float64[width]`` azimuths (0.01°): the received columns' ``azimuth_cdeg`` at ``places``, every other
    column interpolated along their unwrapped azimuth, the anchor ``before_cdeg`` (the column before
    these, ``None``: none) standing at place −1; modulo a turn."""
    col_az = np.asarray(azimuth_cdeg, np.float64)
    anchor_idx = [] if before_cdeg is None else [-1]
    anchor_az = [] if before_cdeg is None else [before_cdeg]
    known_idx = np.concatenate([anchor_idx, places]).astype(np.float64)
    known_az = np.concatenate([anchor_az, col_az])
    step = np.diff(known_az) % 36000.0
    unwrapped = known_az[0] + np.concatenate([[0.0], np.cumsum(step)])
    az_all = np.interp(np.arange(width, dtype=np.float64), known_idx, unwrapped) % 36000.0
    az_all[places] = col_az
    return az_all
