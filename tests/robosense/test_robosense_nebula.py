"""The RoboSense bag against nebula's own decoded clouds of four of its messages (the .pcd files beside it).

nebula's test (``robosense_ros_decoder_test_helios16P.cpp`` at the fixture's commit) decodes the bag
with its Helios 16P decoder: the CSV's angles, returns between 0.2 and 200 m (compared in float32:
``raw · 0.0025f``), the cloud of each rotation cut where a block's azimuth passes 0°, points in block
order, slot by slot. Each cloud is one of lidarpkt's frames of the bag: the same returns one for one.

What the packets are. The bag is labelled Helios 16P, and nebula reads slot s of a block as laser
s % 16 (the 16P manual: two firing sequences of 16 lasers). The packets say otherwise, and lidarpkt
follows them: header byte 30 is 0x06, "RS-Helios-5515" in the Helios-16P manual's own table of LiDAR
models (0x07 would be the 16P); the DIFOP carries 32 calibrated vertical and horizontal angles (the
lower 16 from -9.94° to -53.70°, a 5515's); and each slot's ranges agree with the same slot of the
next block (0.2° on) far more often than with the slot 16 away in the same block, which on a 16P
would be the same laser 0.1° on (:func:`test_the_capture_is_a_32_laser_helios`). So lidarpkt decodes
32 rows, RS-Helios. Slots 0-15 then are the lasers nebula names; for slots 16-31 nebula's points lie
at the upper lasers' angles, and only the forced 16P reading (``model="RS-Helios-16P"``) is compared
with its XYZ.

Where the references differ. lidarpkt fires the 32 slots of a block 1.73 µs apart, rs_driver's
Helios and Helios 16P table since March 2024 (:mod:`lidarpkt.vendors.robosense.timing`); nebula's
decoder has the older 16P table (second sequence 55.56 µs after the first, a block 111 µs), which
cannot hold for these packets: their blocks come 55.56 µs apart. A slot's azimuth is the block's
plus the step to the next block times its share of the period, in whole 0.01° (as both decoders
compute it), so the two differ by at most ``step · |share − nebula's share|`` plus the 0.01° of
truncation; nebula also reads the CSV's 8.90° as 8.89° (float truncation). Where lidarpkt's angles
equal nebula's, XYZ agree within 1 mm; elsewhere within the distance times the angle difference.
"""

from __future__ import annotations

import numpy as np
import pytest

from robosense_bag import CSV, PCD_NAMES, all_packets, decode, messages, pcd
from conftest import external
from lidarpkt.vendors.robosense import detect_model, model_named, timing

UNIT_M = np.float32(0.0025)
NEBULA_RANGE_M = (np.float32(0.2), np.float32(200.0))
# nebula's Helios 16P firing times (µs after the block), and the block it divides by (2 × 55.56 µs)
NEBULA_FIRING_US = np.array([
    0.00, 3.15, 6.30, 9.45, 13.26, 17.08, 20.56, 23.71, 26.53, 27.77, 31.49, 32.73, 36.46, 38.94, 41.42, 43.91,
    55.56, 58.70, 61.85, 65.00, 68.82, 72.64, 76.12, 79.27, 82.08, 83.32, 87.05, 88.29, 92.01, 94.50, 96.98, 99.46],
    np.float32)
NEBULA_SHARE = NEBULA_FIRING_US / np.float32(2 * 55.56)
LIDARPKT_SHARE = np.asarray(timing.HELIOS, np.float32) / np.float32(55560)
STRONGEST = 3  # nebula's ReturnType::STRONGEST


@pytest.fixture(scope="module")
def detected():
    return decode()[0]


@pytest.fixture(scope="module")
def as_16p():
    return decode(model="RS-Helios-16P", calibration=str(external(CSV)))[0]


def nebula_points(frame) -> dict:
    """The frame's slots in nebula's order (block by block, slots 0-31), kept where nebula keeps them:
    each slot's row and column, from the manuals' layouts (32 lasers: slot s is laser s, a block a column;
    16P: slot s is laser s % 16 of firing s // 16, two columns a block)."""
    rows_of_laser = np.argsort(np.asarray(frame.sensor.metadata["row_laser"]))
    slot = np.arange(32)
    if frame.shape[1] == 32:
        laser, column = slot, np.zeros(32, int)
        blocks = frame.shape[2]
        col = np.arange(blocks)[:, None] + column[None, :]
    else:
        laser, column = slot % 16, slot // 16
        blocks = frame.shape[2] // 2
        col = 2 * np.arange(blocks)[:, None] + column[None, :]
    row = np.broadcast_to(rows_of_laser[laser], (blocks, 32))
    raw = (frame.range_mm[0][row, col].astype(np.int64) * 1000) // 2500
    metres = raw.astype(np.float32) * UNIT_M
    keep = (metres >= NEBULA_RANGE_M[0]) & (metres <= NEBULA_RANGE_M[1])
    return {"row": row[keep], "col": col[keep], "slot": np.broadcast_to(slot, (blocks, 32))[keep],
            "raw": raw[keep], "reflectivity": frame.reflectivity[0][row, col][keep],
            "xyz": frame.xyz()[0][row, col][keep]}


def angles_cdeg(frame, pts) -> tuple[np.ndarray, np.ndarray]:
    """lidarpkt's azimuth (firing azimuth plus the laser's offset) and elevation of the points, 0.01°."""
    alpha = frame.extra["azimuth_cdeg"][pts["row"], pts["col"]].astype(np.int64)
    offset = np.rint(frame.sensor.beam_azimuth_deg[pts["row"]] * 100).astype(np.int64)
    elevation = np.rint(frame.sensor.beam_altitude_deg[pts["row"]] * 100).astype(np.int64)
    return alpha + offset, elevation


@pytest.mark.parametrize("k", range(4))
@pytest.mark.parametrize("reading", ["detected", "as_16p"])
def test_each_cloud_is_a_frame_with_the_same_returns(request, reading, k):
    frame = request.getfixturevalue(reading)[k]
    ref = pcd(PCD_NAMES[k])
    pts = nebula_points(frame)
    assert len(pts["raw"]) == len(ref)
    np.testing.assert_allclose(pts["raw"] * 0.0025, ref["distance"], atol=1e-6)
    assert np.array_equal(pts["reflectivity"], ref["intensity"])
    assert set(np.unique(ref["return_type"])) == {STRONGEST}
    if reading == "as_16p":  # nebula's channel: rank of the laser's elevation, 0 the lowest; our row 0 the highest
        assert np.array_equal(15 - pts["row"], ref["channel"])
    else:
        low = pts["slot"] < 16  # the same lasers: the upper 16 of 32, rows 0-15 here
        assert np.array_equal(15 - pts["row"][low], ref["channel"][low])
        # nebula folds slot s + 16 onto laser s: its channel of a slot 16-31 is the one of slot s - 16
        rank16 = dict(zip(pts["slot"][low].tolist(), ref["channel"][low].tolist()))
        assert all(rank16[s - 16] == c for s, c in zip(pts["slot"][~low].tolist(), ref["channel"][~low].tolist())
                   if s - 16 in rank16)


def compared(frames, reading):
    """For each cloud: nebula's points, ours in its order, and both angles (0.01°), of the slots both
    read as the same lasers (all of them in the 16P reading, slots 0-15 in the detected one)."""
    for k in range(4):
        frame, ref = frames[k], pcd(PCD_NAMES[k])
        pts = nebula_points(frame)
        theta, elevation = angles_cdeg(frame, pts)
        keep = np.ones(len(theta), bool) if reading == "as_16p" else pts["slot"] < 16
        ref = ref[keep]
        d_theta = (theta[keep] - ref["azimuth"].astype(np.int64) + 18000) % 36000 - 18000
        d_el = elevation[keep] - ref["elevation"].astype(np.int64)
        yield ref, {name: v[keep] for name, v in pts.items()}, d_theta, d_el


@pytest.mark.parametrize("reading", ["detected", "as_16p"])
def test_angles_differ_by_at_most_what_the_firing_tables_do(request, reading):
    for ref, pts, d_theta, d_el in compared(request.getfixturevalue(reading), reading):
        slot = pts["slot"]
        # the step to the next block is 19-21 (0.01°, 10 Hz); its share of each slot in both tables
        bound = np.floor(21 * np.abs(LIDARPKT_SHARE[slot] - NEBULA_SHARE[slot])) + 1
        assert np.all(np.abs(d_theta) <= bound)
        assert np.count_nonzero(d_theta == 0) > 0.15 * len(d_theta)
        assert set(np.unique(d_el)) <= {0, 1}
        # only the laser whose CSV value 8.90 nebula reads as 8.89
        assert np.all(ref["elevation"][d_el == 1] == 889)


@pytest.mark.parametrize("reading", ["detected", "as_16p"])
def test_xyz_within_1mm_where_the_angles_agree_else_within_the_angle_difference(request, reading):
    for ref, pts, d_theta, d_el in compared(request.getfixturevalue(reading), reading):
        err = np.linalg.norm(pts["xyz"] - np.stack([ref["x"], ref["y"], ref["z"]], axis=1), axis=1)
        same = (d_theta == 0) & (d_el == 0)
        assert same.sum() > 0.15 * len(same)
        assert err[same].max() < 0.001
        angle_rad = np.radians((np.abs(d_theta) + np.abs(d_el)) / 100.0)
        assert np.all(err <= ref["distance"] * angle_rad + 0.001)


def test_frames_name_the_model_return_mode_and_calibration(detected, as_16p):
    assert [f.shape for f in detected[1:5]] == [(1, 32, 1800)] * 4
    assert [f.partial for f in detected] == [True, False, False, False, False, True]
    for f in detected:
        info = f.sensor
        assert (info.vendor, info.model, info.rows) == ("robosense", "RS-Helios", 32)
        assert f.return_labels == ("strongest",) and info.return_mode == "strongest"
        assert info.metadata["calibration_source"] == "DIFOP" and info.frequency_hz == 10.0
        assert info.serial == "2410bac9d50b"
        assert np.all(np.diff(info.beam_altitude_deg) <= 0)  # row 0 the highest
    assert {f.sensor.model for f in as_16p} == {"RS-Helios-16P"} and as_16p[1].shape == (1, 16, 3600)


def test_the_difop_says_strongest_return_though_nebulas_test_says_dual():
    payload, _ = all_packets()
    difop = payload[np.all(payload[:, :8] == np.frombuffer(bytes.fromhex("a5ff005a11115555"), np.uint8), axis=1)]
    assert len(difop) == 1 and difop[0, 300] == 0x04  # Helios return-mode byte: 0x04 strongest, 0x00 dual
    msgs = messages()
    assert [int(m.is_difop.sum()) for m in msgs] == [0, 0, 0, 1, 0] and len(payload) == 751


def test_the_capture_is_a_32_laser_helios():
    payload, _ = all_packets()
    msop = payload[payload[:, 0] == 0x55]
    difop = payload[payload[:, 0] == 0xA5][0]
    # the header: LiDAR type 0x06 at byte 30 (RS-Helios; "RS-Helios-5515" in the 16P manual's table), no model
    assert set(msop[:, 30]) == {0x06} and set(msop[:, 31]) == {0} and set(msop[:, 32]) == {0}
    # the DIFOP: 32 calibrated vertical angles, the lower 16 a 5515's (-9.94° to -53.70°)
    angles = difop[468:564].reshape(32, 3).astype(np.int64)
    vertical = np.where(angles[:, 0] == 1, -1, 1) * (angles[:, 1] * 256 + angles[:, 2])
    assert vertical[16] == -994 and vertical[31] == -5370 and np.all(vertical[16:] < vertical[15])
    # the returns: slot j follows slot j of the next block, not slot j + 16 of its own (a 16P's same laser)
    blocks = msop[:, 42:1242].reshape(-1, 12, 100)
    distance = (blocks[:, :, 4:].reshape(-1, 12, 32, 3)[..., 0].astype(np.int64) << 8) | \
        blocks[:, :, 4:].reshape(-1, 12, 32, 3)[..., 1]

    def agree(a, b):
        both = (a > 0) & (b > 0)
        return np.count_nonzero((np.abs(a - b) * 50 <= np.maximum(a, b)) & both) / np.count_nonzero(both)

    for j in range(16):
        next_block = agree(distance[:, :-1, j], distance[:, 1:, j])
        same_block = agree(distance[:, :, j], distance[:, :, j + 16])
        assert next_block > 0.3 and same_block < 0.11 and next_block > 3 * same_block
    # the floor: the farthest returns of lasers 23-31 lie at one height with the 32 DIFOP angles only
    metres = distance.reshape(-1, 32) * 0.0025
    far = np.array([np.percentile(metres[:, s][metres[:, s] > 0], 90) for s in range(23, 32)])
    z32 = far * np.sin(np.radians(vertical[23:32] / 100.0))
    z16 = far * np.sin(np.radians(vertical[np.arange(23, 32) % 16] / 100.0))
    assert np.ptp(z32) < 0.03 and np.ptp(z16) > 0.1 and -0.72 < z32.mean() < -0.64
    assert detect_model(msop).name == "RS-Helios"
    assert model_named("RobosenseHelios16P").name == "RS-Helios-16P"


def test_range_mm_is_the_distance_rounded_and_xyz_uses_the_exact_one(detected):
    frame = detected[1]
    mm = frame.range_mm[frame.range_mm > 0].astype(np.int64)
    # 2.5 mm units: an odd raw value is a half millimetre, rounded up; the exact value comes back from it
    exact_m = frame.sensor.geometry.distance_m(mm)
    raw = np.rint(exact_m / 0.0025).astype(np.int64)
    assert np.allclose(raw * 0.0025, exact_m, rtol=0, atol=1e-12)
    assert np.array_equal((raw * 2500 + 500) // 1000, mm)
    assert np.any(raw % 2 == 1) and np.any(raw % 2 == 0)
    xyz = frame.xyz()[0]
    hit = frame.range_mm[0] > 0
    lens = np.stack([0.03498 * np.cos(np.radians(frame.extra["azimuth_cdeg"] / 100.0)),
                     -0.03498 * np.sin(np.radians(frame.extra["azimuth_cdeg"] / 100.0))], axis=-1)
    # the beam starts at the lens centre: |xy - lens| is the horizontal distance of the exact range
    horizontal = np.linalg.norm(xyz[..., :2] - lens, axis=-1)[hit]
    elevation = np.radians(frame.sensor.beam_altitude_deg)[:, None].repeat(frame.shape[2], 1)[hit]
    np.testing.assert_allclose(horizontal, frame.sensor.geometry.distance_m(frame.range_mm[0][hit]) * np.cos(elevation),
                               atol=1e-9)
