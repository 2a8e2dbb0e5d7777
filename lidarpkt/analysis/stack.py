"""Getting a :class:`~lidarpkt.core.sequence.FrameStack` ready for the analysis: loading, frame
selection, pixel checks, and the neighbourhood geometry every spatial computation shares.

Pixel coordinates are always the stack's own (row, column): for Ouster that is the
staggered column (= measurement id, as on the wire). Neighbourhoods, patches and the
spatial monitor are taken in the *destaggered* image, where adjacent columns are adjacent
azimuths; :func:`neighbour_columns` does that translation.
"""

from __future__ import annotations

import warnings
from dataclasses import replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from lidarpkt.errors import AnalysisError, LidarpktWarning
from lidarpkt.core.grid import default_grid_deg, destagger, restagger  # noqa: F401 - one grid, one destagger
from lidarpkt.core.sequence import FrameStack

_MAX_PARTIAL_FALLBACK = 8


def load_stack(
    path: str | Path,
    *,
    metadata: str | Path | Sequence[str | Path] | None = None,
    frames: tuple[int | None, int | None] | None = None,
    include_partial: bool = False,
    resolution_deg: float | None = None,
    workers: int = 1,
    **options: Any,
) -> FrameStack:
    """Decode a capture (pcap/pcapng, MCAP, ROS bag) with :func:`lidarpkt.open` and stack its frames.

    Args:
        path: the capture.
        metadata: Ouster metadata JSON, or a list of them for several sensors (VLP-16 needs none).
        frames: ``(A, B)`` keeps complete frames A..B-1 (Python slice semantics, counted over
            the complete frames of the capture; ``None`` = open end).
        include_partial: also stack partial frames (start/end of a capture). Without it, a
            capture with no complete frame falls back to its partial frames, with a
            :class:`~lidarpkt.errors.LidarpktWarning`.
        resolution_deg: azimuth grid of the stack (VLP-16); default :func:`default_grid_deg`.
        workers: decoding threads (``lidarpkt.open(..., workers=)``); the frames are the same.
        options: other keyword options of ``lidarpkt.open`` (``model`` ...).

    Raises:
        AnalysisError: no frame left after the selection.
        lidarpkt.errors.LidarpktError: whatever the decoder raises on bad input.
    """
    from lidarpkt.pipeline.reader import open_frames

    if metadata is not None and not isinstance(metadata, (str, Path)):  # a list of them
        metadata = [str(m) for m in metadata] or None
    kwargs: dict = {"workers": workers, **options}
    if metadata is not None:
        kwargs["metadata"] = metadata if isinstance(metadata, list) else str(metadata)
    complete: list = []
    partial: list = []
    a, b = frames if frames is not None else (None, None)
    if (a is not None and a < 0) or (b is not None and b < 0):
        raise AnalysisError(f"--frames {a}:{b}: use non-negative frame numbers")
    n_complete = 0
    for f in open_frames(str(path), **kwargs):
        if include_partial or not f.partial:
            n_complete += 1
            if a is not None and n_complete <= a:
                continue
            complete.append(_slim(f))
            if b is not None and n_complete >= b:
                break
        elif not complete and len(partial) < _MAX_PARTIAL_FALLBACK:
            partial.append(_slim(f))  # kept only until a complete frame shows up
    pool = complete
    if not n_complete and partial:
        # A capture shorter than a rotation (or two) is still worth a look (spatial CDFs, the map).
        warnings.warn(
            f"{path}: no complete frame, analysing {len(partial)} partial frame(s) instead",
            LidarpktWarning,
            stacklevel=2,
        )
        pool = partial[slice(a, b)]
    picked = pool
    if not picked:
        sel = "" if frames is None else f" in frames {'' if a is None else a}:{'' if b is None else b}"
        raise AnalysisError(
            f"{path}: no frames{sel} to analyse ({n_complete} complete, {len(partial)} partial found; "
            "check the capture, the --frames range and, for a sensor decoded with its file, --metadata)"
        )
    res = resolution_deg if resolution_deg is not None else default_grid_deg(picked[0].sensor)
    return stack_frames(picked, res)


def _slim(frame):
    """The frame without the per-pixel arrays the analysis does not use (signal, near-IR, flags,
    firing times...), so that a long capture costs only its ranges and reflectivities. The VLP-16
    dual mark of the second strongest returns is kept: :mod:`analysis.returns` needs it."""
    keep = {k: v for k, v in frame.extra.items() if k == "second_strongest"}
    return replace(frame, signal=None, near_ir=None, flags=None, pixel_time_offset_ns=None, extra=keep)


def stack_frames(frames: list, resolution_deg: float | None) -> FrameStack:
    """:meth:`FrameStack.from_frames` that also carries the VLP-16 dual ``second_strongest`` mark
    (a :class:`~analysis.returns.ReturnStack` with ``second_strongest`` set, its raw slots kept)."""
    from dataclasses import fields

    from .returns import ReturnStack

    gridded = [f.on_grid(resolution_deg) for f in frames]
    stack = FrameStack.from_frames(gridded, include_partial=True, resolution_deg=resolution_deg)
    marks = [f.extra.get("second_strongest") for f in gridded]
    if any(m is None for m in marks):
        return stack
    base = {f.name: getattr(stack, f.name) for f in fields(FrameStack)}
    return ReturnStack(**base, second_strongest=np.stack(marks).astype(bool))


def parse_frame_range(text: str) -> tuple[int | None, int | None]:
    """``"A:B"``, ``"A:"``, ``":B"`` → (A, B). Raises AnalysisError on anything else."""
    parts = text.split(":")
    if len(parts) != 2:
        raise AnalysisError(f"--frames {text!r}: expected A:B (e.g. 0:30, 10:, :20)")
    try:
        a = int(parts[0]) if parts[0].strip() else None
        b = int(parts[1]) if parts[1].strip() else None
    except ValueError:
        raise AnalysisError(f"--frames {text!r}: A and B must be integers (e.g. 0:30)") from None
    if (a is not None and a < 0) or (b is not None and b < 0) or (a is not None and b is not None and b <= a):
        raise AnalysisError(f"--frames {text!r}: need 0 <= A < B")
    return a, b


def select_frames(stack: FrameStack, start: int | None = None, stop: int | None = None) -> FrameStack:
    """Frames ``start:stop`` of a stack (stack indices). Raises AnalysisError if none is left."""
    sl = slice(start, stop)
    if not range(len(stack))[sl]:
        raise AnalysisError(f"frames {start}:{stop} select nothing from a stack of {len(stack)} frames")
    per_frame = {}
    for name in ("pixel_valid", "second_strongest"):  # ReturnStack's per-frame arrays
        if getattr(stack, name, None) is not None:
            per_frame[name] = getattr(stack, name)[sl]
    return replace(
        stack,
        **per_frame,
        frame_id=stack.frame_id[sl],
        range_mm=stack.range_mm[sl],
        reflectivity=stack.reflectivity[sl],
        column_valid=stack.column_valid[sl],
        column_timestamp_ns=stack.column_timestamp_ns[sl],
        azimuth_deg=stack.azimuth_deg[sl],
    )


def check_stack(stack: FrameStack) -> None:
    """Raise AnalysisError unless the stack holds at least one frame with the documented shapes."""
    if stack.range_mm.ndim != 4:
        raise AnalysisError(f"range_mm must be [K, R, H, W], got shape {stack.range_mm.shape}")
    if stack.range_mm.shape[0] == 0:
        raise AnalysisError("the frame stack is empty: no frames to analyse")
    k, _, _, w = stack.range_mm.shape
    if stack.column_valid.shape != (k, w):
        raise AnalysisError(f"column_valid has shape {stack.column_valid.shape}, expected {(k, w)}")


def check_pixel(stack: FrameStack, row: int, col: int, slot: int = 0) -> None:
    """Raise AnalysisError (with the valid ranges) if (row, col, slot) is not in the stack."""
    check_stack(stack)
    _, r, h, w = stack.range_mm.shape
    if not (0 <= row < h and 0 <= col < w):
        raise AnalysisError(f"pixel ({row}, {col}) is outside the {h} x {w} range image: use ROW in 0..{h - 1} and COL in 0..{w - 1}")
    if not 0 <= slot < r:
        labels = ", ".join(f"{i}={lab}" for i, lab in enumerate(stack.return_labels))
        raise AnalysisError(f"return slot {slot} does not exist: this capture has {r} slot(s) ({labels})")


def pixel_shift(stack: FrameStack) -> np.ndarray:
    """``int64[H]`` stagger shift of each row (zeros for sensors without a stagger)."""
    h = stack.range_mm.shape[2]
    shift = stack.sensor.pixel_shift_by_row
    if shift is None:
        return np.zeros(h, np.int64)
    shift = np.asarray(shift, np.int64)
    if shift.shape != (h,):
        raise AnalysisError(f"pixel_shift_by_row has {shift.size} entries for {h} rows: metadata does not fit the frames")
    return shift


def neighbour_columns(stack: FrameStack, row: int, col: int, rows: np.ndarray, dcols: np.ndarray) -> np.ndarray:
    """Stack columns of the pixels ``dcols`` azimuth steps from (row, col), in each of ``rows``.

    Works in the destaggered image (``destaggered[u, (c + shift[u]) % W] = staggered[u, c]``) and
    wraps in azimuth. Returns ``int64[len(rows), len(dcols)]``.
    """
    w = stack.range_mm.shape[3]
    shift = pixel_shift(stack)
    base = col + shift[row] - shift[np.asarray(rows)]
    return (base[:, None] + np.asarray(dcols)[None, :]) % w
