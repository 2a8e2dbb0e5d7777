"""Ouster metadata JSON in both layouts: values, documented defaults, and errors that name the field."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from conftest import external
from lidarpkt.errors import MetadataError
from lidarpkt.vendors.ouster import load_metadata
from lidarpkt.vendors.ouster.profiles import PROFILES


def test_reduced_legacy_file_gets_the_documented_defaults():
    md = load_metadata(external("ouster-sdk/OS-1-64_sensor_config_reduced.json"))
    assert md.profile.name == "LEGACY" and md.pixels_per_column == 64
    assert md.columns_per_packet == 16 and md.columns_per_frame == 1024 and md.column_window == (0, 1023)
    assert md.packet_size == 12608  # SOURCES.md: 16 × (16 + 64 × 12 + 4)
    assert md.pixel_shift_by_row.tolist() == [18, 12, 6, 0] * 16
    assert md.lidar_origin_to_beam_origin_mm == 12.163
    assert md.beam_to_lidar_transform[0, 3] == 12.163
    assert np.array_equal(np.diag(md.lidar_to_sensor_transform), [-1, -1, 1, 1])
    assert md.lidar_to_sensor_transform[2, 3] == 36.18
    assert md.init_id == 0 and md.serial is None and md.firmware is None
    assert md.frequency_hz == 10.0 and md.footer_kind == "none"
    assert {"pixel_shift_by_row", "lidar_to_sensor_transform", "udp_profile_lidar"} <= set(md.defaulted)


@pytest.mark.parametrize("mode,w,shift", [("512x10", 512, [9, 6, 3, 0]), ("2048x10", 2048, [36, 24, 12, 0]), ("1024x20", 1024, [18, 12, 6, 0])])
def test_default_stagger_follows_lidar_mode(mode, w, shift):
    doc = json.loads(external("ouster-sdk/OS-1-64_sensor_config_reduced.json").read_text())
    doc["lidar_mode"] = mode
    md = load_metadata(doc)
    assert md.columns_per_frame == w and md.pixel_shift_by_row[:4].tolist() == shift
    assert md.frequency_hz == float(mode.split("x")[1])


def test_flat_layout_full_file():
    md = load_metadata(external("ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.json"))
    assert md.profile.name == "RNG19_RFL8_SIG16_NIR16" and md.packet_size == 24832
    assert md.init_id == 5431293 and md.serial == "992210000957" and md.serial_int == 992210000957
    assert md.firmware_version == (2, 3, 0) and md.footer_kind == "opaque"
    assert md.lidar_to_sensor_transform[2, 3] == 78.296
    assert md.beam_to_lidar_transform[0, 3] == 13.762  # from lidar_origin_to_beam_origin_mm
    assert md.lidar_port == 7502 and md.imu_port == 7503


def test_nested_layout():
    md = load_metadata(external("ouster-sdk/crc_test.json"))
    assert md.profile.name == "RNG15_RFL8_NIR8" and md.pixels_per_column == 128 and md.columns_per_frame == 512
    assert md.init_id == 11394290 and md.serial == "122247000785"
    # build_rev is a commit hash here; the version comes from image_rev (v3.2.0-alpha.1)
    assert md.firmware_version == (3, 2, 0) and md.footer_kind == "crc"
    assert md.packet_size == 8448 and md.lidar_to_sensor_transform[2, 3] == 38.195
    md2 = load_metadata(external("ouster-sdk/duplicate_id.json"))
    assert (md2.lidar_port, md2.imu_port) == (34636, 48887) and md2.footer_kind == "opaque"


def test_flat_and_nested_layouts_give_the_same_sensor():
    nested = json.loads(external("ouster-sdk/crc_test.json").read_text())
    flat = {
        "beam_altitude_angles": nested["beam_intrinsics"]["beam_altitude_angles"],
        "beam_azimuth_angles": nested["beam_intrinsics"]["beam_azimuth_angles"],
        "lidar_origin_to_beam_origin_mm": nested["beam_intrinsics"]["lidar_origin_to_beam_origin_mm"],
        "beam_to_lidar_transform": nested["beam_intrinsics"]["beam_to_lidar_transform"],
        "lidar_to_sensor_transform": nested["lidar_intrinsics"]["lidar_to_sensor_transform"],
        "imu_to_sensor_transform": nested["imu_intrinsics"]["imu_to_sensor_transform"],
        "data_format": nested["lidar_data_format"],
        "lidar_mode": nested["config_params"]["lidar_mode"],
        "udp_port_lidar": 7502,
        "udp_port_imu": 7503,
        **{k: nested["sensor_info"][k] for k in ("initialization_id", "prod_sn", "build_rev", "image_rev", "prod_line")},
    }
    a, b = load_metadata(nested), load_metadata(flat)
    for attr in ("pixels_per_column", "columns_per_frame", "column_window", "init_id", "serial", "packet_size", "footer_kind"):
        assert getattr(a, attr) == getattr(b, attr), attr
    assert a.profile is b.profile
    for attr in ("beam_altitude_deg", "beam_azimuth_deg", "pixel_shift_by_row", "beam_to_lidar_transform", "lidar_to_sensor_transform"):
        assert np.array_equal(getattr(a, attr), getattr(b, attr)), attr


def test_packet_sizes_of_every_profile_from_the_manual():
    """Sizes quoted in SOURCES.md for the captures (header + 16 columns + footer)."""
    assert PROFILES["LEGACY"].packet_size(32) == 6464
    assert PROFILES["LEGACY"].packet_size(64) == 12608
    assert PROFILES["LEGACY"].packet_size(128) == 24896
    assert PROFILES["RNG19_RFL8_SIG16_NIR16_DUAL"].packet_size(32) == 8448
    assert PROFILES["RNG19_RFL8_SIG16_NIR16_DUAL"].packet_size(64) == 16640
    assert PROFILES["RNG15_RFL8_NIR8"].packet_size(128) == 8448
    assert PROFILES["RNG19_RFL8_SIG16_NIR16"].packet_size(128) == 24832
    assert PROFILES["FUSA_RNG15_RFL8_NIR8_DUAL"].packet_size(128) == 16640


def test_bit_tables_cover_every_bit_once():
    for p in PROFILES.values():
        bits = np.zeros(p.pixel_bytes * 8, int)
        for f in p.pixel_fields:
            bits[f.start_bit : f.start_bit + f.width] += 1
        assert np.all(bits == 1), p.name


def _doc():
    return json.loads(external("ouster-sdk/crc_test.json").read_text())


@pytest.mark.parametrize(
    "edit,field",
    [
        (lambda d: d["beam_intrinsics"].pop("beam_altitude_angles"), "beam_altitude_angles"),
        (lambda d: d["beam_intrinsics"].pop("beam_azimuth_angles"), "beam_azimuth_angles"),
        (lambda d: d["beam_intrinsics"]["beam_azimuth_angles"].pop(), "beam_azimuth_angles"),
        (lambda d: d["beam_intrinsics"].__setitem__("beam_altitude_angles", ["x"] * 128), "beam_altitude_angles"),
        (lambda d: d["lidar_data_format"].__setitem__("pixels_per_column", "many"), "pixels_per_column"),
        (lambda d: d["lidar_data_format"].__setitem__("columns_per_frame", 500), "columns_per_frame"),
        (lambda d: d["lidar_data_format"].__setitem__("column_window", [0, 4000]), "column_window"),
        (lambda d: d["lidar_data_format"].__setitem__("column_window", "all"), "column_window"),
        (lambda d: d["lidar_data_format"].__setitem__("pixel_shift_by_row", [1, 2]), "pixel_shift_by_row"),
        (lambda d: d["lidar_data_format"].__setitem__("udp_profile_lidar", "RNG99"), "RNG99"),
        (lambda d: d["lidar_intrinsics"].__setitem__("lidar_to_sensor_transform", [1, 0, 0]), "lidar_to_sensor_transform"),
        (lambda d: d["sensor_info"].__setitem__("initialization_id", 1.5), "initialization_id"),
        (lambda d: (d["lidar_data_format"].pop("columns_per_frame"), d["config_params"].pop("lidar_mode")), "columns_per_frame"),
        (lambda d: d["config_params"].__setitem__("lidar_mode", "fast"), "lidar_mode"),
    ],
)
def test_malformed_fields_are_named(edit, field):
    doc = _doc()
    edit(doc)
    with pytest.raises(MetadataError, match=field):
        load_metadata(doc)


def test_unreadable_files(tmp_path):
    with pytest.raises(MetadataError, match="cannot read"):
        load_metadata(tmp_path / "absent.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(MetadataError, match="not valid JSON"):
        load_metadata(bad)
    lst = tmp_path / "list.json"
    lst.write_text("[1, 2]")
    with pytest.raises(MetadataError, match="JSON object"):
        load_metadata(lst)
    vlp = tmp_path / "other.json"
    vlp.write_text(json.dumps({"lasers": []}))
    with pytest.raises(MetadataError, match="beam_altitude_angles"):
        load_metadata(vlp)


def test_sensor_info_for_frames():
    md = load_metadata(external("ouster-sdk/same_ports_nonlegacy.2.json"))
    info = md.sensor_info("169.254.238.111:7502")
    assert info.vendor == "ouster" and info.model == "OS-1-64-AH" and info.rows == 64
    assert info.return_mode == "dual" and info.return_labels == ("strongest", "second_strongest")
    assert info.geometry is not None and info.grid_resolution_deg == 360 / 1024
    assert info.serial == "122239000672" and info.init_id == 9342165 and info.profile == "RNG19_RFL8_SIG16_NIR16_DUAL"
    json.dumps(info.describe())  # JSON-ready
