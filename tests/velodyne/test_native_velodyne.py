"""The compiled VLP-16 kernels give the bytes of their NumPy twins: ``velodyne_columns`` (packets into
range-image columns), ``velodyne_xyz`` and ``dual_mark`` (the dual-return mark of
:func:`lidarpkt.core.dual.second_strongest_mark`).

Columns: every frame of real strongest, last and dual captures decoded with and without the
extension, array for array; views and copies of the packet records, any row order, bad shapes.

XYZ: real captures (VeloView's, rust-lidar-utils', the canned strongest/last/dual ones) through the stock
calibration, and the same frames through geometries whose per-row distance corrections, vertical
offsets and rotation corrections are all non-zero (the branches the stock calibration skips);
bad azimuths and arrays are refused as NumPy's lookup refuses them.
"""

from __future__ import annotations

import numpy as np
import pytest

import lidarpkt
from lidarpkt.core import kernels
from lidarpkt.vendors.velodyne.geometry import VelodyneGeometry, _trig_tables

from conftest import REPO_ROOT, external

NATIVE = kernels.native
pytestmark = pytest.mark.skipif(NATIVE is None, reason="the C extension is not built (LIDARPKT_NATIVE=0 or no compiler)")

CAPTURES = ["veloview/vlp-16-test-90deg-1-50-frames", "rust-lidar-utils/velodyne_vlp16", "canned/vlp16-dual",
            "canned/vlp16-last", "canned/vlp16-strongest"]


def _path(name: str):
    if name.startswith("canned/"):
        return REPO_ROOT / "lidarpkt" / "fixtures" / "canned" / f"{name[7:]}.pcap"
    return external(f"{name}.pcap")


def _both(geometry, frame, monkeypatch) -> tuple[np.ndarray, np.ndarray]:
    native = geometry.xyz(frame)
    with monkeypatch.context() as m:
        m.setattr(kernels, "native", None)
        twin = geometry.xyz(frame)
    return native, twin


def _corrected(seed: int) -> VelodyneGeometry:
    """The stock geometry with every per-row correction set (as a calibration file would)."""
    g = VelodyneGeometry()
    rng = np.random.default_rng(seed)
    omega = np.arctan2(g._k_z[:, 0], g._k_xy[:, 0])
    g._dist_correction = rng.uniform(-0.05, 0.05, (16, 1))
    g._dc_xy = g._dist_correction * np.cos(omega)[:, None]
    g._dc_z = g._dist_correction * np.sin(omega)[:, None]
    g._vert_offset = rng.uniform(-0.02, 0.02, (16, 1))
    g._per_row = True
    g._cos, g._neg_sin = _trig_tables(tuple(rng.uniform(-0.05, 0.05, 16).tolist()))
    g._coef = np.ascontiguousarray(np.stack([g._k_xy[:, 0], g._k_z[:, 0], g._dc_xy[:, 0], g._dc_z[:, 0],
                                             g._vert_offset[:, 0]]))
    g._kernel_coef = g._coef  # a table per row: the kernel takes the five coefficients
    g._has_dist = g._has_voff = True
    return g


@pytest.mark.parametrize("name", CAPTURES)
def test_native_xyz_equals_numpy_on_real_frames(name, monkeypatch):
    frames = list(lidarpkt.open(_path(name)))
    assert frames
    corrected = _corrected(len(name))
    for frame in frames:
        for geometry in (frame.sensor.geometry, corrected):
            native, twin = _both(geometry, frame, monkeypatch)
            assert native.shape == twin.shape == frame.range_mm.shape + (3,)
            assert native.tobytes() == twin.tobytes()  # bit for bit, signs of zeros included
    assert np.count_nonzero(frames[0].xyz()) > 0


def test_native_xyz_every_azimuth_and_range_edge(monkeypatch):
    """All 36000 azimuths, zero and extreme ranges, two return slots."""
    w = 36000 // 16 + 1
    az = (np.arange(16 * w) % 36000).astype(np.uint16).reshape(16, w)
    rng = np.random.default_rng(3).integers(0, 2**32, (2, 16, w), dtype=np.uint64).astype(np.uint32)
    rng[:, :, ::7] = 0
    rng[0, 0, :4] = [1, 2**32 - 1, 0, 65535 * 2]
    frame = lidarpkt.Frame.__new__(lidarpkt.Frame)
    frame.range_mm, frame.extra = rng, {"azimuth_cdeg": az}
    for geometry in (VelodyneGeometry(), _corrected(7)):
        native, twin = _both(geometry, frame, monkeypatch)
        assert native.tobytes() == twin.tobytes()
    # views as frames hold them (rows apart, each contiguous: taken as they are), rows reversed, and a
    # last axis that is not contiguous (copied first)
    for r, a in ((rng[..., 5:-3], az[:, 5:-3]), (rng[:, ::-1], az[::-1]), (rng[..., ::2], az[:, ::2]),
                 (rng.astype(np.int64)[..., 1:], az.astype(np.int32)[:, 1:])):
        frame.range_mm, frame.extra = r, {"azimuth_cdeg": a}
        native, twin = _both(_corrected(8), frame, monkeypatch)
        assert native.shape == r.shape + (3,) and native.tobytes() == twin.tobytes()


def test_native_xyz_refuses_bad_input():
    g = VelodyneGeometry()
    rng = np.ones((1, 16, 4), np.uint32)
    out = np.empty((1, 16, 4, 3))
    az = np.zeros((16, 4), np.uint16)
    args = [rng, az, g._cos, g._neg_sin, g._coef, False, False, out]
    assert NATIVE.velodyne_xyz(*args) is None and np.all(out[..., 2] != 0)
    bad_az = az.copy()
    bad_az[3, 2] = 36000
    with pytest.raises(IndexError, match="36000"):
        NATIVE.velodyne_xyz(rng, bad_az, *args[2:])
    with pytest.raises(ValueError):
        NATIVE.velodyne_xyz(rng.astype(np.uint16), *args[1:])
    with pytest.raises(ValueError):
        NATIVE.velodyne_xyz(rng, az, g._cos, g._neg_sin, g._coef, False, False, np.empty((1, 16, 5, 3)))
    with pytest.raises(ValueError):
        NATIVE.velodyne_xyz(rng, az[:, :2], *args[2:])
    with pytest.raises(ValueError, match="rows contiguous"):
        NATIVE.velodyne_xyz(np.ones((1, 16, 8), np.uint32)[..., ::2], *args[1:])


FRAME_ARRAYS = ("range_mm", "reflectivity", "column_valid", "column_timestamp_ns", "azimuth_deg",
                "pixel_time_offset_ns")


@pytest.mark.parametrize("name", CAPTURES + ["rust-lidar-utils/velodyne_example"])
def test_native_columns_give_the_frames_of_numpy(name, monkeypatch):
    native = list(lidarpkt.open(_path(name), read_ahead=False))
    with monkeypatch.context() as m:
        m.setattr(kernels, "native", None)
        twin = list(lidarpkt.open(_path(name), read_ahead=False))
    assert len(native) == len(twin) > 0
    for a, b in zip(native, twin):
        for attr in FRAME_ARRAYS:
            x, y = getattr(a, attr), getattr(b, attr)
            assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y), (name, attr)
        assert set(a.extra) == set(b.extra) and all(np.array_equal(a.extra[k], b.extra[k]) for k in a.extra)


@pytest.mark.parametrize("slots", [1, 2])
def test_native_columns_views_copies_and_row_orders(slots, monkeypatch):
    from lidarpkt.vendors.velodyne.decode import column_pixels, decode_packets
    from lidarpkt.vendors.velodyne.timing import firing_dt_s, packet_rate_cdeg_s_vlp16

    payload = np.random.default_rng(slots).integers(0, 256, (37, 1206), dtype=np.uint8)
    raw = decode_packets(payload)
    for azimuths in ("any", "valid"):  # any 16 bits (the twin's general path), then block azimuths below 36000
        if azimuths == "valid":
            raw.azimuth_cdeg %= 36000
        rate = packet_rate_cdeg_s_vlp16(raw.azimuth_cdeg, slots == 2)
        dt = firing_dt_s(slots == 2)[::slots]
        for rows in (np.arange(16), np.random.default_rng(9).permutation(16)):
            for r in (raw, raw.select(np.arange(36, -1, -1))):  # compact copies, and fancy-indexed copies reversed
                rr = rate if r is raw else rate[::-1]
                got = column_pixels(r, rr, dt, rows, slots)
                with monkeypatch.context() as m:
                    m.setattr(kernels, "native", None)
                    want = column_pixels(r, rr, dt, rows, slots)
                assert all(x.dtype == y.dtype and np.array_equal(x, y) for x, y in zip(got, want))
        view = decode_packets(payload, copy=False)  # strided views of the payload
        got = column_pixels(view, packet_rate_cdeg_s_vlp16(view.azimuth_cdeg, slots == 2), dt, np.arange(16), slots)
        with monkeypatch.context() as m:
            m.setattr(kernels, "native", None)
            want = column_pixels(view, packet_rate_cdeg_s_vlp16(view.azimuth_cdeg, slots == 2), dt, np.arange(16), slots)
        assert all(np.array_equal(x, y) for x, y in zip(got, want))
    w = 37 * 24 // slots
    rng, refl, az = np.empty((slots, 16, w), np.uint32), np.empty((slots, 16, w), np.uint8), np.empty((16, w), np.uint16)
    args = (raw.distance_2mm, raw.reflectivity, raw.azimuth_cdeg, rate, np.ascontiguousarray(dt))
    with pytest.raises(ValueError, match="laser"):
        NATIVE.velodyne_columns(*args, np.full(16, 16, np.int64), slots, rng, refl, az)
    with pytest.raises(ValueError, match="shapes"):
        NATIVE.velodyne_columns(*args, np.arange(16), slots, rng[:, :, 1:].copy(), refl, az)
    with pytest.raises(ValueError, match="shapes"):
        NATIVE.velodyne_columns(*args[:3], rate[1:].copy(), args[4], np.arange(16), slots, rng, refl, az)
    with pytest.raises(ValueError, match="slots"):
        NATIVE.velodyne_columns(*args, np.arange(16), 3, rng, refl, az)

def _marks(range_mm, reflectivity, monkeypatch):
    from lidarpkt.core.dual import second_strongest_mark

    got = second_strongest_mark(range_mm, reflectivity)
    with monkeypatch.context() as m:
        m.setattr(kernels, "native", None)
        want = second_strongest_mark(range_mm, reflectivity)
    return got, want


def test_native_dual_mark_equals_numpy(monkeypatch):
    """Random dual frames (one return twice, empty slots, different returns; ranges up to the kernel's exact
    bound and beyond it, where the twin serves), as whole arrays, column views, row views and other ranks;
    the real dual frames are compared in test_native_columns_give_the_frames_of_numpy."""
    gen = np.random.default_rng(5)
    for trial in range(40):
        n = int(gen.integers(1, 2500))
        top = (131_071, 4_194_303, 4_194_304, 2**32 - 1)[trial % 4]
        rng = gen.integers(0, top, (2, 16, n), dtype=np.int64, endpoint=True).astype(np.uint32)
        rng *= gen.integers(0, 2, (2, 16, n)).astype(np.uint32)  # empty slots
        rng[1] = np.where(gen.random((16, n)) < 0.4, rng[0], rng[1])  # one return sent twice
        refl = gen.integers(0, 256, (2, 16, n)).astype(np.uint8)
        lo = int(gen.integers(0, n))
        for r, f in ((rng, refl), (rng[..., lo:], refl[..., lo:]), (rng[:, ::3], refl[:, ::3]),
                     (rng[:, 4], refl[:, 4]), (rng.reshape(2, 4, 4, n), refl.reshape(2, 4, 4, n))):
            got, want = _marks(r, f, monkeypatch)
            assert got.dtype == want.dtype == bool and got.shape == want.shape == r.shape[1:]
            assert np.array_equal(got, want), (trial, r.shape)
    # the exact bound: products one apart near 255 * (2^22 - 1)^2
    r = np.array([[4_194_303, 4_194_302], [4_194_302, 4_194_303]], np.uint32).reshape(2, 1, 2)
    f = np.full((2, 1, 2), 255, np.uint8)
    got, want = _marks(r, f, monkeypatch)
    assert np.array_equal(got, want) and got.tolist() == [[False, True]]  # the nearer return's slot is stronger


def test_native_dual_mark_refuses_bad_input():
    out = np.empty((16, 10), bool)
    rng, refl = np.ones((2, 16, 10), np.uint32), np.ones((2, 16, 10), np.uint8)
    assert NATIVE.dual_mark(rng, refl, out) is True
    assert NATIVE.dual_mark(rng * np.uint32(1 << 22), refl, out) is False  # beyond its exact products
    with pytest.raises(ValueError, match="uint32"):
        NATIVE.dual_mark(rng.astype(np.float32), refl, out)
    with pytest.raises(ValueError, match="4 bytes"):
        NATIVE.dual_mark(rng.astype(np.int16), refl, out)
    with pytest.raises(ValueError, match=r"\[2, H, W\]"):
        NATIVE.dual_mark(rng, refl, out[:, :9].copy())
    with pytest.raises(ValueError, match=r"\[2, H, W\]"):
        NATIVE.dual_mark(rng[:1], refl[:1], out)
