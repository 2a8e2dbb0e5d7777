"""``lidarpkt.core.buffers.BufferPool``: arrays made from recycled buffers, and never from one an array
still refers to."""

from __future__ import annotations

import gc

import numpy as np
import pytest

from lidarpkt.core.buffers import BufferPool, size_class


def address(a: np.ndarray) -> int:
    return a.__array_interface__["data"][0]


@pytest.mark.parametrize("shape, dtype", [((3, 16, 1000), np.uint32), (7, np.float64), ((0, 5), np.int64),
                                          ((2, 3), np.bool_), (1, np.uint8)])
def test_arrays_are_as_numpy_empty_makes_them(shape, dtype):
    pool = BufferPool(1 << 20)
    a = pool.empty(shape, dtype)
    want = np.empty(shape, dtype)
    assert (a.shape, a.dtype) == (want.shape, want.dtype)
    assert a.flags.c_contiguous and a.flags.writeable
    assert address(a) % 16 == 0  # as malloc's, which numpy.empty uses


def test_a_buffer_serves_again_once_nothing_refers_to_it():
    pool = BufferPool(1 << 20)
    a = pool.empty((4, 1000), np.uint32)
    first = address(a)
    del a
    b = pool.empty((2000,), np.int64)  # another shape and dtype, as many bytes
    assert address(b) == first
    assert (pool.made, pool.reused) == (1, 1)


HOLDERS = {"array": lambda a: a, "slice": lambda a: a[2:3, 10:20], "view": lambda a: a.view(np.uint8),
           "reshaped": lambda a: a.reshape(-1)[::3], "memoryview": memoryview,
           "strided": lambda a: np.lib.stride_tricks.as_strided(a, (4,), (2,))}


@pytest.mark.parametrize("keep", sorted(HOLDERS))
def test_any_reference_keeps_its_buffer_out_of_the_pool(keep):
    pool = BufferPool(1 << 20)
    a = pool.empty((8, 100), np.uint16)
    a[...] = 7
    held = HOLDERS[keep](a)
    before = np.array(held, copy=True)
    del a
    gc.collect()
    b = pool.empty((8, 100), np.uint16)
    b[...] = 9
    assert (pool.made, pool.reused) == (2, 0)
    assert np.array_equal(np.asarray(held), before)  # the numbers the holder sees never change


def test_held_arrays_keep_their_numbers_while_the_pool_goes_on():
    rng = np.random.default_rng(3)
    pool = BufferPool(2 << 20)
    held: list[tuple[np.ndarray, int]] = []
    for i in range(400):
        a = pool.empty(int(rng.integers(1, 50_000)), np.uint32)
        a.fill(i)
        if rng.random() < 0.2:
            held.append((a[: int(rng.integers(1, a.size + 1))], i))
        if held and rng.random() < 0.15:
            held.pop(int(rng.integers(len(held))))
        del a
        for view, value in held:
            assert (view == value).all()
    assert pool.reused > 0
    assert pool.nbytes <= pool.max_bytes


@pytest.mark.parametrize("nbytes", [1, 63, 64, 65, 1000, 4096, 100_000, 1_500_000, (1 << 20) + 1])
def test_size_classes_round_up_by_a_quarter_or_a_cache_line(nbytes):
    capacity = size_class(nbytes)
    assert nbytes <= capacity and capacity % 64 == 0
    assert capacity <= max(nbytes * 1.25, nbytes + 63)
    assert size_class(capacity) == capacity


def test_memory_kept_is_bounded():
    pool = BufferPool(1 << 20)
    arrays = [pool.empty(300_000, np.uint8) for _ in range(6)]  # all held: only three fit the bound
    assert pool.nbytes <= 1 << 20
    assert pool.made == 6
    del arrays
    big = pool.empty(900_000, np.uint8)  # no kept buffer is large enough: the free ones make room for it
    assert pool.nbytes <= 1 << 20
    small = pool.empty(100, np.uint8)
    assert not np.shares_memory(big, small)
