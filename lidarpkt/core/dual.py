"""VLP-16 dual return: which firings' slot 1 holds the second strongest return.

In dual mode (factory byte 0x39) the VLP-16 sends each firing twice: block 2k holds the last
return, block 2k+1 the strongest, except where the last return was also the strongest; there
block 2k+1 holds the second strongest (VLP-16 manual, "Dual Return Mode"). The packet does not
say which of the two block 2k+1 holds: the decoder has to infer it.

The sensor ranks returns by the *signal strength at the detector* ("usually, the farther away
a reflection starts, the weaker it is at the detector"). The packet carries, per return, the
range and the *calibrated reflectivity*, which the sensor derives from that signal by
correcting it for range. This module inverts that correction with the documented range model
of an extended diffuse target (the lidar equation): signal ∝ reflectivity / range². Comparing
reflectivities alone (the rule before this module) ignores the range term and marks a far
return of higher reflectivity as the stronger, which at the larger range it need not be.

Rule (:func:`second_strongest_mark`): slot 1 is marked *second strongest* where the two slots'
ranges differ and the last return's estimated signal is strictly higher:
``reflectivity₀ · range₁² > reflectivity₁ · range₀²`` (exact integer arithmetic, no division).
Tie rule: equal estimated signals are not marked (slot 1 is read as the strongest, which is
what the sensor puts in slot 1 unless the last return was the strongest). Where the sensor saw
one return, both slots hold it and nothing is marked; a firing with an empty slot (range 0,
whose reflectivity byte means nothing) is not marked either: slot 1 is read as sent.

Other tools: velodyne_decoder labels block 2k+1 "strongest" whatever it holds (no mark; our
``frame_points`` keeps its labels). VeloView flags the return with the higher intensity byte
``DUAL_INTENSITY_HIGH`` and nebula labels it ``*_STRONGEST`` (ties: the nearer); both compare the
bytes alone, with no range term, so they call a far return of higher reflectivity the stronger.
On the nebula VLP-16 dual bag the range term keeps 146 of the 339 pairs the bytes call "last
return stronger" (42 of the 89 in nebula's own decoded cloud; tests/velodyne/test_velodyne_dual.py).

What the mark cannot know on a real sensor: the reflectivity byte is quantised (two returns
whose signals differ by less than about half a reflectivity unit cannot be ordered from the
packet), saturates at 255, and a real unit's range calibration is not exactly 1/range² (at
short range the receiver's near-field response differs). There the inferred order can be wrong;
on the generated scene (whose reflectivity is derived from the echo strength with exactly this
model) the only wrong marks are firings whose order the quantised bytes cannot decide.
"""

from __future__ import annotations

import numpy as np

from . import kernels

__all__ = ["second_strongest_mark", "signal_order_undecided"]


def _pairs(range_mm: np.ndarray, reflectivity: np.ndarray) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, ...]]:
    """(``both`` bool[N] over the flattened firings, its indices, (r0, r1, f0, f1) int64 there).

    Only firings with two different returns are widened to int64: in a dual frame most firings
    hold one return twice, and widening whole frames costs more than the comparison."""
    r = np.asarray(range_mm)
    f = np.asarray(reflectivity)
    if r.shape != f.shape or r.ndim < 1 or r.shape[0] != 2:
        raise ValueError(f"need range_mm and reflectivity of the same shape [2, ...], got {r.shape} and {f.shape}")
    flat_r, flat_f = r.reshape(2, -1), f.reshape(2, -1)
    both = (flat_r[0] != flat_r[1]) & (flat_r[0] > 0) & (flat_r[1] > 0)
    idx = np.flatnonzero(both)
    return both, idx, tuple(a[k].take(idx).astype(np.int64) for a in (flat_r, flat_f) for k in (0, 1))


def second_strongest_mark(range_mm: np.ndarray, reflectivity: np.ndarray) -> np.ndarray:
    """``bool[...]``: the firings whose slot 1 holds the second strongest return.

    Args:
        range_mm: ``[2, ...]`` integer ranges of slot 0 (the last return) and slot 1, mm
            (0 = no return).
        reflectivity: ``[2, ...]`` calibrated reflectivity bytes of the same slots.

    True where both slots hold a return, their ranges differ, and slot 0's estimated signal
    (reflectivity / range²) is strictly the higher; ties are not marked. Int64 arithmetic is
    exact for every VLP-16 range (< 131.1 m) and reflectivity byte.
    Raises ValueError when the shapes are not ``[2, ...]`` and equal.
    """
    native = kernels.native
    if native is not None and _native_ready(range_mm, reflectivity):
        shape = range_mm.shape
        three = range_mm.ndim == 3  # the kernel's [2, H, W], views taken as they are; other ranks as [2, 1, N]
        as3 = shape if three else (2, 1, -1)
        marks = np.empty((shape[1], shape[2]) if three else (1, int(np.prod(shape[1:]))), bool)
        if native.dual_mark(range_mm.reshape(as3), reflectivity.reshape(as3), marks):  # False: a range of 2^22 mm or more
            return marks.reshape(shape[1:])
    both, idx, (r0, r1, f0, f1) = _pairs(range_mm, reflectivity)
    out = np.zeros(both.size, bool)
    out[idx] = f0 * r1 * r1 > f1 * r0 * r0
    return out.reshape(np.shape(range_mm)[1:])


def _native_ready(range_mm, reflectivity) -> bool:
    """Arrays the compiled twin takes: ``uint32`` / ``uint8`` of one ``[2, ...]`` shape."""
    return (isinstance(range_mm, np.ndarray) and isinstance(reflectivity, np.ndarray)
            and range_mm.dtype == np.uint32 and reflectivity.dtype == np.uint8
            and range_mm.shape == reflectivity.shape and range_mm.ndim >= 1 and range_mm.shape[0] == 2)


def signal_order_undecided(range_mm: np.ndarray, reflectivity: np.ndarray) -> np.ndarray:
    """``bool[...]``: two-return firings whose signal order the quantised reflectivity bytes cannot decide.

    A byte ``b`` stands for any reflectivity in [b − ½, b + ½] (b = 255: any above 254.5, the
    byte saturates); the firing is undecided when the two returns' signal intervals
    (reflectivity / range²) overlap. Outside these firings the packet determines which return
    was the stronger, and :func:`second_strongest_mark` is right whenever the range model holds.
    Same arguments and errors as :func:`second_strongest_mark`.
    """
    both, idx, (r0, r1, f0, f1) = _pairs(range_mm, reflectivity)
    # In half-units to stay in integers: interval of 2b ± 1, open-ended above for 255.
    lo0, hi0 = (2 * f0 - 1) * r1 * r1, (2 * f0 + 1) * r1 * r1
    lo1, hi1 = (2 * f1 - 1) * r0 * r0, (2 * f1 + 1) * r0 * r0
    out = np.zeros(both.size, bool)
    out[idx] = ((lo0 <= hi1) | (f1 >= 255)) & ((lo1 <= hi0) | (f0 >= 255))
    return out.reshape(np.shape(range_mm)[1:])
