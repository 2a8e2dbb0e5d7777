"""The column grid of frames: where a firing falls on a fixed azimuth grid (:meth:`Frame.on_grid
<lidarpkt.core.frame.Frame.on_grid>`), the default grid of a sensor, and (de)staggering of images."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .sensor import SensorInfo


_SMOOTH_FIRINGS = 15  # firings averaged to tell the sensor's turn from its encoder's jitter


def _grid_positions(azimuth_deg: np.ndarray, timestamp_ns: np.ndarray, res: float) -> np.ndarray:
    """Position of each firing on a grid of ``res`` degrees (in bins), from its azimuths against time
    smoothed over a few firings rather than from each measured azimuth: the sensor turns steadily,
    but its encoder readings jitter (a VLP-16 at 19.98 Hz fires every 0.3996°, read as 0.39, 0.40 and
    0.41°), and on a grid as fine as the firings that jitter puts two firings in one bin beside an
    empty one, a column marked invalid though no packet was lost. A firing whose measured azimuth is
    more than half a bin from the line (the rate changed) keeps its measured azimuth."""
    measured = np.mod(azimuth_deg, 360.0)
    if measured.size < 8:
        return measured / res + 1e-9
    steps = measured / res
    if np.all(np.abs(steps - np.rint(steps)) < 1e-6):
        # a sensor that reports its firings on the grid itself (Hesai XT and QT: 0.18° and 0.4° steps): each
        # firing is its bin; a line fitted through their times (µs jitter) would only move some across an edge
        return np.rint(steps) + 1e-9
    turns = np.concatenate([[0], np.cumsum(np.diff(measured) < -180.0)])  # unwrap through 0°
    unwrapped = measured + 360.0 * turns
    t = (timestamp_ns - timestamp_ns[0]).astype(np.float64)
    if not np.all(np.diff(t) >= 0) or t[-1] <= 0:
        return measured / res + 1e-9
    # least-squares line azimuth = a + b·t, in closed form (np.polyfit costs ~0.2 ms a frame)
    t_mean, az_mean = t.mean(), unwrapped.mean()
    dt = t - t_mean
    slope = float(dt @ (unwrapped - az_mean)) / float(dt @ dt)
    line = az_mean + slope * dt
    # the slow wander of the rate about the line (up to ~0.06° a rotation) is kept, the jitter averaged out:
    # a running mean of the residual over _SMOOTH_FIRINGS firings (fewer at the ends)
    residual = unwrapped - line
    half = _SMOOTH_FIRINGS // 2
    csum = np.concatenate([[0.0], np.cumsum(residual)])
    idx = np.arange(residual.size)
    lo, hi = np.maximum(idx - half, 0), np.minimum(idx + half + 1, residual.size)
    fitted = line + (csum[hi] - csum[lo]) / (hi - lo)
    steady = np.abs(fitted - unwrapped) < 0.5 * res
    # the epsilon keeps an azimuth on a bin edge (187.6° / 0.4 = 468.99999...) in its bin
    return np.mod(np.where(steady, fitted, unwrapped), 360.0) / res + 1e-9


def _grid_bins(pos: np.ndarray, n_bins: int, tolerance: float = 0.1) -> np.ndarray:
    """Bins of firings at ``pos`` (in bins, firing order): floor, except that where two consecutive
    firings share a bin beside an empty one, the one within ``tolerance`` of the empty bin's edge
    moves into it (what smoothing leaves of the jitter). Vectorised: one pass each way."""
    bins = np.floor(pos).astype(np.int64) % n_bins
    frac = pos - np.floor(pos)
    for step in (1, -1):
        occupied = np.zeros(n_bins, bool)
        occupied[bins] = True
        pairs = np.flatnonzero(bins[1:] == bins[:-1])
        mover = pairs + 1 if step == 1 else pairs  # the later firing moves up, the earlier down
        near = frac[mover] > 1.0 - tolerance if step == 1 else frac[mover] < tolerance
        target = (bins[mover] + step) % n_bins
        ok = near & ~occupied[target]
        _, once = np.unique(target[ok], return_index=True)  # one firing per empty bin
        bins[mover[ok][once]] = target[ok][once]
    return bins


def default_grid_deg(sensor: SensorInfo) -> float | None:
    """The azimuth grid (degrees per column) frames of ``sensor`` are put on by default, from its firing rate.

    The sensor's ``grid_resolution_deg``, coarsened where a rotation holds fewer firings than that grid
    has columns (``columns_per_frame``), so that each column still holds a firing: a VLP-16, whose grid
    is its firing step at 10 Hz, fires every 0.4° at 20 Hz, and a 0.2° grid would leave every other
    column empty (``column_valid`` False although no packet was lost). ``None`` when the sensor has no
    grid. One grid for :meth:`Frame.on_grid`, :meth:`FrameStack.from_frames`, ``lidarpkt decode -o x.npz``
    and the analysis verbs.
    """
    res = sensor.grid_resolution_deg
    if res is None or not sensor.columns_per_frame:
        return res
    factor = max(1, int(round(360.0 / res / sensor.columns_per_frame)))
    while factor > 1 and abs(round(360.0 / (res * factor)) * res * factor - 360.0) > 1e-9:
        factor -= 1  # keep a grid that divides 360°
    return res * factor


def destagger(image: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """``[..., H, W]`` staggered (Ouster: columns = measurement ids) → destaggered, where adjacent
    columns are adjacent azimuths: ``destaggered[u, (c + shift[u]) % W] = staggered[u, c]``, as
    ouster-sdk does it. ``shift``: ``int[H]`` (``SensorInfo.pixel_shift_by_row``)."""
    return _roll_rows(image, np.asarray(shift))


def restagger(image: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """Inverse of :func:`destagger`."""
    return _roll_rows(image, -np.asarray(shift))


def _roll_rows(image: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """``out[..., u, (c + shift[u]) % W] = image[..., u, c]``: two slice copies per group of rows of one shift (rows
    in a stride, as a sensor's few distinct shifts repeat down the beams, are one group), no gather of every pixel.
    A structured image (a point cloud) is moved as raw records: NumPy copies a structured dtype field by field."""
    if not np.any(shift):
        return image
    src = image.view(np.dtype((np.void, image.dtype.itemsize))) if image.dtype.names else image
    w = src.shape[-1]
    out = np.empty_like(src)
    for s, rows in _shift_groups(np.asarray(shift)):
        k = s % w
        for sel in rows:
            out[..., sel, k:] = src[..., sel, :w - k]
            out[..., sel, :k] = src[..., sel, w - k:]
    return out.view(image.dtype) if image.dtype.names else out


def _shift_groups(shift: np.ndarray) -> list[tuple[int, list[slice]]]:
    """(shift, row slices) of each distinct shift: one strided slice when its rows are evenly spaced, else a
    slice per row."""
    groups = []
    for s in np.unique(shift).tolist():
        rows = np.flatnonzero(shift == s)
        step = int(rows[1] - rows[0]) if rows.size > 1 else 1
        if rows.size == 1 or bool(np.all(np.diff(rows) == step)):
            groups.append((int(s), [slice(int(rows[0]), int(rows[-1]) + 1, step)]))
        else:
            groups.append((int(s), [slice(r, r + 1) for r in rows.tolist()]))
    return groups
