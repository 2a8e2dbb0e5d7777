"""Ouster XYZ from the manual's formula, by hand, on single pixels (ouster-sdk is compared in the crosscheck tests)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from conftest import external
from lidarpkt.core.sequence import FrameStack
from lidarpkt.vendors.ouster import OusterDecoder, encode_frame, load_metadata
from lidarpkt.core.packet import PacketBatch
from test_ouster_cases import decode_frames

REDUCED = "ouster-sdk/OS-1-64_sensor_config_reduced.json"


def _frame_with(md, row, col, range_mm):
    frames, _ = decode_frames("ouster-sdk/OS-1-64_1024x10_fw20.pcap", [REDUCED])
    f = frames[0]
    f.range_mm[:] = 0
    f.range_mm[0, row, col] = range_mm
    return f


@pytest.mark.parametrize("col,enc_deg", [(0, 360.0), (256, 270.0), (512, 180.0), (100, 360.0 * (1 - 100 / 1024))])
@pytest.mark.parametrize("row", [0, 31, 63])
def test_single_pixel_against_the_formula(row, col, enc_deg):
    md = load_metadata(external(REDUCED))
    r = 10_000
    f = _frame_with(md, row, col, r)
    got = f.xyz()
    assert np.count_nonzero(got) == 3  # only the pixel with a return
    phi = math.radians(md.beam_altitude_deg[row])
    theta_e = math.radians(enc_deg)
    theta = theta_e - math.radians(md.beam_azimuth_deg[row])
    n = 12.163  # documented default: lidar origin to beam origin, mm
    x = r * math.cos(theta) * math.cos(phi) + n * math.cos(theta_e) - n * math.cos(theta) * math.cos(phi)
    y = r * math.sin(theta) * math.cos(phi) + n * math.sin(theta_e) - n * math.sin(theta) * math.cos(phi)
    z = r * math.sin(phi) - n * math.sin(phi)
    # lidar → sensor frame: diag(-1, -1, 1), z + 36.18 mm (documented default); mm → m
    want = np.array([-x, -y, z + 36.18]) / 1000
    assert np.max(np.abs(got[0, row, col] - want)) < 1e-9
    # the azimuth reported for the column is the encoder angle
    assert f.azimuth_deg[col] == pytest.approx(enc_deg % 360.0)


def test_xyz_shape_and_zero_where_no_return():
    frames, _ = decode_frames("ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.pcap", ["ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.json"])
    f = frames[0]
    xyz = f.xyz()
    assert xyz.shape == (2, 32, 1024, 3) and xyz.dtype == np.float64
    assert np.array_equal(np.any(xyz != 0, axis=-1), f.range_mm > 0)
    # distance from the sensor origin grows with range (beam origin offsets are cm-scale)
    far = f.range_mm[0] > 5000
    d = np.linalg.norm(xyz[0][far] - [0, 0, 0.03618], axis=-1)
    assert np.all(np.abs(d - f.range_mm[0][far] / 1000) < 0.05)


def test_frame_stack_of_ouster_frames():
    """Ouster frames are already on their column grid: stacking keeps every pixel in place."""
    md = load_metadata(external("ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.json"))
    frames, _ = decode_frames("ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.pcap", ["ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.json"])
    f = frames[0]
    assert f.on_grid() is f
    # a second frame re-encoded from the first with the next frame id
    dec = OusterDecoder(md)
    again = dec.push(PacketBatch.from_payloads(encode_frame(replace(f, frame_id=f.frame_id + 1), md))) + dec.finish()
    stack = FrameStack.from_frames([frames[0], *again])
    assert stack.range_mm.shape == (2, 2, 32, 1024)
    assert np.array_equal(stack.range_mm[0], stack.range_mm[1])
    assert stack.frame_id.tolist() == [1453, 1454]


def test_lookup_tables_are_shared_by_opens_of_one_calibration():
    """Each lidarpkt.open makes a new geometry; the tables of one calibration are made once, read-only,
    and a calibration that differs in one beam angle gets its own."""
    import dataclasses

    import lidarpkt
    from lidarpkt.vendors.ouster.geometry import OusterGeometry

    pcap, meta = external("ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.pcap"), external("ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.json")
    a, b = (next(iter(lidarpkt.open(pcap, metadata=meta))).sensor.geometry for _ in range(2))
    assert a is not b and a.lut[0] is b.lut[0] and a._planes32[1] is b._planes32[1]
    assert not a.lut[0].flags.writeable and not a._planes[0].flags.writeable
    md = a.metadata
    altitude = np.array(md.beam_altitude_deg, np.float64)
    altitude[3] += 0.01
    other = OusterGeometry(dataclasses.replace(md, beam_altitude_deg=altitude))
    assert other.lut[0] is not a.lut[0] and not np.array_equal(other.lut[0], a.lut[0])
