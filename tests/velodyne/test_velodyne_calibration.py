"""VLP-16 calibrations (stock, ROS YAML, VeloView XML) and NMEA parsing, against the files and references."""

from __future__ import annotations

import numpy as np
import pytest

from lidarpkt.errors import CalibrationError, NMEAError
from lidarpkt.core.packet import PacketBatch
from lidarpkt.vendors.velodyne import VelodyneDecoder, load_calibration, stock_calibration
from lidarpkt.core.nmea import parse_nmea

MANUAL_ELEVATION = np.array([-15, 1, -13, 3, -11, 5, -9, 7, -7, 9, -5, 11, -3, 13, -1, 15], float)


@pytest.mark.parametrize("name", ["rust-lidar-utils/VLP16db.yaml", "nebula/VLP16.yaml", "veloview/VLP-16.xml"])
def test_calibration_files_give_the_manual_elevations(ext, name):
    cal = load_calibration(ext(name))
    np.testing.assert_allclose(cal.elevation_deg, MANUAL_ELEVATION, atol=1e-9)
    # these shipped files carry no azimuth offsets (the files say 0); non-zero corrections of every
    # kind are checked against velodyne_decoder in test_velodyne_calibration_corrections.py
    assert np.all(cal.rot_correction_rad == 0) and np.all(cal.dist_correction_m == 0)
    assert cal.distance_resolution_m == pytest.approx(0.002)
    np.testing.assert_array_equal(cal.rows_to_laser, [15, 13, 11, 9, 7, 5, 3, 1, 14, 12, 10, 8, 6, 4, 2, 0])


def test_stock_calibration():
    cal = stock_calibration()
    np.testing.assert_allclose(cal.elevation_deg, MANUAL_ELEVATION)
    assert cal.vert_offset_m[0] == pytest.approx(0.04191 * np.tan(np.radians(15)))


@pytest.mark.crosscheck
def test_stock_calibration_is_velodyne_decoders_default():
    vd = pytest.importorskip("velodyne_decoder")
    from ruamel.yaml import YAML

    doc = YAML(typ="safe", pure=True).load(vd.Calibration.default_calibs[vd.Model.VLP16].to_string())
    lasers = sorted(doc["lasers"], key=lambda e: e["laser_id"])
    cal = stock_calibration()
    np.testing.assert_allclose(cal.vert_correction_rad, [e["vert_correction"] for e in lasers], atol=1e-7)
    np.testing.assert_allclose(cal.vert_offset_m, [e.get("vert_offset_correction", 0) for e in lasers], atol=1e-7)


@pytest.mark.crosscheck
@pytest.mark.parametrize("name", ["rust-lidar-utils/VLP16db.yaml", "nebula/VLP16.yaml"])
def test_yaml_calibration_points_match_velodyne_decoder(ext, name):
    vd = pytest.importorskip("velodyne_decoder")
    payload = np.fromfile(ext("einride-vlp16-go/recording.bin"), np.uint8).reshape(-1, 1206)[:100]
    cfg = vd.Config(model=vd.Model.VLP16, calibration=vd.Calibration.read(str(ext(name))))
    cfg.min_range, cfg.max_range = 0.0, 1e4
    packets = vd.PacketVector()
    for i, row in enumerate(payload):
        packets.append(vd.VelodynePacket(1.0 + i * 0.001327, row.tobytes()))
    _, ref = vd.ScanDecoder(cfg).decode(packets, True)
    dec = VelodyneDecoder(calibration=ext(name))
    frames = dec.push(PacketBatch.from_payloads(payload)) + dec.finish()
    from lidarpkt.vendors.velodyne import frame_points

    ours = np.concatenate([frame_points(f) for f in frames])
    assert len(ours) == len(ref)
    # same firing order on both sides: column by column, laser id order within a column
    for axis in "xyz":
        assert np.abs(ours[axis] - ref[axis]).max() < 1e-3


def test_bad_calibration_files(tmp_path):
    with pytest.raises(CalibrationError, match="cannot read"):
        load_calibration(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("lasers: [1, 2\n")
    with pytest.raises(CalibrationError):
        load_calibration(bad)
    hdl32 = tmp_path / "hdl32.yaml"
    hdl32.write_text("lasers:\n" + "".join(f"- {{laser_id: {i}, vert_correction: 0.0}}\n" for i in range(32)))
    with pytest.raises(CalibrationError, match="32 lasers"):
        load_calibration(hdl32)
    noid = tmp_path / "noid.yaml"
    noid.write_text("lasers:\n" + "".join("- {vert_correction: 0.0}\n" for _ in range(16)))
    with pytest.raises(CalibrationError, match="bad laser entry"):
        load_calibration(noid)
    xml = tmp_path / "short.xml"
    xml.write_text("<?xml version='1.0'?><boost_serialization><DB><points_></points_></DB></boost_serialization>")
    with pytest.raises(CalibrationError, match="px"):
        load_calibration(xml)
    broken = tmp_path / "broken.xml"
    broken.write_text("<?xml version='1.0'?><boost_serialization><DB>")
    with pytest.raises(CalibrationError, match="malformed"):
        load_calibration(broken)


# ------------------------------------------------------------------ NMEA
def test_real_gprmc_sentence(ext):
    """The $GPRMC sentence of the HDL-32E capture's position packets (a real GPS)."""
    from lidarpkt.containers.pcap_reader import PcapReader
    from lidarpkt.vendors.velodyne import decode_position_packets

    batch = next(b for b in PcapReader(ext("rust-lidar-utils/velodyne_vlp32.pcap")).batches() if b.payload_size == 512)
    sentence = decode_position_packets(batch.payload).sentences()[0]
    assert sentence == "$GPRMC,214616,A,3708.3443,N,12139.4299,W,009.7,040.6,111212,013.8,E,D*0E"
    fix = parse_nmea(sentence)
    assert fix.sentence == "RMC" and fix.valid
    assert fix.date == (2012, 12, 11) and fix.time_of_day_s == 21 * 3600 + 46 * 60 + 16
    assert fix.latitude_deg == pytest.approx(37 + 8.3443 / 60)
    assert fix.longitude_deg == pytest.approx(-(121 + 39.4299 / 60))
    assert fix.utc_ns == 1355262376 * 10**9  # 2012-12-11T21:46:16Z


def test_gpgga_and_bad_sentences():
    # the NMEA 0183 standard's GGA example
    fix = parse_nmea("$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47\r\n")
    assert fix.sentence == "GGA" and fix.valid and fix.date is None and fix.utc_ns is None
    assert fix.latitude_deg == pytest.approx(48 + 7.038 / 60) and fix.longitude_deg == pytest.approx(11 + 31 / 60)
    with pytest.raises(NMEAError, match="checksum mismatch"):
        parse_nmea("$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*48")
    with pytest.raises(NMEAError, match="not an NMEA"):
        parse_nmea("GPGGA,123519")
    with pytest.raises(NMEAError, match="unsupported"):
        parse_nmea("$GPVTG,054.7,T,034.4,M,005.5,N,010.2,K*48")
    empty_fix = parse_nmea("$GPRMC,,V,,,,,,,,,,N*53")
    assert not empty_fix.valid and empty_fix.utc_ns is None


def test_xyz_is_the_manuals_spherical_to_cartesian(ext):
    """Manual: X = R·cos ω·sin α, Y = R·cos ω·cos α, Z = R·sin ω (Y forward, X right). Points are in
    the ROS frame (x forward, y left): x = Y, y = −X, z = Z; with the ROS YAML (no offsets) exactly."""
    payload = np.fromfile(ext("einride-vlp16-go/recording.bin"), np.uint8).reshape(-1, 1206)[:200]
    dec = VelodyneDecoder(calibration=ext("rust-lidar-utils/VLP16db.yaml"))
    f = (dec.push(PacketBatch.from_payloads(payload)) + dec.finish())[1]
    xyz = f.xyz()[0]
    rows, cols = np.nonzero(f.range_mm[0])
    r_m = f.range_mm[0, rows, cols] / 1000.0
    omega = np.radians(np.arange(15, -16, -2))[rows]
    alpha = np.radians(f.extra["azimuth_cdeg"][rows, cols] / 100.0)
    X, Y, Z = r_m * np.cos(omega) * np.sin(alpha), r_m * np.cos(omega) * np.cos(alpha), r_m * np.sin(omega)
    np.testing.assert_allclose(xyz[rows, cols, 0], Y, atol=1e-9)
    np.testing.assert_allclose(xyz[rows, cols, 1], -X, atol=1e-9)
    np.testing.assert_allclose(xyz[rows, cols, 2], Z, atol=1e-9)
