"""Return selection as the sensor defines it: which return of each firing a consumer looks at.

A capture's *slots* are what is on the wire; a *return kind* is what a study compares:

* VLP-16 dual (slots ``("last", "strongest")``): slot 0 is the last return; slot 1 is the
  strongest, except where the last return was also the strongest, where it holds the second
  strongest (the decoder marks those pixels in ``frame.extra["second_strongest"]``, inferring
  from the signal estimated as reflectivity / range², see :mod:`lidarpkt.core.dual`). So per
  firing: ``last`` = slot 0; ``strongest`` = slot 0 where marked, else slot 1;
  ``second_strongest`` = slot 1 where marked, no return where the sensor saw one return (both
  slots equal), and **no sample** elsewhere (the sensor did not report the second strongest).
* Ouster dual (``("strongest", "second_strongest")``) and single-return captures: each kind is
  one slot.
* A raw slot stays selectable by its index (``0``, ``1``).

:func:`select_returns` is the one function every consumer uses (``analyze``, ``multireturn``,
``compare-returns``, the Python API and the figures): it turns a stack and a list of selections
into a :class:`ReturnStack` whose slots are the selections, with a per-pixel ``pixel_valid``
where a kind has no sample in some firings. :func:`sample_mask` is how consumers read "is this
a sample" (column not lost, and the sensor reported this return).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Sequence

import numpy as np

from lidarpkt.errors import AnalysisError
from lidarpkt.core.sequence import FrameStack
from lidarpkt.core.dual import second_strongest_mark

#: The return kinds a selection may name (besides a raw slot index).
RETURN_KINDS = ("strongest", "last", "second_strongest")
#: the labels sensors give their return slots (Hesai's first/second, Ouster's by return order), besides the kinds
SLOT_LABELS = ("first", "second", "farthest", "second_farthest", "nearest", "second_nearest", "second_last")

_LAST_STRONGEST = ("last", "strongest")  # a dual mode whose slot 1 is the strongest or the second strongest


@dataclass(eq=False)
class ReturnStack(FrameStack):
    """A :class:`FrameStack` whose slots are return selections.

    Attributes (besides FrameStack's):
        pixel_valid: ``bool[K, R, H, W]`` or None: False where the sensor did not report this
            return in this firing (no sample); None = every pixel of a valid column is a sample.
        second_strongest: ``bool[K, H, W]`` or None: VLP-16 dual only, the decoder's mark of the
            firings whose slot 1 holds the second strongest return (carried from
            ``frame.extra["second_strongest"]`` by :func:`analysis.stack.load_stack`).
        sources: per slot, the raw slot index it was taken from, or None when it is combined
            per firing from both slots.
    """

    pixel_valid: np.ndarray | None = None
    second_strongest: np.ndarray | None = None
    sources: tuple[int | None, ...] | None = None


def _mixes_second_strongest(stack: FrameStack) -> bool:
    """True for a stack of a Last+Strongest dual mode as decoded (slot 1 mixes strongest and second
    strongest: a VLP-16's dual mode, a Hesai Pandar's Last+Strongest, whose decoder marks the second
    strongest by the same rule, :mod:`lidarpkt.vendors.hesai.models`); False for a stack already made of
    selections (:func:`select_returns`)."""
    if getattr(stack, "sources", None) is not None:
        return False
    return tuple(stack.return_labels) == _LAST_STRONGEST


def available_returns(stack: FrameStack) -> tuple[str, ...]:
    """The return kinds this capture reports, in the order the analysis shows them
    (VLP-16 dual: last, strongest, second_strongest; otherwise its slot labels)."""
    if _mixes_second_strongest(stack):
        return ("last", "strongest", "second_strongest")
    return tuple(stack.return_labels)


def parse_return(text: str | int) -> str | int:
    """``"0"``/``0`` → 0 (a raw slot), ``"strongest"`` → ``"strongest"``, a slot label of some sensor
    (:data:`SLOT_LABELS`: ``"first"``, ``"farthest"``...) as it is, looked up in the capture's slots when used.
    Raises AnalysisError for anything else."""
    if isinstance(text, (int, np.integer)):
        return int(text)
    t = str(text).strip()
    if t.lstrip("-").isdigit():
        return int(t)
    if t in RETURN_KINDS or t in SLOT_LABELS:
        return t
    raise AnalysisError(f"--return {text!r}: give a slot index (0, 1) or one of {', '.join(RETURN_KINDS + SLOT_LABELS)}")


def second_strongest_marks(stack: FrameStack) -> np.ndarray:
    """``bool[K, H, W]``: the VLP-16 dual firings whose slot 1 holds the second strongest return.

    The decoder's mark when the stack carries it (:func:`analysis.stack.load_stack` does);
    for a stack built by hand, the decoder's rule applied to its slots
    (:func:`lidarpkt.core.dual.second_strongest_mark`: the last return's signal, estimated as
    reflectivity / range², is strictly the higher)."""
    marks = getattr(stack, "second_strongest", None)
    if marks is not None:
        return marks
    return second_strongest_mark(np.moveaxis(stack.range_mm, 1, 0), np.moveaxis(stack.reflectivity, 1, 0))


def _kind(stack: FrameStack, kind: str) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, int | None]:
    """(range_mm [K,H,W], reflectivity [K,H,W], pixel_valid [K,H,W] or None, raw source slot or None)."""
    pv = getattr(stack, "pixel_valid", None)
    if _mixes_second_strongest(stack):
        marked = second_strongest_marks(stack)
        r0, r1 = stack.range_mm[:, 0], stack.range_mm[:, 1]
        f0, f1 = stack.reflectivity[:, 0], stack.reflectivity[:, 1]
        if kind == "last":
            return r0, f0, None if pv is None else pv[:, 0], 0
        if kind == "strongest":
            return np.where(marked, r0, r1), np.where(marked, f0, f1), None if pv is None else pv[:, 1], None
        if kind == "second_strongest":
            one_return = r1 == r0  # the sensor saw one return: there is no second one (a non-return)
            rng = np.where(marked, r1, np.uint32(0)).astype(stack.range_mm.dtype)
            refl = np.where(marked, f1, 0).astype(stack.reflectivity.dtype)
            valid = marked | one_return
            return rng, refl, valid if pv is None else valid & pv[:, 1], None
    labels = tuple(stack.return_labels)
    if kind in labels:
        i = labels.index(kind)
        return stack.range_mm[:, i], stack.reflectivity[:, i], None if pv is None else pv[:, i], i
    raise AnalysisError(
        f"return {kind!r} is not in this capture ({stack.sensor.model}, slots {list(labels)}); "
        f"choose one of {', '.join(available_returns(stack))} or a slot index"
    )


def _raw_label(stack: FrameStack, slot: int) -> str:
    if _mixes_second_strongest(stack) and slot == 1:
        return "strongest_or_second"  # slot 1 as the sensor fills it, not one return kind
    return stack.return_labels[slot]


def select_returns(stack: FrameStack, selections: Sequence[str | int]) -> ReturnStack:
    """A stack whose slots are ``selections`` (return kinds or raw slot indices), per firing.

    Args:
        stack: any FrameStack (a :class:`ReturnStack` too).
        selections: e.g. ``["strongest"]``, ``["last", "strongest", "second_strongest"]``, ``[1]``.

    Returns:
        ReturnStack with ``len(selections)`` slots labelled by kind (a raw slot keeps its label,
        except VLP-16 dual slot 1: ``"strongest_or_second"``), ``pixel_valid`` set when any
        selection has firings without a sample. Arrays are copies (slots are stacked).

    Raises:
        AnalysisError: a kind the capture does not report, or a slot index out of range.
    """
    if not selections:
        raise AnalysisError("select at least one return")
    r_count = stack.range_mm.shape[1]
    k, _, h, w = stack.range_mm.shape
    rngs, refls, valids, labels, sources = [], [], [], [], []
    pv = getattr(stack, "pixel_valid", None)
    for sel in selections:
        sel = parse_return(sel)
        if isinstance(sel, int):
            if not 0 <= sel < r_count:
                names = ", ".join(f"{i}={lab}" for i, lab in enumerate(stack.return_labels))
                raise AnalysisError(f"return slot {sel} does not exist: this capture has {r_count} "
                                    f"{'slot' if r_count == 1 else 'slots'} ({names}); give one of them (--return)")
            rngs.append(stack.range_mm[:, sel])
            refls.append(stack.reflectivity[:, sel])
            valids.append(None if pv is None else pv[:, sel])
            labels.append(_raw_label(stack, sel))
            src = getattr(stack, "sources", None)
            sources.append(sel if src is None else src[sel])
        else:
            rng, refl, valid, src_slot = _kind(stack, sel)
            rngs.append(rng)
            refls.append(refl)
            valids.append(valid)
            labels.append(sel)
            src = getattr(stack, "sources", None)
            sources.append(src_slot if src is None or src_slot is None else src[src_slot])
    pixel_valid = None
    if any(v is not None for v in valids):
        pixel_valid = np.stack([np.ones((k, h, w), bool) if v is None else v for v in valids], axis=1)
    base = {f.name: getattr(stack, f.name) for f in fields(FrameStack)}
    base.update(return_labels=tuple(labels), range_mm=np.stack(rngs, axis=1), reflectivity=np.stack(refls, axis=1))
    return ReturnStack(**base, pixel_valid=pixel_valid, second_strongest=None, sources=tuple(sources))


def sensor_returns(stack: FrameStack) -> ReturnStack:
    """The stack with one slot per return kind the capture reports (:func:`available_returns`),
    each selected per firing: what whole-image statistics (``multireturn``, one capture or an
    archive of them) are computed on."""
    return select_returns(stack, available_returns(stack))


def resolve(stack: FrameStack, selection: str | int) -> tuple[FrameStack, int]:
    """``(stack, slot)`` for a consumer that works on one slot index: a raw slot or a kind that is
    one slot of ``stack`` comes back as that slot of ``stack`` itself (no copy); a kind combined
    per firing (VLP-16 dual strongest / second strongest) as slot 0 of a one-slot
    :func:`select_returns` stack. Raises AnalysisError like :func:`select_returns`."""
    sel = parse_return(selection)
    if isinstance(sel, int):
        if not 0 <= sel < stack.range_mm.shape[1]:
            select_returns(stack, [sel])  # raises with the list of slots
        return stack, sel
    if not _mixes_second_strongest(stack) and sel in stack.return_labels:
        return stack, tuple(stack.return_labels).index(sel)
    if _mixes_second_strongest(stack) and sel == "last":
        return stack, 0
    return select_returns(stack, [sel]), 0


def sample_mask(stack: FrameStack, slot: int | None = None) -> np.ndarray:
    """Which pixels are samples (column not lost, and the sensor reported this return).

    ``bool[K, R, H, W]`` (``slot=None``) or ``bool[K, H, W]`` for one slot; a broadcast view
    where the stack has no per-pixel mask."""
    k, r, h, w = stack.range_mm.shape
    pv = getattr(stack, "pixel_valid", None)
    if slot is None:
        col = np.broadcast_to(stack.column_valid[:, None, None, :], (k, r, h, w))
        return col if pv is None else col & pv
    col = np.broadcast_to(stack.column_valid[:, None, :], (k, h, w))
    return col if pv is None else col & pv[:, slot]
