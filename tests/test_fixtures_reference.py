"""Deeper checks of the generated captures against things the generator does not share code with:
the reference decoders' geometry (the scene must be where the packets say it is), the full-length
captures, the jittered captures, and the UDP framing checksums.
"""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from lidarpkt import fixtures
import lidarpkt
from lidarpkt.fixtures import output

from test_fixtures import decoded, ipv4_udp_records, report_of  # noqa: E402 (tests dir is on sys.path)

# The courtyard of fixtures.scene, in the world frame (x forward, y left, z up, origin at the lidar):
FRONT_WALL_X_M = 25.0
SENSOR_HEIGHT_M = 1.2


def _front_wall_and_ground(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> None:
    """Points in world coordinates: the ground is the plane z = -1.2 m and the front wall the plane
    x = 25 m (where no named object stands in front of it)."""
    r_h = np.hypot(x, y)
    az = np.degrees(np.arctan2(y, x))
    ground = (z < -0.6) & (r_h < 15.0) & (r_h > 0.5)
    assert ground.sum() > 500
    assert abs(np.median(z[ground]) + SENSOR_HEIGHT_M) < 0.03
    assert np.percentile(np.abs(z[ground] + SENSOR_HEIGHT_M), 95) < 0.1
    wall = (((az > 15) & (az < 25)) | ((az > -35) & (az < -15))) & (z > -0.5) & (z < 3.0) & (r_h > 20)
    assert wall.sum() > 50
    assert abs(np.median(x[wall]) - FRONT_WALL_X_M) < 0.05
    assert np.percentile(np.abs(x[wall] - FRONT_WALL_X_M), 95) < 0.15


@pytest.mark.crosscheck
def test_velodyne_decoder_points_put_the_courtyard_where_the_scene_has_it():
    vd = pytest.importorskip("velodyne_decoder")
    cfg = vd.Config(model=vd.Model.VLP16)
    clouds = [c for _, c in vd.read_pcap(str(fixtures.canned("vlp16-strongest")), cfg, as_pcl_structs=True)]
    c = np.concatenate(clouds)
    # velodyne_decoder's frame is x forward, y left, z up: the scene's world frame.
    _front_wall_and_ground(c["x"].astype(float), c["y"].astype(float), c["z"].astype(float))


@pytest.mark.crosscheck
def test_ouster_sdk_xyz_puts_the_courtyard_where_the_scene_has_it():
    pytest.importorskip("ouster.sdk")
    from ouster.sdk import open_source
    from ouster.sdk.core import XYZLut

    pcap = fixtures.canned("os1-64-dual")
    src = open_source(str(pcap), meta=[str(fixtures.metadata_path(pcap))], index=False)
    lut = XYZLut(src.sensor_info[0])
    scan = next(iter(src))[0]
    for field in ("RANGE", "RANGE2"):
        rng = scan.field(field)
        pts = lut(rng)[rng > 0]
        if field == "RANGE2":
            assert len(pts) > 10  # second returns only where there are two echoes (window, foliage)
            continue
        # Sensor frame = lidar frame turned 180° about z and raised 36.18 mm (lidar_to_sensor_transform).
        _front_wall_and_ground(-pts[:, 0], -pts[:, 1], pts[:, 2] - 0.03618)


@pytest.mark.crosscheck
def test_velodyne_decoder_on_the_full_50_frame_dual_capture():
    vd = pytest.importorskip("velodyne_decoder")
    pcap = fixtures.ensure("vlp16-dual", frames=50, seed=0)
    truth = fixtures.load_truth(pcap)
    rep = report_of("vlp16-dual", truth)
    cfg = vd.Config(model=vd.Model.VLP16)
    start_s = output.START_NS / 1e9
    seqs, clouds = [], []
    for stamp, cloud in vd.read_pcap(str(pcap), cfg, as_pcl_structs=True):
        t = (stamp.device - start_s) + cloud["time"].astype(np.float64)
        seqs.append(np.floor((t + 2e-6) / 55.296e-6).astype(np.int64))
        clouds.append(cloud)
    seq, cloud = np.concatenate(seqs), np.concatenate(clouds)
    keep = (seq >= 0) & (seq < 50 * 1800)
    seq, cloud = seq[keep], cloud[keep]
    k, col = np.divmod(seq, 1800)
    row = 15 - cloud["ring"].astype(np.int64)
    slot = np.where(cloud["return_type"] == 1, 1, 0)
    np.testing.assert_array_equal(cloud["intensity"], rep.reflectivity[k, slot, row, col])
    both = (rep.range_mm[:, 0] == rep.range_mm[:, 1]) & (rep.range_mm[:, 0] > 0)
    differ = rep.range_mm[:, 0] != rep.range_mm[:, 1]
    assert seq.size == both.sum() + 2 * differ.sum()
    # Named pixels: the points velodyne_decoder gives there are the truth's samples.
    elev = np.radians(15.0 - 2.0 * row)
    d_mm = 2 * np.rint(
        np.sqrt(cloud["x"].astype(float) ** 2 + cloud["y"].astype(float) ** 2
                + (cloud["z"].astype(float) - 0.04191 * np.tan(-elev)) ** 2) / 0.002
    ).astype(np.int64)
    for name, info in truth["raypaths"].items():
        for i, (r, c) in enumerate(info["pixel"]):
            at = (k == i) & (row == r) & (col == c)
            expect = info["samples"]["range_mm"][i]
            got = sorted(d_mm[at].tolist())
            want = sorted(set(v for v in expect if v > 0))
            assert got == want, (name, i)


@pytest.mark.crosscheck
def test_ouster_sdk_reads_the_jittered_capture_at_the_truth_pixels():
    pytest.importorskip("ouster.sdk")
    from ouster.sdk import open_source

    pcap = fixtures.ensure("os1-64-dual", frames=6, seed=3, jitter_px=2)
    truth = fixtures.load_truth(pcap)
    src = open_source(str(pcap), meta=[str(fixtures.metadata_path(pcap))], index=False)
    scans = [fs[0] for fs in src]
    assert len(scans) == 6
    moved = 0
    for k, s in enumerate(scans):
        for name, info in truth["raypaths"].items():
            if info["pixel"][k] is None:  # the raypath left the image in this frame: no sample
                assert info["samples"]["range_mm"][k] is None, (name, k)
                continue
            r, c = info["pixel"][k]
            got = [int(s.field("RANGE")[r, c]), int(s.field("RANGE2")[r, c])]
            assert got == info["samples"]["range_mm"][k], (name, k)
            assert [int(s.field("REFLECTIVITY")[r, c]), int(s.field("REFLECTIVITY2")[r, c])] == info["samples"]["reflectivity"][k]
            moved += info["pixel"][k] != info["pixel"][0]
    assert moved > 0


def test_full_length_captures_decode_whole_with_lidarpkt():
    for name, n in (("vlp16-strongest", 50), ("os1-64-legacy", 30)):
        pcap = fixtures.ensure(name, frames=n, seed=0)
        truth = fixtures.load_truth(pcap)
        frames = decoded(str(pcap))
        assert len(frames) == n and not any(f.partial for f in frames)
        rep = report_of(name, truth)
        np.testing.assert_array_equal(np.stack([f.range_mm for f in frames]), rep.range_mm)
        np.testing.assert_array_equal(np.stack([f.reflectivity for f in frames]), rep.reflectivity)
    stack = lidarpkt.FrameStack.from_frames(lidarpkt.open(fixtures.ensure("vlp16-strongest", frames=50, seed=0)),
                                            resolution_deg=0.2)
    assert len(stack) == 50 and stack.column_valid.all()


def _udp_checksum_ok(ip, udp_bytes: bytes) -> bool:
    pseudo = ip.src + ip.dst + struct.pack("!BBH", 0, 17, len(udp_bytes))
    data = pseudo + udp_bytes + (b"\0" if len(udp_bytes) % 2 else b"")
    s = sum(struct.unpack(f"!{len(data) // 2}H", data))
    while s >> 16:
        s = (s & 0xFFFF) + (s >> 16)
    return s == 0xFFFF


def test_udp_checksums_zero_for_vlp16_and_valid_for_ouster():
    pytest.importorskip("dpkt")
    for _, ip in ipv4_udp_records(fixtures.canned("vlp16-dual")):
        assert ip.data.sum == 0 and not ip.mf and ip.ttl > 0
    datagrams: dict[int, list] = {}
    for _, ip in ipv4_udp_records(fixtures.canned("os1-64-dual")):
        datagrams.setdefault(ip.id, []).append(ip)
    checked = 0
    for ident, frags in datagrams.items():
        frags.sort(key=lambda f: f.offset)
        raw = b"".join(bytes(f.data) if not isinstance(f.data, bytes) else f.data for f in frags)
        assert _udp_checksum_ok(frags[0], raw), ident
        checked += 1
    assert checked == 64 * 2 + 20


def test_metadata_is_the_nested_layout_and_says_it_is_synthetic():
    meta = json.loads(fixtures.metadata_path(fixtures.canned("os1-64-legacy")).read_text())
    assert {"sensor_info", "config_params", "lidar_data_format", "beam_intrinsics", "lidar_intrinsics",
            "imu_intrinsics", "calibration_status"} <= set(meta)
    assert "SYNTHETIC" in meta["_comment"]
    alt = np.array(meta["beam_intrinsics"]["beam_altitude_angles"])
    az = np.array(meta["beam_intrinsics"]["beam_azimuth_angles"])
    assert alt.size == az.size == 64 and np.all(np.diff(alt) < 0)
    assert 32 < alt[0] - alt[-1] < 34.5  # an OS1's 33.2° vertical field of view
    shift = np.array(meta["lidar_data_format"]["pixel_shift_by_row"])
    np.testing.assert_array_equal(shift, np.rint(az * 1024 / 360))
    assert meta["lidar_data_format"]["udp_profile_lidar"] == "LEGACY"


def test_ouster_dual_30_frames_shows_the_multi_return_cases():
    """The truth samples of the full OS1 dual capture (they equal the decoded ones: tested above):
    second returns where the paper has several scatterers, none on single surfaces."""
    truth = fixtures.load_truth(fixtures.ensure("os1-64-dual", frames=30, seed=0))
    s = {name: np.array(info["samples"]["range_mm"]) for name, info in truth["raypaths"].items()}
    sig = {name: np.array(info["samples"]["signal"]) for name, info in truth["raypaths"].items()}
    for name in ("wall", "corner", "sign", "hedge", "partial", "sky"):
        assert not s[name][:, 1].any(), name  # one surface: never a second return
    assert not s["sky"].any()
    for name in ("window", "foliage"):
        assert np.mean(s[name][:, 1] > 0) > 0.3, name
        two = s[name][:, 1] > 0
        assert np.all(sig[name][two, 1] <= sig[name][two, 0])
    # The glass (11.2 m, weak) shows up only now and then.
    glass = np.abs(s["window"] - 11200) < 50
    assert glass.mean() < 0.15
    # Foliage: the second tree 3 m behind appears in some frames, in either slot.
    assert np.any(np.abs(s["foliage"] - 13400) < 300)
    refl = np.array(truth["raypaths"]["sign"]["samples"]["reflectivity"])[:, 0]
    assert 160 < np.median(refl) < 200 and np.mean(refl > 100) > 0.9  # speckle spreads single firings
