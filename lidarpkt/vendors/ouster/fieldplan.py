"""Where a frame's pixel fields come from: the extraction plan of a profile, shared by both paths
of the Ouster frame assembly (:mod:`lidarpkt.vendors.ouster.frames`).

The compiled ``ouster_scatter`` takes the plan as ``int64[F, 4]`` steps (:func:`scatter_steps`)
and the frame's ``[H, W]`` arrays (:func:`new_fields`); its NumPy twin applies the same steps to
word planes (:func:`extract`).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

SLOT_FIELDS = (
    ("RANGE", "REFLECTIVITY", "SIGNAL", "FLAGS"),
    ("RANGE2", "REFLECTIVITY2", "SIGNAL2", "FLAGS2"),
)
SLOT_ATTRS = ("range_mm", "reflectivity", "signal", "flags")


def plane_attr(name: str) -> str:
    """The frame attribute (or ``Frame.extra`` key) of a one-plane pixel field: its name lower-cased
    (``NEAR_IR`` → ``near_ir``, ``ZONE_MASK`` → ``zone_mask``, ``R`` → ``r``)."""
    return name.lower()


@lru_cache(maxsize=None)
def field_plan(profile) -> tuple:
    """Per frame attribute: (attr, one extraction step per return slot, dtype); no steps = absent.

    The four slot attributes (:data:`SLOT_ATTRS`) and ``near_ir`` always appear; every other pixel
    field of the profile (``WINDOW``, ``ZONE_MASK``, ``R``/``G``/``B`` ...) follows with one plane,
    under :func:`plane_attr` of its name.

    A step is (word index, bit offset in the word, mask or 0 when the cast already drops the bits
    above the field, up-shift): see :func:`extract`.
    """
    names = set(profile.field_names)
    slots = SLOT_FIELDS[: profile.returns]
    plan: list[tuple[str, tuple[tuple[int, int, int, int], ...], np.dtype | None]] = []
    for i, attr in enumerate(SLOT_ATTRS):
        if slots[0][i] not in names:
            plan.append((attr, (), None))
            continue
        fs = [profile.field(sl[i]) for sl in slots]
        plan.append((attr, tuple(_step(f) for f in fs), fs[0].dtype))
    in_slots = {n for sl in SLOT_FIELDS for n in sl}
    planes = ["NEAR_IR"] + [n for n in profile.field_names if n not in in_slots and n != "NEAR_IR"]
    for name in planes:
        f = profile.field(name) if name in names else None
        plan.append((plane_attr(name), (_step(f),) if f is not None else (), f.dtype if f is not None else None))
    return tuple(plan)


def new_fields(profile, h: int, w: int) -> tuple[dict[str, np.ndarray | None], list[np.ndarray]]:
    """Fresh (unzeroed) field arrays of a frame, by attribute as ``frames._Builder.fields`` returns them,
    and their ``[H, W]`` planes in the order of :func:`scatter_steps`."""
    out: dict[str, np.ndarray | None] = {}
    targets: list[np.ndarray] = []
    for attr, per_slot, dtype in field_plan(profile):
        if not per_slot:
            out[attr] = None
        elif attr not in SLOT_ATTRS:
            out[attr] = plane = np.empty((h, w), dtype)
            targets.append(plane)
        else:
            out[attr] = planes = np.empty((len(per_slot), h, w), dtype)
            targets.extend(planes)
    return out, targets


@lru_cache(maxsize=None)
def scatter_steps(profile) -> np.ndarray:
    """``int64[F, 4]``: the extraction steps of :func:`field_plan`, flattened in the order of :func:`new_fields`."""
    return np.array([step for _, per_slot, _ in field_plan(profile) for step in per_slot], np.int64).reshape(-1, 4)


@lru_cache(maxsize=None)
def packet_layout(profile, h: int, c: int) -> tuple[int, int, int, int]:
    """Bytes of the packet layout: (first column, one column, pixels within a column, one pixel)."""
    packet = profile.packet_dtype(h, c)
    column = packet["columns"].base
    return packet.fields["columns"][1], column.itemsize, column.fields["pixels"][1], profile.pixel_bytes


def _step(f) -> tuple[int, int, int, int]:
    k, off = divmod(f.start_bit, 32)
    masked = f.width < min(32 - off, 8 * f.dtype.itemsize)
    return k, off, f.mask if masked else 0, f.upshift


def extract(planes: np.ndarray, step: tuple[int, int, int, int], out: np.ndarray) -> np.ndarray:
    """The NumPy twin's pass of one step: ``out`` (``[H, W]``) from word plane ``planes[k]``; returns ``out``."""
    k, off, mask, upshift = step
    w = planes[k]
    if off:
        np.right_shift(w, np.uint32(off), out=out, casting="unsafe")
        if mask:
            np.bitwise_and(out, out.dtype.type(mask), out=out)
    elif mask:
        np.bitwise_and(w, np.uint32(mask), out=out, casting="unsafe")
    else:
        np.copyto(out, w, casting="unsafe")
    if upshift:
        np.left_shift(out, out.dtype.type(upshift), out=out)
    return out
