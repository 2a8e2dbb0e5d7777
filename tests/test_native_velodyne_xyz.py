"""The compiled VLP-16 XYZ kernel (``_lidarpkt_native.velodyne_xyz``) gives the bytes of its NumPy twin.

Real captures (VeloView's, rust-lidar-utils', the canned strongest/last/dual ones) through the stock
calibration, and the same frames through geometries whose per-row distance corrections, vertical
offsets and rotation corrections are all non-zero (the branches the stock calibration skips);
bad azimuths and arrays are refused as NumPy's lookup refuses them.
"""

from __future__ import annotations

import numpy as np
import pytest

import lidarpkt
from lidarpkt import kernels
from lidarpkt.velodyne.geometry import VelodyneGeometry, _trig_tables

from conftest import REPO_ROOT, external

NATIVE = kernels.native
pytestmark = pytest.mark.skipif(NATIVE is None, reason="the C extension is not built (LIDARPKT_NATIVE=0 or no compiler)")

CAPTURES = ["veloview/vlp-16-test-90deg-1-50-frames", "rust-lidar-utils/velodyne_vlp16", "canned/vlp16-dual",
            "canned/vlp16-last", "canned/vlp16-strongest"]


def _path(name: str):
    if name.startswith("canned/"):
        return REPO_ROOT / "fixtures" / "canned" / f"{name[7:]}.pcap"
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
