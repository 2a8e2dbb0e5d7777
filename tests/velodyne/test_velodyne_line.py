"""Every spinning Velodyne against velodyne_decoder 3.1.0: the real HDL-32E, VLP-32C and VLS-128
captures, copies of them with every return redrawn, and hand-built packets of the models with no
capture here (Puck Hi-Res, Puck LITE, VLP-32A/B, Alpha Prime, HDL-64E S2/S3, the dual modes of all).

The measure (issue 24): at least 99.5 % of velodyne_decoder's points have one of lidarpkt's within
1 mm, and the other way round; the two clouds have the same number of points.
"""

from __future__ import annotations

import numpy as np
import pytest

import lidarpkt
from lidarpkt.errors import CalibrationError, UnknownSensorError
from lidarpkt.core.packet import PacketBatch
from lidarpkt.vendors.velodyne import VelodyneDecoder, encode_data_packets, frame_points
from lidarpkt.vendors.velodyne.layout import packet_layout
from lidarpkt.vendors.velodyne.models import MODELS, model_named

pytestmark = pytest.mark.crosscheck

REAL = {
    "HDL-32E": "rust-lidar-utils/velodyne_vlp32.pcap",
    "VLP-32C": "nebula/vlp32/1713492677464078412",
    "VLS-128": "nebula/vls128/1614315746471294674",
}
VD_MODEL = {"VLP-16": "VLP16", "Puck LITE": "PuckLite", "Puck Hi-Res": "PuckHiRes", "HDL-32E": "HDL32E",
            "VLP-32C": "VLP32C", "VLP-32A": "VLP32A", "VLP-32B": "VLP32B", "VLS-128": "VLS128",
            "Alpha Prime": "AlphaPrime", "HDL-64E S2": "HDL64E_S2", "HDL-64E S3": "HDL64E_S3"}
HDL64_CAL = {"HDL-64E S2": "nebula/HDL64e_s2.yaml", "HDL-64E S3": "nebula/HDL64e_s3.yaml"}


def data_packets(path) -> PacketBatch:
    from lidarpkt.vendors.registry import open_packets

    return PacketBatch.concatenate([b for b in open_packets(path).batches() if b.payload_size == 1206])


def reference_points(batch: PacketBatch, model: str | None = None, calibration=None) -> np.ndarray:
    vd = pytest.importorskip("velodyne_decoder")
    cfg = vd.Config()
    if model is not None:
        cfg.model = getattr(vd.Model, VD_MODEL[model])
    if calibration is not None:
        cfg.calibration = vd.Calibration.read(str(calibration))
    cfg.min_range, cfg.max_range = 0.0, 1e4
    packets = vd.PacketVector()
    for t, row in zip(batch.timestamp_ns.tolist(), batch.payload):
        packets.append(vd.VelodynePacket(t / 1e9, row.tobytes()))
    _, points = vd.ScanDecoder(cfg).decode(packets, True)
    return points


def our_points(batch: PacketBatch, **options) -> tuple[np.ndarray, list]:
    dec = VelodyneDecoder(**options)
    frames = dec.push(batch) + dec.finish()
    return np.concatenate([frame_points(f) for f in frames]), frames


def assert_clouds_agree(ref: np.ndarray, ours: np.ndarray, share: float = 0.995) -> None:
    from scipy.spatial import cKDTree

    a = np.stack([ref["x"], ref["y"], ref["z"]], 1).astype(np.float64)
    b = np.stack([ours["x"], ours["y"], ours["z"]], 1)
    assert len(a) == len(b) and len(a) > 0
    # at most 150 000 points asked each way (the VLS-128 capture has 766 000): the share stays within
    # ±0.05 % of the whole cloud's at 3 sigma
    pick = np.random.default_rng(0).permutation(len(a))[:150_000]
    d_ab, _ = cKDTree(b).query(a[pick])
    d_ba, _ = cKDTree(a).query(b[pick])
    assert np.mean(d_ab <= 1e-3) >= share, np.median(d_ab)
    assert np.mean(d_ba <= 1e-3) >= share, np.median(d_ba)


# ------------------------------------------------------------------ real captures
@pytest.mark.parametrize("model", sorted(REAL))
def test_real_capture_matches_velodyne_decoder(ext, model):
    batch = data_packets(ext(REAL[model]))
    ours, frames = our_points(batch)
    assert {f.sensor.model for f in frames} == {model}
    assert frames[0].sensor.rows == model_named(model).lasers
    assert_clouds_agree(reference_points(batch), ours)


@pytest.mark.parametrize("model", sorted(REAL))
def test_real_capture_with_every_return_redrawn_matches_velodyne_decoder(ext, model):
    """Distances and reflectivities drawn anew (flags, azimuths, times and factory bytes kept)."""
    batch = data_packets(ext(REAL[model]))
    rng = np.random.default_rng(24)
    payload = batch.payload.copy()
    channels = payload[:, :1200].reshape(-1, 12, 100)[:, :, 4:].reshape(-1, 12, 32, 3)
    dist = rng.integers(0, 30_000, channels.shape[:3]).astype("<u2")
    dist[rng.random(dist.shape) < 0.2] = 0  # no return
    channels[..., :2] = dist[..., None].view(np.uint8)
    channels[..., 2] = rng.integers(0, 256, channels.shape[:3])
    redrawn = PacketBatch.from_payloads(payload, batch.timestamp_ns)
    ours, _ = our_points(redrawn)
    assert_clouds_agree(reference_points(redrawn), ours)


@pytest.mark.parametrize("model", sorted(REAL))
def test_info_names_the_model_of_each_real_capture(ext, model):
    from lidarpkt.vendors.velodyne.detect import describe_stream

    desc = describe_stream(data_packets(ext(REAL[model])))
    assert desc["kind"] == f"{model} data" and desc["model"] == model


# ------------------------------------------------------------------ hand-built packets
def hand_built(model_name: str, mode: str, n: int = 60, seed: int = 0) -> PacketBatch:
    """``n`` packets of ``model_name`` in ``mode`` turning at 10 Hz: block azimuths from the firing time of
    each block's column, random distances (a fifth empty), in dual mode a third of the firings with one
    return (both blocks equal)."""
    model = model_named(model_name)
    lay = packet_layout(model, mode)
    rng = np.random.default_rng(seed)
    period_us = model.packet_period_us(mode)
    t_us = 1_000_000 + np.rint(np.arange(n) * period_us).astype(np.int64)
    ref_ns = lay.firing_ns[lay.azimuth_block[:, 0], 0] - lay.dt_s32[lay.azimuth_block[:, 0], 0] * 1e9
    t_block = t_us[:, None] * 1e-6 + ref_ns[None, :] * 1e-9
    azimuth = np.rint(t_block * 10 * 36000 + 12_345).astype(np.int64) % 36000
    dist = rng.integers(200, 20_000, (n, 12, 32))
    dist[rng.random(dist.shape) < 0.2] = 0
    if mode == "dual":
        src = lay.source  # [2, lasers, columns] channel of each slot
        one = rng.random(src.shape[1:]) < 0.33
        flat = dist.reshape(n, -1)
        flat[:, src[0][one]] = flat[:, src[1][one]]
    refl = rng.integers(0, 256, (n, 12, 32))
    flags = np.where(lay.flag == 0, 0xEEFF, lay.flag)
    if model.dual_layout != "upper_lower":  # the LITE and the Alpha Prime say VLP-16 and VLS-128
        product, mode_byte = (model.product_ids or {"Puck LITE": (0x22,), "Alpha Prime": (0xA1,)}[model.name])[0], mode
    else:  # HDL-64E: a status byte pair where the others carry mode and product
        product, mode_byte = 0x00, 0x48
    payload = encode_data_packets(azimuth, dist, refl, t_us % 3_600_000_000, mode_byte, product,
                                  flag=np.broadcast_to(flags, (n, 12)))
    return PacketBatch.from_payloads(payload, 1_700_000_000_000_000_000 + t_us * 1000)


# the HDL-64E says its single-return mode only in its status cycle: strongest and dual cover it
@pytest.mark.parametrize("model, mode", [(m.name, mode) for mode in ("strongest", "last", "dual") for m in MODELS
                                         if not (m.name.startswith("HDL-64E") and mode == "last")])
def test_hand_built_packets_of_every_model_and_mode_match_velodyne_decoder(ext, model, mode):
    # velodyne_decoder measures a VLS-128's rate from the packet before: its first packet turns at 0 (1 in 300)
    batch = hand_built(model, mode, n=300 if model in ("VLS-128", "Alpha Prime") else 60)
    cal = ext(HDL64_CAL[model]) if model in HDL64_CAL else None
    ours, frames = our_points(batch, model=model, calibration=cal)
    assert {f.sensor.model for f in frames} == {model}
    assert {f.sensor.return_mode for f in frames} == {"strongest" if model.startswith("HDL-64E") and mode != "dual"
                                                     else mode}
    if mode == "dual":  # the dual mark (velodyne/dual.py) on every model: slot 1 second strongest where the
        # last return's signal (reflectivity / range²) is the higher
        from lidarpkt.core.dual import second_strongest_mark

        for f in frames:
            mark = f.extra["second_strongest"]
            assert mark.shape == f.range_mm.shape[1:]
            np.testing.assert_array_equal(mark, second_strongest_mark(f.range_mm, f.reflectivity))
        assert any(f.extra["second_strongest"].any() for f in frames)
    ref = reference_points(batch, model, cal)
    assert_clouds_agree(ref, ours, share=0.995 if model in ("VLS-128", "Alpha Prime") else 1.0)


def test_the_model_comes_from_the_factory_byte_without_an_option():
    for name in ("Puck Hi-Res", "HDL-32E", "VLP-32C", "VLS-128"):
        _, frames = our_points(hand_built(name, "strongest"))
        assert frames[0].sensor.model == name


# ------------------------------------------------------------------ errors
def test_a_vlp32a_or_b_byte_says_which_option_picks_one():
    batch = hand_built("VLP-32A", "strongest")
    with pytest.raises(UnknownSensorError, match=r"0x23 is a VLP-32A or a VLP-32B.*model='VLP-32A'"):
        VelodyneDecoder().push(batch)


def test_a_bad_model_byte_is_one_clear_error():
    batch = hand_built("VLP-32C", "strongest")
    payload = batch.payload.copy()
    payload[:, 1205] = 0x77
    with pytest.raises(UnknownSensorError, match=r"factory byte 0x77 names no model lidarpkt decodes"):
        VelodyneDecoder().push(PacketBatch.from_payloads(payload, batch.timestamp_ns))


def test_a_calibration_for_another_model_is_refused(ext):
    batch = hand_built("VLP-32C", "strongest")
    with pytest.raises(CalibrationError, match=r"not a VLP-32C's .*looks like a HDL-32E calibration"):
        VelodyneDecoder(calibration=ext("nebula/HDL32.yaml")).push(batch)
    with pytest.raises(CalibrationError, match=r"describes 128 lasers .*a VLP-32C has 32"):
        VelodyneDecoder(calibration=ext("nebula/VLS128.yaml")).push(batch)
    dec = VelodyneDecoder(model="HDL-64E S3")
    assert dec.push(hand_built("HDL-64E S3", "strongest")) == []  # held for the status cycle's calibration
    with pytest.raises(CalibrationError, match="held no whole calibration; pass the unit's calibration"):
        dec.finish()


# ------------------------------------------------------------------ downstream
def test_info_cli_names_each_real_captures_model(ext):
    import subprocess
    import sys

    for model, rel in REAL.items():
        out = subprocess.run([sys.executable, "-m", "lidarpkt", "info", str(ext(rel))], capture_output=True,
                             text=True, timeout=60, check=True).stdout
        assert f"{model} data" in out, out


def test_parquet_export_of_the_vlp32c_bag_holds_one_row_per_return(ext, tmp_path):
    import subprocess
    import sys

    pq = pytest.importorskip("pyarrow.parquet")
    path = ext(REAL["VLP-32C"])
    subprocess.run([sys.executable, "-m", "lidarpkt", "export", "-q", "-o", str(tmp_path / "out"), "--format",
                    "parquet", "--workers", "1", str(path)], capture_output=True, timeout=120, check=True)
    table = pq.read_table(next((tmp_path / "out").rglob("*.parquet")))
    frames = list(lidarpkt.open(path))
    returns = sum(int(np.count_nonzero(f.range_mm)) for f in frames)
    assert table.num_rows == returns > 100_000
    ranges = np.sort(np.concatenate([f.range_mm[f.range_mm > 0] for f in frames]) / 1000.0)
    np.testing.assert_allclose(np.sort(table.column("range_m").to_numpy()), ranges, atol=1e-6)


# ------------------------------------------------------------------ the compiled kernels and their NumPy twins
@pytest.mark.parametrize("model, mode", [("VLS-128", "strongest"), ("VLS-128", "dual"), ("VLP-32C", "dual"),
                                         ("HDL-32E", "strongest"), ("HDL-64E S3", "dual")])
def test_compiled_columns_and_xyz_give_the_numpy_twins_bytes(ext, monkeypatch, model, mode):
    from lidarpkt.core import kernels

    if kernels.native is None:
        pytest.skip("the C extension is not built (LIDARPKT_NATIVE=0 or no compiler)")
    batch = hand_built(model, mode, n=40, seed=3)
    cal = ext(HDL64_CAL[model]) if model in HDL64_CAL else None
    _, native = our_points(batch, model=model, calibration=cal)
    with monkeypatch.context() as m:
        m.setattr(kernels, "native", None)
        _, twin = our_points(batch, model=model, calibration=cal)
        twin_xyz = [f.xyz() for f in twin]
    assert len(native) == len(twin)
    for a, b, xyz in zip(native, twin, twin_xyz):
        np.testing.assert_array_equal(a.range_mm, b.range_mm)
        np.testing.assert_array_equal(a.reflectivity, b.reflectivity)
        np.testing.assert_array_equal(a.extra["azimuth_cdeg"], b.extra["azimuth_cdeg"])
        np.testing.assert_array_equal(a.xyz(), xyz)


# ------------------------------------------------------------------ HDL-64E status cycle
@pytest.mark.parametrize("model", ["HDL-64E S2", "HDL-64E S3"])
@pytest.mark.parametrize("mode", ["strongest", "dual"])
def test_hdl64e_calibration_from_its_status_cycle(ext, tmp_path, model, mode):
    """Packets whose status bytes cycle through a parameter block made from a real calibration (nebula's
    YAML, rounded to the block's units): velodyne_decoder's ``hdl64e`` reads the same calibration from
    them, and both decode the packets to the same points; lidarpkt without any calibration given."""
    vd = pytest.importorskip("velodyne_decoder")
    from lidarpkt.vendors.velodyne.calibration import load_calibration
    from lidarpkt.vendors.velodyne.hdl64e import encode_unit_parameters, status_bytes

    s3 = model.endswith("S3")
    block = encode_unit_parameters(load_calibration(ext(HDL64_CAL[model]), model_named(model)), s3=s3)
    batch = hand_built(model, mode, n=9000, seed=5)  # a cycle: 1820 bytes, 7 in 16 packets: 4160 packets
    types, values = status_bytes(block, len(batch), s3=s3, offset=700)
    payload = batch.payload.copy()
    payload[:, 1204], payload[:, 1205] = types, values
    records = payload[:-200, :1200].reshape(-1, 12, 100)[:, :, 4:].reshape(-1, 12, 32, 3)
    records[..., :2] = 0  # returns in the last 200 packets only: a cloud the comparison reads in seconds
    batch = PacketBatch.from_payloads(payload, batch.timestamp_ns)
    status = vd.hdl64e.read_status_info(bytes(row) for row in payload)
    assert status["Model"] == ("S3" if s3 else "S2")
    ours, frames = our_points(batch)  # no model, no calibration: the layout and the status cycle say both
    assert {f.sensor.model for f in frames} == {model}
    cal = frames[0].sensor.geometry.calibration
    theirs = np.array([[c["Vertical Correction"], c["Rotational Correction"], c["Far Distance Correction"],
                        c["Distance Correction X"], c["Vertical Offset Correction"], c["Focal Slope"]]
                       for c in status["Calibration"]])
    np.testing.assert_allclose(np.degrees(cal.vert_correction_rad), theirs[:, 0], atol=1e-9)
    np.testing.assert_allclose(np.degrees(cal.rot_correction_rad), theirs[:, 1], atol=1e-9)
    np.testing.assert_allclose(cal.dist_correction_m, theirs[:, 2], atol=1e-9)
    np.testing.assert_allclose(cal.dist_correction_x_m, theirs[:, 3], atol=1e-9)
    np.testing.assert_allclose(cal.vert_offset_m, theirs[:, 4], atol=1e-9)
    np.testing.assert_allclose(cal.focal_slope, theirs[:, 5], atol=1e-9)
    import yaml

    doc = vd.hdl64e.status_info_to_calib_dict(status)
    doc.pop("status")
    path = tmp_path / "cycle.yaml"
    path.write_text(yaml.safe_dump(doc))
    assert_clouds_agree(reference_points(batch, model, path), ours)


# ------------------------------------------------------------------ position packets
def test_hdl32e_position_packets_give_gyro_temperature_and_acceleration(ext):
    from lidarpkt.containers.pcap_reader import read_batches
    from lidarpkt.vendors.velodyne import encode_position_packets, hdl32e_inertial

    pos = next(b for b in read_batches(ext(REAL["HDL-32E"])) if b.payload_size == 512)
    imu = hdl32e_inertial(pos.payload)
    assert imu.gyro_deg_s.shape == imu.temperature_c.shape == (9, 3) and imu.accel_g.shape == (9, 3, 2)
    # a unit at rest indoors: two of its 2-axis accelerometers see about 1 g, its sensors 30-45 °C
    g = np.linalg.norm(imu.accel_g, axis=-1).mean(axis=0)
    assert np.all(np.abs(g[:2] - 1.0) < 0.05)
    assert np.all((imu.temperature_c > 30) & (imu.temperature_c < 45))
    assert np.all(imu.tag == np.arange(4))
    # hand-built words: -1 count, +2047 counts and the tag bits around them
    head = np.zeros((1, 198), np.uint8)
    words = np.array([[0xFFFF, 0x17FF, 0x2001, 0x3800] * 3], "<u2")
    head[0, 14:38] = words.view(np.uint8)
    imu = hdl32e_inertial(encode_position_packets(0, 0, "", unused_head=head))
    np.testing.assert_allclose(imu.gyro_deg_s, [[-0.09766] * 3])
    np.testing.assert_allclose(imu.temperature_c, [[2047 * 0.1453 + 25] * 3])
    np.testing.assert_allclose(imu.accel_g, [[[0.001221, -2048 * 0.001221]] * 3])
    # a VLP-16's position packet has zeros there
    vlp = next(b for b in read_batches(ext("rust-lidar-utils/velodyne_vlp16.pcap")) if b.payload_size == 512)
    assert np.all(hdl32e_inertial(vlp.payload).gyro_deg_s == 0)


# ------------------------------------------------------------------ nebula's decoded clouds
def _pcd_xyz(path) -> np.ndarray:
    head, _, body = path.read_bytes().partition(b"DATA binary\n")
    assert b"FIELDS x y z\n" in head
    return np.frombuffer(body, "<f4").reshape(-1, 3).astype(np.float64)


@pytest.mark.parametrize("model, message, pcd, calibration", [
    ("VLP-32C", 0, "nebula/vlp32/1713492677464078412.pcd", "nebula/VLP32.yaml"),
    ("VLS-128", 1, "nebula/vls128/1585897255376374245.pcd", "nebula/VLS128.yaml"),
])
def test_where_nebula_differs_it_is_the_azimuth_alone(ext, model, message, pcd, calibration):
    """nebula's cloud and ours (its calibration for both) differ by a median of 4 mm (VLP-32C) and 17 mm
    (VLS-128). Why, measured here: matched point to point, the range and the elevation agree to the
    micrometre (so the distance unit, 4 mm on both even though nebula's VLS128.yaml says
    ``distance_resolution: 0.007``, and the reading of the calibration are the same); all of the difference
    is in the azimuth, in steps of 0.01° that follow the lasers' firing order (VLP-32C: nebula's azimuth of a
    laser firing later in the block lags ours by up to ~0.1°). That is the per-firing azimuth interpolation:
    velodyne_decoder and lidarpkt advance each firing by the rotation rate times its time in the manuals'
    firing-timing tables (VLP-32C: pairs 2.304 µs apart; VLS-128: groups of 8 lasers, a channel time apart),
    nebula by its own table. By the manuals' "Precision Azimuth Calculation", ours stands."""
    from scipy.spatial import cKDTree

    batch = [b for b in __import__("lidarpkt.vendors.registry", fromlist=["x"]).open_packets(ext(REAL[model])).batches()
             if b.payload_size == 1206][message]
    neb = _pcd_xyz(ext(pcd))
    ours, _ = our_points(batch, calibration=ext(calibration))
    xyz = np.stack([ours["x"], ours["y"], ours["z"]], 1)
    dist, idx = cKDTree(xyz).query(neb)
    assert np.median(dist) > 2e-3  # the discrepancy the issue reports
    # every nebula point has one of ours at the same range (1 mm) and elevation (0.001°), wherever its azimuth
    r_neb, r_ours = np.linalg.norm(neb, axis=1), np.linalg.norm(xyz, axis=1)
    el_neb, el_ours = np.degrees(np.arcsin(neb[:, 2] / r_neb)), np.degrees(np.arcsin(xyz[:, 2] / r_ours))
    near, _ = cKDTree(np.stack([r_ours * 1000, el_ours * 1000], 1)).query(np.stack([r_neb * 1000, el_neb * 1000], 1))
    assert np.mean(near < 1.0) > 0.995
    az = np.degrees(np.arctan2(neb[:, 1], neb[:, 0]) - np.arctan2(xyz[idx, 1], xyz[idx, 0]))
    az = (az + 180) % 360 - 180
    assert np.percentile(np.abs(az), 90) > 0.02 and np.percentile(np.abs(az), 95) < 0.2


# ------------------------------------------------------------------ the encoder
@pytest.mark.parametrize("model", [m.name for m in MODELS if m.sequences_per_block == 1])
@pytest.mark.parametrize("mode", ["strongest", "dual"])
def test_encoded_frames_are_the_packets_again(ext, model, mode):
    """encode_frames(decode(packets)) == packets, byte for byte (but the HDL-64E's status bytes, which the
    frames do not carry, and the VLS-128's unused dual blocks 8-11)."""
    from lidarpkt.vendors.velodyne import encode_frames

    batch = hand_built(model, mode, n=50, seed=7)
    cal = ext(HDL64_CAL[model]) if model in HDL64_CAL else None
    _, frames = our_points(batch, model=model, calibration=cal)
    again = encode_frames(frames)
    original = batch.payload.copy()
    if model.startswith("HDL-64E"):
        original[:, 1204:] = 0
    if mode == "dual" and model in ("VLS-128", "Alpha Prime"):
        original[:, 800:1200] = again[:, 800:1200] = 0
    np.testing.assert_array_equal(again, original)


def test_cli_says_in_one_line_which_option_picks_a_vlp32a_or_b(tmp_path):
    import subprocess
    import sys

    from lidarpkt.core.packet import Endpoint, Packet
    from lidarpkt.writers.pcap import write_pcap

    batch = hand_built("VLP-32A", "strongest", n=300)
    src, dst = Endpoint("192.168.1.201", 2368), Endpoint("255.255.255.255", 2368)
    pcap = tmp_path / "vlp32ab.pcap"
    write_pcap(pcap, (Packet(int(t), src, dst, row.tobytes()) for t, row in zip(batch.timestamp_ns, batch.payload)),
               udp_checksum=False)
    run = [sys.executable, "-m", "lidarpkt", "decode", str(pcap), "-o", str(tmp_path / "out.npz"), "-q"]
    bad = subprocess.run(run, capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr
    lines = bad.stderr.strip().splitlines()
    assert len(lines) == 1 and "VLP-32A or a VLP-32B" in lines[0] and "(--model)" in lines[0]
    good = subprocess.run(run + ["--velodyne-model", "VLP-32B"], capture_output=True, text=True, timeout=60)
    assert good.returncode == 0, good.stderr
    with np.load(tmp_path / "out.npz") as npz:
        assert any(npz[k].shape[-2:-1] == (32,) or 32 in npz[k].shape for k in npz.files if "range" in k)


def test_decode_to_mcap_names_the_model_and_its_own_elevations(ext, tmp_path):
    """The MCAP's sensor record of a VLP-32C bag: its model and its 32 stock elevations (not the VLP-16's)."""
    import json

    from mcap.reader import make_reader

    from lidarpkt.cli import main

    out = tmp_path / "vlp32c.mcap"
    assert main(["decode", str(ext("nebula/vlp32/1713492677464078412")), "-o", str(out), "-q"]) == 0
    with out.open("rb") as fh:
        records = [m for m in make_reader(fh).iter_metadata() if m.name == "lidarpkt.sensor"]
    assert records and records[0].metadata["model"] == "VLP-32C"
    elevations = json.loads(records[0].metadata["laser_elevation_deg"])
    assert elevations == [float(e) for e in model_named("VLP-32C").elevation_deg] and len(elevations) == 32


def test_a_restricted_field_of_view_is_not_lost_packets(ext):
    """nebula's VLP-32C sends only 270° → 90° (half of each rotation, FOV set on the sensor): the missing half
    recurs at the same azimuths every rotation, so it is counted outside the field of view, not lost."""
    import warnings

    from lidarpkt.errors import DroppedPacketsWarning

    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        reader = lidarpkt.open(ext("nebula/vlp32/1713492677464078412"))
        frames = list(reader)
    assert frames and not [w for w in said if issubclass(w.category, DroppedPacketsWarning)]
    (decoder,) = reader.decoders.values()
    assert decoder.stats.lost_packets == 0 and decoder.stats.outside_fov_packets == 300  # 4 gaps of 75 packets


def _vlp16_batches(ext):
    from lidarpkt.containers.pcap_reader import PcapReader

    reader = PcapReader(ext("veloview/vlp-16-test-90deg-1-50-frames.pcap"), batch_packets=8192)
    return [PacketBatch.concatenate([b for b in reader.batches() if b.payload_size == 1206])]  # all of it, one batch


def _decode(batches):
    decoder = VelodyneDecoder()
    for b in batches:
        decoder.push(b)
    decoder.finish()
    return decoder.stats


def test_one_wide_gap_is_lost_and_the_same_sector_every_rotation_is_the_field_of_view(ext):
    import warnings

    (batch,) = _vlp16_batches(ext)
    azimuth = batch.payload[:, 2:4].copy().view("<u2").ravel()
    whole = _decode([batch])
    once = np.ones(len(batch), bool)
    once[500:530] = False  # 30 packets gone once: a loss
    sector = (azimuth >= 9000) & (azimuth < 21000)  # 120° gone every rotation: a field of view
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lost_once = _decode([batch.select(once)])
        fov = _decode([batch.select(~sector)])
    assert lost_once.lost_packets - whole.lost_packets == 30 and lost_once.outside_fov_packets == 0
    assert fov.lost_packets == whole.lost_packets and fov.outside_fov_packets >= np.count_nonzero(sector) - 40


def test_an_unknown_velodyne_model_is_one_line_naming_the_flag(ext, tmp_path, capsys):
    from lidarpkt.cli import main

    out = tmp_path / "x.mcap"
    status = main(["decode", str(ext("rust-lidar-utils/velodyne_vlp32.pcap")), "-o", str(out), "--model", "VLP-99"])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and err[0].startswith("lidarpkt: error: --model VLP-99: no such")
    assert not out.exists()
    with pytest.raises(UnknownSensorError, match="^model 'VLP-99'"):
        model_named("VLP-99")
