"""CRC-64/XZ (ECMA-182 polynomial, reflected, init and xorout all ones) over a batch of packets.

Ouster firmware ≥ 2.5 stores this CRC of bytes ``[0, len − 8)`` little-endian in the last 8
bytes of each lidar packet.

The CRC register update is linear over GF(2), so a block of ``B`` bytes contributes
``XOR_p T_p[byte_p]`` where ``T_p`` is the one-byte table advanced by ``B − 1 − p`` zero bytes.
A batch is processed one block at a time for all packets at once (a gather and an XOR
reduction per block), with the register carried between blocks through the "advance by B
zero bytes" operator, itself split into 8 byte tables. Memory per table set: B × 256 × 8 bytes.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from .profiles import CRC_BYTES

POLY_REFLECTED = 0xC96C5795D7870F42
INIT = 0xFFFFFFFFFFFFFFFF
XOROUT = 0xFFFFFFFFFFFFFFFF
BLOCK = 256


@lru_cache(maxsize=1)
def _byte_table() -> np.ndarray:
    t = np.arange(256, dtype=np.uint64)
    poly = np.uint64(POLY_REFLECTED)
    one = np.uint64(1)
    for _ in range(8):
        t = np.where(t & one, (t >> one) ^ poly, t >> one)
    return t


def _advance_zero(reg: np.ndarray) -> np.ndarray:
    """Register after one zero byte (linear in ``reg``)."""
    t = _byte_table()
    return t[(reg & np.uint64(0xFF)).astype(np.intp)] ^ (reg >> np.uint64(8))


@lru_cache(maxsize=1)
def _position_tables() -> np.ndarray:
    """``uint64[BLOCK, 256]``: contribution of byte value v at block position p."""
    out = np.empty((BLOCK, 256), np.uint64)
    row = _byte_table().copy()
    for p in range(BLOCK - 1, -1, -1):
        out[p] = row
        row = _advance_zero(row)
    return out


@lru_cache(maxsize=None)
def _shift_tables(n_bytes: int) -> np.ndarray:
    """``uint64[8, 256]``: register advanced by ``n_bytes`` zero bytes, split by register byte."""
    basis = (np.arange(256, dtype=np.uint64)[None, :] << (np.uint64(8) * np.arange(8, dtype=np.uint64)[:, None])).copy()
    for _ in range(n_bytes):
        basis = _advance_zero(basis)
    return basis


def _shift(reg: np.ndarray, n_bytes: int) -> np.ndarray:
    tables = _shift_tables(n_bytes)
    out = np.zeros_like(reg)
    for k in range(8):
        out ^= tables[k][((reg >> np.uint64(8 * k)) & np.uint64(0xFF)).astype(np.intp)]
    return out


def crc64_xz(data: np.ndarray) -> np.ndarray:
    """CRC-64/XZ of each row of ``data`` (``uint8[N, L]``, or ``uint8[L]``) → ``uint64[N]`` (or scalar array).

    Check value: ``crc64_xz(b"123456789") == 0x995DC9BBDF1939FA``.
    """
    arr = np.asarray(data, dtype=np.uint8)
    single = arr.ndim == 1
    if single:
        arr = arr[None, :]
    n, length = arr.shape
    pos = _position_tables()
    reg = np.full(n, INIT, np.uint64)
    start = 0
    # bounded memory: gather at most ~8 MB at a time
    rows_per_chunk = max(1, (1 << 20) // BLOCK)
    while start < length:
        size = min(BLOCK, length - start)
        block = arr[:, start : start + size]
        reg = _shift(reg, size)
        contrib = np.empty(n, np.uint64)
        table = pos[BLOCK - size :]  # the last `size` rows: positions followed by the right number of zeros
        cols = np.arange(size)
        for r0 in range(0, n, rows_per_chunk):
            sub = block[r0 : r0 + rows_per_chunk]
            contrib[r0 : r0 + rows_per_chunk] = np.bitwise_xor.reduce(table[cols, sub], axis=1)
        reg ^= contrib
        start += size
    out = reg ^ np.uint64(XOROUT)
    return out[0] if single else out


def footer_crc_ok(payload: np.ndarray) -> np.ndarray:
    """``bool[N]``: the last 8 bytes of each packet are the CRC-64/XZ of the bytes before them."""
    stored = np.ascontiguousarray(payload[:, -CRC_BYTES:]).view("<u8")[:, 0]
    return crc64_xz(payload[:, :-CRC_BYTES]) == stored
