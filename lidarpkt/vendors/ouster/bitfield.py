"""Bit fields: one field of a little-endian bit-packed record (:class:`BitField`, named as the Ouster
firmware manual names it), the check that a record's fields own every bit once, and reading and writing
a field of many records at once (NumPy)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidarpkt.errors import PacketFormatError


@dataclass(frozen=True)
class BitField:
    """One field of a little-endian bit-packed record.

    Attributes:
        name: the manual's field name (``RANGE``, ``FLAGS`` ...); ``_``-prefixed = reserved bits.
        start_bit: offset of the least significant bit from the start of the record.
        width: number of bits on the wire.
        upshift: left shift applied after extraction to get the field's unit (RANGE of
            RNG15_RFL8_NIR8 is in 8 mm steps: upshift 3 gives mm).
    """

    name: str
    start_bit: int
    width: int
    upshift: int = 0

    @property
    def reserved(self) -> bool:
        return self.name.startswith("_")

    @property
    def dtype(self) -> np.dtype:
        """Smallest unsigned type holding ``width + upshift`` bits (as ouster-sdk's field types)."""
        bits = self.width + self.upshift
        for dt in (np.uint8, np.uint16, np.uint32, np.uint64):
            if bits <= np.dtype(dt).itemsize * 8:
                return np.dtype(dt)
        raise ValueError(f"bit field {self.name} is wider than 64 bits")

    @property
    def mask(self) -> int:
        return (1 << self.width) - 1


def check_cover(fields: tuple[BitField, ...], n_bits: int, what: str) -> None:
    """Every bit of the record belongs to exactly one field (checked at import)."""
    used = np.zeros(n_bits, np.int32)
    for f in fields:
        if f.start_bit + f.width > n_bits or f.width <= 0:
            raise PacketFormatError(f"{what}: field {f.name} outside the record")
        used[f.start_bit : f.start_bit + f.width] += 1
    if not np.all(used == 1):
        raise PacketFormatError(f"{what}: bits {np.flatnonzero(used != 1).tolist()} not covered exactly once")


def reserved_bits(start_bit: int, width: int) -> tuple[BitField, ...]:
    """Reserved bits split into ≤ 32-bit pieces (so any field fits a 64-bit read)."""
    out = []
    while width > 0:
        w = min(32, width, 32 - start_bit % 32) if start_bit % 32 else min(32, width)
        out.append(BitField(f"_reserved_{start_bit}", start_bit, w))
        start_bit += w
        width -= w
    return tuple(out)


def read_bits(data: np.ndarray, field: BitField) -> np.ndarray:
    """Field ``field`` of byte records ``data`` (``uint8[..., nbytes]``), up-shift applied, in ``field.dtype``."""
    first = field.start_bit // 8
    shift = field.start_bit % 8
    nbytes = (shift + field.width + 7) // 8
    if nbytes == 1:  # within one byte (the header's status fields, read for every packet decoded)
        v = data[..., first]
        if shift:
            v = v >> np.uint8(shift)
        if field.width < 8:
            v = v & np.uint8(field.mask)
        v = v.astype(field.dtype)
        return v << field.dtype.type(field.upshift) if field.upshift else v
    acc = np.zeros(data.shape[:-1], np.uint64)
    for k in range(nbytes):
        acc |= data[..., first + k].astype(np.uint64) << np.uint64(8 * k)
    value = (acc >> np.uint64(shift)) & np.uint64(field.mask)
    return value.astype(field.dtype) << field.dtype.type(field.upshift) if field.upshift else value.astype(field.dtype)


def write_bits(data: np.ndarray, field: BitField, value: np.ndarray) -> None:
    """OR ``value`` (in field units, up-shift included) into the zeroed bits of ``data`` (``uint8[..., nbytes]``)."""
    raw = _to_raw(np.asarray(value), field)
    first = field.start_bit // 8
    shift = field.start_bit % 8
    nbytes = (shift + field.width + 7) // 8
    raw = raw << np.uint64(shift)
    for k in range(nbytes):
        data[..., first + k] |= ((raw >> np.uint64(8 * k)) & np.uint64(0xFF)).astype(np.uint8)


def _to_raw(value: np.ndarray, field: BitField) -> np.ndarray:
    """The wire value of ``value``; :class:`PacketFormatError` if it does not fit the field exactly."""
    v = value.astype(np.uint64)
    if field.upshift and np.any(v & np.uint64((1 << field.upshift) - 1)):
        raise PacketFormatError(
            f"field {field.name}: values must be multiples of {1 << field.upshift} "
            f"(the wire unit); got e.g. {int(v[(v & np.uint64((1 << field.upshift) - 1)) != 0].flat[0])}"
        )
    raw = v >> np.uint64(field.upshift)
    if np.any(raw > np.uint64(field.mask)):
        raise PacketFormatError(
            f"field {field.name}: value {int(raw.max()) << field.upshift} does not fit in {field.width} bits"
            + (f" × {1 << field.upshift}" if field.upshift else "")
        )
    return raw
