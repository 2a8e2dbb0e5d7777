"""Rotations of a spinning sensor cut at an azimuth, from its columns' azimuths (0.01°): where a stream of
azimuths wraps, and whether a frame's columns hold a whole rotation. Shared by every vendor whose packets
carry an azimuth (:mod:`lidarpkt.vendors.velodyne`, :mod:`lidarpkt.vendors.hesai`)."""

from __future__ import annotations

import numpy as np

from .median import median

HALF_TURN_CDEG = 18_000
TURN_CDEG = 36_000.0


def modulo_turn(cdeg: np.ndarray) -> np.ndarray:
    """``float64`` ``cdeg % 36000.0`` (0.01°), the same values as ``np.remainder``: by one addition where the
    values lie within a turn of [0, 36000) (differences of azimuths, azimuths less a cut angle), which is
    what a frame asks; ``np.remainder``'s floating-point modulo costs several times that."""
    out = np.array(cdeg, np.float64)
    np.add(out, TURN_CDEG, out=out, where=out < 0)
    if out.size and not (out.min() >= 0 and out.max() < TURN_CDEG):  # also NaN: np.remainder says what it gives
        return np.remainder(np.asarray(cdeg, np.float64), TURN_CDEG)
    return out


def wrapped(key_cdeg: np.ndarray, previous_cdeg: float | None = None) -> np.ndarray:
    """``bool[N]``: True where an azimuth (minus the cut angle, 0.01°) dropped by more than half a
    turn from the one before it (``previous_cdeg`` for the first; ``None``: the first did not wrap)."""
    key = np.asarray(key_cdeg)
    out = np.empty(key.shape, bool)
    if key.size:
        out[0] = previous_cdeg is not None and bool(key[0] < previous_cdeg - HALF_TURN_CDEG)
        # written in place, with one temporary: a shifted copy as well made two arrays of 200 kB per piece
        np.less(key[1:], key[:-1] - HALF_TURN_CDEG, out=out[1:])
    return out


#: a step between two columns of a frame larger than this many typical steps means columns are missing
#: between them (one missing column makes it two; sensors' jitter stays well below)
GAP_STEPS = 1.6


def rotation_is_whole(azimuth_cdeg: np.ndarray, cut_cdeg: float, *, check_start: bool, check_end: bool,
                      by_block: bool = False, fallback_step_cdeg: float | None = None,
                      lost_columns: bool = False) -> bool:
    """Whether the columns of a frame (``azimuth_cdeg``: each column's azimuth, 0.01°) hold its whole
    rotation: the rule of every vendor whose columns carry an azimuth, so that ``Frame.partial`` means
    the same for all (True exactly when columns of the rotation are missing).

    Missing inside: ``lost_columns`` (the decoder put invalid columns where packets were lost), or a step
    between two columns larger than :data:`GAP_STEPS` typical steps (columns never received and not
    put in). Missing at the ends: where the frame did not begin (``check_start``) or end (``check_end``)
    at a wrap, its first (last) column must lie within one firing interval after (before) the cut angle:
    the firing before (after) it then belongs to another rotation. The interval is the median azimuth step
    of the columns (``fallback_step_cdeg`` for a one-column frame; without it such a frame is not whole);
    with ``by_block`` (frames cut at whole blocks, even columns opening a block) it is two steps, and a
    block's second column takes its first's place."""
    if lost_columns:
        return False
    az = np.asarray(azimuth_cdeg)
    advance: np.ndarray | None = None
    steps: np.ndarray | None = None
    if az.dtype == np.float64 and not cut_cdeg and az.size >= 2:
        # azimuths within a turn and no cut angle: the key is the azimuth itself and its advances are the
        # differences, so the steps are those below 0 moved on by a turn (what modulo_turn gives; half the
        # passes); azimuths rising from the first to the last (a frame between two wraps) are within the turn
        # where those two are, and their steps are the advances themselves (a third of the passes)
        advance = np.diff(az)
        smallest = float(advance.min())
        if smallest > 0 and 0.0 <= az[0] and az[-1] < TURN_CDEG:
            steps = advance
        elif 0.0 <= az.min() and az.max() < TURN_CDEG:
            steps = np.where(advance < 0, advance + TURN_CDEG, advance)
            smallest = float(steps.min())
    if steps is not None and advance is not None:
        key = az
        if smallest > 0:  # then the median is positive too, and bounded by the smallest step and twice the mean
            top, per = float(advance.max()), 2 if by_block else 1
            if not (check_start or check_end) and top <= GAP_STEPS * per * smallest:
                return True  # no advance beyond GAP_STEPS of the smallest step, so none beyond the median's: no gap
            if top > GAP_STEPS * per * 2.0 * float(steps.mean()) * (1 + 1e-9):
                return False  # beyond GAP_STEPS of twice the mean step (steps are >= 0: the median is at most that)
        step = median(steps)
    else:
        key = modulo_turn(np.asarray(az, np.float64) - cut_cdeg)
        step = median(modulo_turn(np.diff(az))) if len(key) >= 2 else 0.0
        advance = np.diff(key) if step > 0 and len(key) >= 2 else None
    if step > 0 and advance is not None:
        if float(advance.max()) > GAP_STEPS * (2 * step if by_block else step):
            return False  # columns of this rotation never arrived between two that did
    if not (check_start or check_end):
        return True
    if len(key) < 2:
        if not fallback_step_cdeg:
            return False
        step = fallback_step_cdeg
    if by_block:
        key = key.copy()
        key[1::2] = key[0::2]
        step *= 2
    if check_start and not key[0] < step:
        return False
    return not check_end or key[-1] >= 36000.0 - step


def rate_disagreement(frame) -> str | None:
    """What a whole frame's own column times say of its sensor's rotation rate, where it disagrees by more than
    a third with the rate its :class:`~lidarpkt.core.sensor.SensorInfo` states (a sensor file of another
    mode, e.g. legacy Ouster metadata of 1024x20 for a 10 Hz capture); ``None`` where they agree or cannot
    tell (a partial frame, no stated rate, fewer than two timed columns)."""
    hz = frame.sensor.frequency_hz
    valid = np.flatnonzero(frame.column_valid)
    if frame.partial or not hz or valid.size < 2:
        return None
    times = frame.column_timestamp_ns[valid]
    span_ns = float(times.max() - times.min())
    if span_ns <= 0:
        return None
    width = frame.column_valid.size
    measured_hz = (valid[-1] - valid[0]) / width / (span_ns * 1e-9)
    if abs(measured_hz - hz) <= hz / 3:
        return None
    return (f"{frame.sensor.source or frame.sensor.model}: its sensor file says {hz:g} Hz, but its frames take "
            f"{1e3 / measured_hz:.0f} ms ({measured_hz:.3g} Hz): the file is of another mode of the sensor; the "
            "frames' times and points follow the packets, the rest follows the file")
