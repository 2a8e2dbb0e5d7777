"""The compiled Ouster scatter (``ouster_scatter``, lidarpkt/native/ouster.c) against its NumPy twin.

Frames of every real capture (every profile: LEGACY, RNG19, RNG19 dual, RNG15, FuSa RNG15 dual) are
compared array by array with the twin's (``kernels.native`` set to ``None``); packets shuffled,
duplicated and lost take both through the out-of-order paths (the captures of more than one
packet: LEGACY, RNG19, RNG15); the kernel alone is checked on
random bytes against ``decode.read_pixel_field`` (the per-packet decoder, which reads the profile's
bit fields by another route), and refuses arguments that do not fit without writing anything.
The ouster-sdk crosscheck (test_ouster_crosscheck.py) runs the compiled path on the same captures.
"""

from __future__ import annotations

import numpy as np
import pytest

from lidarpkt.core import kernels
from lidarpkt.vendors.ouster.decode import packet_view, read_pixel_field
from lidarpkt.vendors.ouster.fieldplan import SLOT_FIELDS, extract, new_fields, packet_layout, scatter_steps
from lidarpkt.vendors.ouster.builder import _NATIVE_PIXEL_BYTES
from lidarpkt.vendors.ouster.frames import OusterDecoder
from lidarpkt.vendors.ouster.profiles import PROFILES
from test_ouster_cases import CAPTURES, IDS, decode_frames, lidar_streams

# the kernel's widest pixel is 16 bytes; the 20-byte profiles (FIVE_WORD_PIXEL, RGB16 dual) take the NumPy twin
NATIVE_PROFILES = sorted(n for n, p in PROFILES.items() if p.pixel_bytes <= _NATIVE_PIXEL_BYTES)

NATIVE = kernels.native
pytestmark = pytest.mark.skipif(NATIVE is None, reason="the C extension is not built (python setup.py build_ext --inplace) or LIDARPKT_NATIVE=0")

FRAME_ARRAYS = ("range_mm", "reflectivity", "signal", "near_ir", "flags", "column_valid", "column_timestamp_ns",
                "azimuth_deg", "measurement_id", "status", "encoder_count")


def assert_same_frames(got, want, where):
    assert len(got) == len(want), where
    for a, b in zip(got, want):
        assert (a.frame_id, a.partial) == (b.frame_id, b.partial), where
        assert a.counters == b.counters, where
        for attr in FRAME_ARRAYS:
            x, y = getattr(a, attr), getattr(b, attr)
            assert (x is None) == (y is None), (where, attr)
            if x is not None:
                assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y), (where, a.frame_id, attr)
        assert set(a.extra) == set(b.extra) and all(np.array_equal(a.extra[k], b.extra[k]) for k in a.extra), where


@pytest.mark.parametrize("pcap,jsons,_", CAPTURES, ids=IDS)
def test_native_scatter_gives_the_frames_of_numpy(pcap, jsons, _, monkeypatch):
    got, decoders = decode_frames(pcap, jsons)
    with monkeypatch.context() as m:
        m.setattr(kernels, "native", None)
        want, twin_decoders = decode_frames(pcap, jsons)
    assert_same_frames(got, want, pcap)
    assert [d.stats for d in decoders.values()] == [d.stats for d in twin_decoders.values()]


def _push_all(md, batches):
    dec = OusterDecoder(md)
    frames = [fr for b in batches for fr in dec.push(b)]
    return frames + dec.finish(), dec.stats


@pytest.mark.parametrize("pcap,jsons", [(c[0], c[1]) for c in CAPTURES if c[0].split("/")[-1] in (
    "OS-1-64_1024x10_fw20.pcap", "OS-2-128-U1_v2.3.0_1024x10.pcap", "OS-0-128-U1_v2.3.0_1024x10.pcap")])
def test_native_scatter_on_shuffled_duplicated_and_lost_packets(pcap, jsons, monkeypatch):
    rng = np.random.default_rng(16)
    for md, batch in lidar_streams(pcap, jsons):
        n = len(batch)
        order = np.arange(n)
        for s in range(0, n, 7):  # neighbours swapped within windows of 7 packets
            rng.shuffle(order[s : s + 7])
        order = np.concatenate([order, rng.choice(n, n // 10)])  # a tenth duplicated, some of them late
        order = order[rng.random(order.size) > 0.05]  # and some lost
        cuts = np.unique(rng.integers(0, order.size, 12))
        batches = [batch.select(part) for part in np.split(order, cuts) if part.size]
        got, got_stats = _push_all(md, batches)
        with monkeypatch.context() as m:
            m.setattr(kernels, "native", None)
            want, want_stats = _push_all(md, batches)
        assert got_stats == want_stats and got_stats.duplicates + got_stats.late > 0
        assert any(fr.partial or not fr.column_valid.all() for fr in got)
        assert_same_frames(got, want, pcap)


def _check_scatter(profile, payload, h, c, mids, w):
    """ouster_scatter of ``payload`` (rows of at least the packet's columns) against ``read_pixel_field``."""
    n = len(payload)
    size = profile.packet_dtype(h, c).itemsize
    full = np.zeros((n, size), np.uint8)  # the packets whole and contiguous, for packet_view
    full[:, : payload.shape[1]] = payload
    outputs, targets = new_fields(profile, h, w)
    for t in targets:
        t.fill(0xA5)
    NATIVE.ouster_scatter(payload, *packet_layout(profile, h, c), h, mids.astype(np.int64), scatter_steps(profile), targets)
    words = packet_view(full, profile, h, c)["columns"]["pixels"]  # <u4[n, C, H, k]
    slots = (("RANGE", "REFLECTIVITY", "SIGNAL", "FLAGS"), ("RANGE2", "REFLECTIVITY2", "SIGNAL2", "FLAGS2"))
    names = set(profile.field_names)
    checked = 0
    for attr, i in (("range_mm", 0), ("reflectivity", 1), ("signal", 2), ("flags", 3)):
        for r, slot in enumerate(slots[: profile.returns]):
            if slot[i] in names:
                want = np.full((h, w), 0xA5, outputs[attr].dtype)
                want[:, mids.ravel()] = read_pixel_field(words, profile.field(slot[i])).reshape(n * c, h).T
                assert np.array_equal(outputs[attr][r], want), (attr, r)
                checked += 1
    for attr, field in [("near_ir", "NEAR_IR")] + [(n.lower(), n) for n in names if n.lower() in outputs and n != "NEAR_IR"
                                                   and not any(n in sl for sl in SLOT_FIELDS)]:
        if field in names:
            want = np.full((h, w), 0xA5, outputs[attr].dtype)
            want[:, mids.ravel()] = read_pixel_field(words, profile.field(field)).reshape(n * c, h).T
            assert np.array_equal(outputs[attr], want), attr
            checked += 1
    assert checked == len(targets)


@pytest.mark.parametrize("name", NATIVE_PROFILES)
@pytest.mark.parametrize("h,c", [(16, 16), (64, 8), (128, 16)])
def test_ouster_scatter_matches_the_packet_decoder_on_random_bytes(name, h, c):
    profile = PROFILES[name]
    rng = np.random.default_rng([h, c, len(name)])
    n, w = 5, 8 * c
    size = profile.packet_dtype(h, c).itemsize
    payload = rng.integers(0, 256, (n, size + 3), dtype=np.uint8)[:, 3:]  # rows apart by more than a packet
    mids = np.stack([rng.permutation(w)[:c] for _ in range(n - 1)] + [np.arange(c) + 2 * c])  # scattered, then consecutive
    _check_scatter(profile, payload, h, c, mids, w)


def _packets_ending_at_a_guard_page(rows: np.ndarray) -> np.ndarray:
    """A copy of ``rows`` whose last byte is the last of a mapping followed by a page that faults when read."""
    import ctypes
    import mmap

    size = rows.nbytes
    pages = -(-size // mmap.PAGESIZE) + 1
    buf = mmap.mmap(-1, pages * mmap.PAGESIZE)
    arr = np.frombuffer(buf, np.uint8)
    guard = arr[(pages - 1) * mmap.PAGESIZE :]
    libc = ctypes.CDLL(None, use_errno=True)
    libc.mprotect.argtypes = (ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int)
    assert libc.mprotect(guard.ctypes.data, mmap.PAGESIZE, 0) == 0  # PROT_NONE
    out = arr[(pages - 1) * mmap.PAGESIZE - size : (pages - 1) * mmap.PAGESIZE].reshape(rows.shape)
    out[...] = rows
    return out


@pytest.mark.skipif(not hasattr(__import__("os"), "uname") or __import__("os").uname().sysname != "Linux", reason="mprotect via ctypes")
@pytest.mark.parametrize("name", NATIVE_PROFILES)
@pytest.mark.parametrize("h", [1, 2, 3, 5, 7, 13, 17, 30, 33])
def test_ouster_scatter_reads_nothing_past_the_last_column(name, h):
    """Packets cut right after their last column (no footer), the last one ending at a page that faults: the
    16-byte loads of the vector path must stop before the end (H not a multiple of the rows per load or block)."""
    profile = PROFILES[name]
    c = 16
    rng = np.random.default_rng([h, len(name), 7])
    columns_at, column_bytes, _, _ = packet_layout(profile, h, c)
    end = columns_at + c * column_bytes
    n, w = 9, 16 * 12
    rows = rng.integers(0, 256, (n, end), dtype=np.uint8)
    payload = _packets_ending_at_a_guard_page(rows)
    mids = np.arange(n * c).reshape(n, c)
    _check_scatter(profile, payload, h, c, mids, w)
    strided = _packets_ending_at_a_guard_page(np.pad(rows, ((0, 0), (0, 5))))[:, :end]  # rows farther apart than L
    _check_scatter(profile, strided, h, c, mids[::-1].copy(), w)  # packets in reverse order, each consecutive


@pytest.mark.parametrize("name", NATIVE_PROFILES)
def test_ouster_scatter_keeps_the_last_packet_of_a_column_received_twice(name):
    """Columns repeated within and across groups of 4 packets, packets out of order, one packet's columns
    reversed, groups of side-by-side packets (written field by field across the group) with and without a
    gap: the last packet written wins, as in the NumPy twin."""
    profile = PROFILES[name]
    h, c, w = 20, 16, 96
    rng = np.random.default_rng(len(name))
    size = profile.packet_dtype(h, c).itemsize
    starts = [16, 16, 0, None, 80, 0, 17, 16, 0, 16, 32, 48, 32, 48, 64, 80, 0, 16, 48, 64, 48]
    mids = np.array([range(s, s + c) if s is not None else range(31, 15, -1) for s in starts])
    payload = rng.integers(0, 256, (len(mids), size), dtype=np.uint8)
    _check_scatter(profile, payload, h, c, mids, w)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.uint32])
def test_ouster_scatter_applies_any_step_as_the_twin_does(dtype):
    """Steps beyond those of today's profiles (every combination of shift, mask and up-shift the kernel
    specialises, 16-bit values with the top bit set) against the twin's ``extract`` on word planes."""
    rng = np.random.default_rng(np.dtype(dtype).itemsize)
    h, c, n = 12, 16, 4
    payload = rng.integers(0, 256, (n, c * h * 4), dtype=np.uint8)
    mids = np.arange(n * c, dtype=np.int64).reshape(n, c)
    planes = payload.view("<u4").reshape(n, c, h).transpose(2, 0, 1).reshape(1, h, n * c)
    bits = 8 * np.dtype(dtype).itemsize
    steps = [(0, off, mask, up) for off in (0, 1, 15, 16, 17, 24, 31) for mask in (0, 1, 0x7F, 0xFF, 0x7FFF, 0xFFFF, 0xFFFFF)
             for up in sorted({0, 1, 4, bits - 1}) if mask < 1 << bits]  # the twin's masks fit the type
    for i in range(0, len(steps), 16):
        chunk = np.array(steps[i : i + 16], np.int64)
        targets = [np.zeros((h, n * c), dtype) for _ in chunk]
        NATIVE.ouster_scatter(payload, 0, h * 4, 0, 4, h, mids, chunk, targets)
        for step, got in zip(chunk.tolist(), targets):
            assert np.array_equal(got, extract(planes, tuple(step), np.empty((h, n * c), dtype))), step


def test_ouster_scatter_refuses_what_does_not_fit_and_writes_nothing():
    profile = PROFILES["RNG19_RFL8_SIG16_NIR16"]
    h, c, w = 16, 16, 64
    payload = np.random.default_rng(0).integers(0, 256, (2, profile.packet_dtype(h, c).itemsize), dtype=np.uint8)
    layout, steps = packet_layout(profile, h, c), scatter_steps(profile)
    mids = np.arange(2 * c, dtype=np.int64).reshape(2, c)
    _, targets = new_fields(profile, h, w)
    for t in targets:
        t.fill(0)
    bad_mids = mids.copy()
    bad_mids[1, 5] = w  # one column past the frame
    cases = [
        (payload, *layout, h, bad_mids, steps, targets),
        (payload[:, : layout[0] + c * layout[1] - 1], *layout, h, mids, steps, targets),  # the last column cut
        (payload, *layout, h + 1, mids, steps, targets),  # more pixels than the column holds
        (payload, *layout, h, mids, steps, targets[:-1]),  # one output missing
        (payload, *layout, h, mids, steps, targets[:-1] + [np.zeros((h, w), np.int64)]),  # 8-byte items
        (payload, *layout, h, mids, steps, targets[:-1] + [np.zeros((h + 1, w), np.uint8)]),  # another shape
        (payload, *layout, h, mids, steps + np.array([[9, 0, 0, 0]]), targets),  # a word beyond the pixel
        (payload, *layout, h, mids.astype(np.float64), steps, targets),
    ]
    for i, args in enumerate(cases):
        with pytest.raises(ValueError, match="ouster_scatter"):
            NATIVE.ouster_scatter(*args)
        assert not any(t.any() for t in targets), i


@pytest.mark.parametrize("name", sorted(set(PROFILES) - set(NATIVE_PROFILES)))
def test_ouster_scatter_refuses_pixels_wider_than_its_scratch(name):
    """The 20-byte profiles are refused with a ValueError before anything is written (the decoder gives them
    to the NumPy twin, whose frames test_frames_of_every_profile_native_and_numpy compares)."""
    profile = PROFILES[name]
    h, c, w = 4, 16, 32
    payload = np.zeros((1, profile.packet_dtype(h, c).itemsize), np.uint8)
    _, targets = new_fields(profile, h, w)
    with pytest.raises(ValueError):
        NATIVE.ouster_scatter(payload, *packet_layout(profile, h, c), h, np.arange(c, dtype=np.int64)[None],
                              scatter_steps(profile), targets)
