"""VLP-16 calibrations with every correction non-zero, decoded by lidarpkt and by velodyne_decoder.

The stock and the shipped calibrations have zero azimuth, distance and horizontal offsets, so a
wrong sign on any of them passes the other tests. ``tests/data/calibration/vlp16_corrected.*``
(written by ``make_vlp16_calibrations.py`` there) sets all of them; velodyne_decoder reads the
ROS YAML (it has no VeloView XML reader), lidarpkt reads both, and the points must agree within
1 mm, firing by firing (the matcher of ``test_velodyne_crosscheck``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_velodyne_crosscheck import assert_same_points, synthetic_packets

from lidarpkt.errors import CalibrationError
from lidarpkt.core.packet import PacketBatch
from lidarpkt.vendors.velodyne import VelodyneDecoder, frame_points, load_calibration

DATA = Path(__file__).resolve().parents[1] / "data" / "calibration"
YAML = DATA / "vlp16_corrected.yaml"
XML = DATA / "vlp16_corrected.xml"


def test_both_formats_hold_the_same_non_zero_corrections():
    a, b = load_calibration(YAML), load_calibration(XML)
    for name in ("vert_correction_rad", "rot_correction_rad", "vert_offset_m", "horiz_offset_m", "dist_correction_m"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=0, atol=1e-12, err_msg=name)
    assert np.all(a.rot_correction_rad != 0) and np.all(a.dist_correction_m != 0)
    assert np.all(a.horiz_offset_m != 0) and np.all(a.vert_offset_m != 0)



@pytest.mark.parametrize("path", [YAML, XML], ids=["yaml", "xml"])
def test_loaded_values_are_the_generators(path):
    """Units: YAML radians and metres, XML degrees and centimetres, both to SI."""
    import sys

    sys.path.insert(0, str(DATA))
    try:
        from make_vlp16_calibrations import corrections
    finally:
        sys.path.remove(str(DATA))
    rows = corrections()
    cal = load_calibration(path)
    np.testing.assert_allclose(cal.rot_correction_rad, np.radians([r["rot_deg"] for r in rows]), atol=1e-12)
    np.testing.assert_allclose(cal.vert_correction_rad, np.radians([r["vert_deg"] for r in rows]), atol=1e-12)
    np.testing.assert_allclose(cal.dist_correction_m, [r["dist_cm"] / 100 for r in rows], atol=1e-12)
    np.testing.assert_allclose(cal.vert_offset_m, [r["vert_offset_cm"] / 100 for r in rows], atol=1e-12)
    np.testing.assert_allclose(cal.horiz_offset_m, [r["horiz_offset_cm"] / 100 for r in rows], atol=1e-12)


def test_one_firing_by_the_formulas():
    """One return of laser 0 at a known azimuth, against the formulas written out by hand."""
    cal = load_calibration(YAML)
    az = np.full((1, 12), 9000)  # 90.00°
    dist = np.zeros((1, 12, 32), np.int64)
    dist[0, 0, 0] = 5000  # laser 0 of the first firing of block 0: 10.000 m
    from lidarpkt.vendors.velodyne import encode_data_packets

    payload = encode_data_packets(az, dist, np.full((1, 12, 32), 7), np.array([1000]), "strongest")
    dec = VelodyneDecoder(calibration=YAML)
    pts = np.concatenate([frame_points(f) for f in dec.push(PacketBatch.from_payloads(payload)) + dec.finish()])
    assert len(pts) == 1
    d = 10.0 + cal.dist_correction_m[0]
    w = cal.vert_correction_rad[0]
    a = np.radians(90.0) - cal.rot_correction_rad[0]
    h = cal.horiz_offset_m[0]
    expected = (d * np.cos(w) * np.cos(a) + h * np.sin(a), -d * np.cos(w) * np.sin(a) + h * np.cos(a),
                d * np.sin(w) + cal.vert_offset_m[0])
    np.testing.assert_allclose([pts["x"][0], pts["y"][0], pts["z"][0]], expected, atol=1e-6)


def test_two_point_distance_correction_is_refused(tmp_path):
    text = YAML.read_text().replace("dist_correction_x: 0.0, dist_correction_y: 0.0",
                                    "dist_correction_x: 0.01, dist_correction_y: 0.02", 1)
    (tmp_path / "two.yaml").write_text(text)
    with pytest.raises(CalibrationError, match=r"lasers \[0\] set dist_correction_x and dist_correction_y"):
        load_calibration(tmp_path / "two.yaml")
    xml = XML.read_text().replace("<distCorrectionX_>0</", "<distCorrectionX_>1.5</", 1)
    (tmp_path / "two.xml").write_text(xml.replace("<distCorrectionY_>0</", "<distCorrectionY_>2.5</", 1))
    with pytest.raises(CalibrationError, match="two-point distance correction"):
        load_calibration(tmp_path / "two.xml")


# ------------------------------------------------------------------ against velodyne_decoder
pytest_crosscheck = pytest.mark.crosscheck


@pytest_crosscheck
@pytest.mark.parametrize("mode", ["strongest", "last", "dual"])
@pytest.mark.parametrize("ours", [YAML, XML], ids=["yaml", "xml"])
def test_generated_packets_match(mode, ours):
    assert assert_same_points(synthetic_packets(mode, n=120), calibration=YAML, our_calibration=ours) > 1000


@pytest_crosscheck
@pytest.mark.parametrize("ours", [YAML, XML], ids=["yaml", "xml"])
def test_einride_recording_matches(ext, ours):
    payload = np.fromfile(ext("einride-vlp16-go/recording.bin"), np.uint8).reshape(-1, 1206)[:600]
    host = 1_525_349_000_000_000_000 + np.arange(len(payload), dtype=np.int64) * 1_327_104
    assert assert_same_points(PacketBatch.from_payloads(payload, host), calibration=YAML, our_calibration=ours) > 50000


@pytest_crosscheck
def test_rust_lidar_utils_capture_matches(ext):
    from lidarpkt.containers.pcap_reader import PcapReader

    batches = [b for b in PcapReader(ext("rust-lidar-utils/velodyne_example.pcap")).batches() if b.payload_size == 1206]
    assert assert_same_points(PacketBatch.concatenate(batches), calibration=YAML) > 30000


@pytest_crosscheck
def test_veloview_capture_matches(ext):
    from lidarpkt.containers.pcap_reader import PcapReader

    path = ext("veloview/vlp-16-test-90deg-1-50-frames.pcap")
    batch = PacketBatch.concatenate([b for b in PcapReader(path).batches() if b.payload_size == 1206])
    assert assert_same_points(batch.select(np.arange(400)), product_id_override=0x22, calibration=YAML, our_calibration=XML) > 50000


# ------------------------------------------------------------------ the VeloView XML reader's edges
def _xml(tmp_path, text, name="c.xml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_xml_distance_lsb_and_source(tmp_path):
    cal = load_calibration(XML)
    assert cal.distance_resolution_m == pytest.approx(0.002) and cal.source == str(XML)
    coarse = _xml(tmp_path, XML.read_text().replace("<distLSB_>0.2</distLSB_>", "<distLSB_>0.25</distLSB_>"))
    assert load_calibration(coarse).distance_resolution_m == pytest.approx(0.0025)
    none = _xml(tmp_path, XML.read_text().replace("\t<distLSB_>0.2</distLSB_>\n", ""), "n.xml")
    assert load_calibration(none).distance_resolution_m == 0.002  # the VLP-16's 2 mm when the XML says nothing


def test_xml_ids_above_15_are_skipped_wherever_they_stand(tmp_path):
    """VeloView writes 64 entries; an entry for id ≥ 16 before the last VLP-16 laser must not end the table."""
    text = XML.read_text()
    first = text.index("\t\t<item>\n")
    extra = ("\t\t<item>\n\t\t\t<px><id_>40</id_><rotCorrection_>9</rotCorrection_>"
             "<vertCorrection_>9</vertCorrection_></px>\n\t\t</item>\n")
    cal = load_calibration(_xml(tmp_path, text[:first] + extra + text[first:]))
    ref = load_calibration(XML)
    np.testing.assert_array_equal(cal.rot_correction_rad, ref.rot_correction_rad)
    np.testing.assert_array_equal(cal.vert_correction_rad, ref.vert_correction_rad)


def test_xml_missing_tags_are_zero_and_bad_values_are_named(tmp_path):
    text = XML.read_text()
    cal = load_calibration(_xml(tmp_path, text.replace("<horizOffsetCorrection_>2.59</horizOffsetCorrection_>", "", 1)))
    assert cal.horiz_offset_m[0] == 0.0 and cal.horiz_offset_m[2] == pytest.approx(0.0259)
    bad = _xml(tmp_path, text.replace("<distCorrection_>-4.5</distCorrection_>", "<distCorrection_>x</distCorrection_>"), "b.xml")
    with pytest.raises(CalibrationError, match=rf"{bad}: bad <px> entry"):
        load_calibration(bad)


@pytest.mark.parametrize("path", [YAML, XML], ids=["yaml", "xml"])
def test_one_of_dist_correction_x_y_alone_is_not_a_two_point_correction(tmp_path, path):
    """velodyne_decoder applies the two-point correction only where both are set: one alone is ignored."""
    text = path.read_text()
    for key_x, key_y, zero in (("dist_correction_x: 0.0", "dist_correction_y: 0.0", "0.0"),
                               ("<distCorrectionX_>0<", "<distCorrectionY_>0<", "0")):
        for key in (key_x, key_y):
            if key in text:
                one = _xml(tmp_path, text.replace(key, key.replace(zero, "0.5" if zero == "0.0" else "5"), 1),
                           "one" + path.suffix)
                assert load_calibration(one).source == str(one)
    with pytest.raises(CalibrationError, match=rf"{tmp_path / 'both'}.*: lasers \[0\]"):
        both = text.replace("dist_correction_x: 0.0, dist_correction_y: 0.0", "dist_correction_x: 0.1, dist_correction_y: 0.1", 1)
        both = both.replace("<distCorrectionX_>0<", "<distCorrectionX_>1<", 1).replace("<distCorrectionY_>0<", "<distCorrectionY_>1<", 1)
        load_calibration(_xml(tmp_path, both, "both" + path.suffix))


# ------------------------------------------------------------------ the ROS YAML reader's edges
def _yaml(tmp_path, lasers, head="", name="c.yaml"):
    path = tmp_path / name
    path.write_text(head + "lasers:\n" + "".join(f"- {{{e}}}\n" for e in lasers))
    return path


def test_yaml_defaults_resolution_and_errors(tmp_path):
    from lidarpkt.vendors.velodyne import stock_calibration

    assert stock_calibration().source == "stock"
    plain = [f"laser_id: {i}, vert_correction: 0.01" for i in range(16)]
    cal = load_calibration(_yaml(tmp_path, plain))
    for name in ("rot_correction_rad", "vert_offset_m", "horiz_offset_m", "dist_correction_m"):
        assert np.all(getattr(cal, name) == 0), name  # absent keys are 0
    assert cal.distance_resolution_m == 0.002
    fine = load_calibration(_yaml(tmp_path, plain, "distance_resolution: 0.0025\n", "f.yaml"))
    assert fine.distance_resolution_m == 0.0025
    bad = _yaml(tmp_path, plain, "num_lasers: 32\n", "n.yaml")
    with pytest.raises(CalibrationError, match=rf"{bad} describes 16 lasers \(num_lasers 32\)"):
        load_calibration(bad)
    for ids, what in (([*range(15), 16], "laser_id 16 out of range"), ([*range(15), 3], "laser_id 3 out of range or repeated")):
        path = _yaml(tmp_path, [f"laser_id: {i}, vert_correction: 0.0" for i in ids], name="i.yaml")
        with pytest.raises(CalibrationError, match=rf"{path}: bad laser entry .*{what}"):
            load_calibration(path)
    notdict = tmp_path / "list.yaml"
    notdict.write_text("- 1\n- 2\n")
    with pytest.raises(CalibrationError, match=rf"{notdict}: no 'lasers' list"):
        load_calibration(notdict)
    broken = tmp_path / "broken.yaml"
    broken.write_text("lasers: [1, 2\n")
    with pytest.raises(CalibrationError, match=rf"{broken} is neither VeloView XML nor valid ROS calibration YAML"):
        load_calibration(broken)


def test_frame_without_firing_azimuths_is_named():
    from dataclasses import replace

    from lidarpkt.vendors.velodyne import VelodyneDecoder, encode_data_packets

    payload = encode_data_packets(np.zeros((1, 12), np.int64), np.full((1, 12, 32), 500), np.zeros((1, 12, 32), np.int64),
                                  np.array([1000]), "strongest")
    dec = VelodyneDecoder(calibration=YAML)
    (f,) = dec.push(PacketBatch.from_payloads(payload)) + dec.finish()
    with pytest.raises(CalibrationError, match=r"VLP-16 frame without per-firing azimuths \(extra\['azimuth_cdeg'\]\)"):
        f.sensor.geometry.xyz(replace(f, extra={}))
