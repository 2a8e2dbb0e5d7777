"""Differential tests against ouster-sdk 1.0.1: every field of every frame, and XYZ, on every real capture."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from conftest import external
from lidarpkt.vendors.ouster import OusterMetadata, decode_imu, load_metadata
from lidarpkt.containers.pcap_reader import read_batches
from test_ouster_cases import CAPTURES, decode_frames

pytestmark = pytest.mark.crosscheck

# one run per (capture, single sensor metadata): the SDK refuses two sensors whose IMUs share a port
SENSOR_RUNS = [(pcap, j) for pcap, jsons, _ in CAPTURES for j in jsons]

# ours (attribute, return slot) for each SDK channel field
FIELD_MAP = {
    "RANGE": ("range_mm", 0),
    "RANGE2": ("range_mm", 1),
    "SIGNAL": ("signal", 0),
    "SIGNAL2": ("signal", 1),
    "REFLECTIVITY": ("reflectivity", 0),
    "REFLECTIVITY2": ("reflectivity", 1),
    "FLAGS": ("flags", 0),
    "FLAGS2": ("flags", 1),
    "NEAR_IR": ("near_ir", None),
}
# pixel fields that land in Frame.extra, under their names lower-cased
EXTRA_FIELDS = ("WINDOW", "ZONE_MASK", "R", "G", "B")


def sdk_frames(pcap: str, meta: str):
    sdk_pcap = pytest.importorskip("ouster.sdk.pcap")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        src = sdk_pcap.PcapFrameSetSource(str(external(pcap)), meta=[str(external(meta))])
        frames = [fs[0] for fs in src if fs[0] is not None]
        info = src.sensor_info[0]
    return frames, info


@pytest.mark.parametrize("pcap,meta", SENSOR_RUNS, ids=[f"{p.split('/')[-1]}:{m.split('/')[-1]}" for p, m in SENSOR_RUNS])
def test_frames_identical_to_ouster_sdk(pcap, meta):
    core = pytest.importorskip("ouster.sdk.core")
    theirs, info = sdk_frames(pcap, meta)
    ours, _ = decode_frames(pcap, [meta])
    assert [f.frame_id for f in ours] == [s.frame_id for s in theirs]
    lut = core.XYZLut(info, use_extrinsics=False)
    lut32 = core.XYZLutFloat(info, use_extrinsics=False)
    for mine, sdk in zip(ours, theirs):
        pixel_fields = [n for n in sdk.fields if sdk.field(n).shape == mine.range_mm.shape[1:]]
        assert set(pixel_fields) <= set(FIELD_MAP) | set(EXTRA_FIELDS), f"SDK field without a counterpart: {set(pixel_fields) - set(FIELD_MAP)}"
        for name in pixel_fields:
            if name in EXTRA_FIELDS:
                arr = mine.extra[name.lower()]
            else:
                attr, slot = FIELD_MAP[name]
                arr = getattr(mine, attr)
                arr = arr if slot is None else arr[slot]
            want = sdk.field(name)
            assert arr.dtype == want.dtype, name
            assert np.array_equal(arr, want), f"frame {mine.frame_id} field {name} differs"
        # fields the SDK does not produce for this profile are absent here too
        if "SIGNAL" not in sdk.fields:
            assert mine.signal is None
        assert mine.range_mm.shape[0] == (2 if "RANGE2" in sdk.fields else 1)
        assert np.array_equal(mine.column_timestamp_ns, sdk.timestamp.astype(np.int64))
        assert np.array_equal(mine.measurement_id, sdk.measurement_id)
        assert np.array_equal(mine.status, sdk.status)
        assert mine.partial == (not sdk.complete())
        # XYZ: the SDK's lookup table, sensor frame, metres
        for slot, name in enumerate(("RANGE", "RANGE2")[: mine.range_mm.shape[0]]):
            want = lut(sdk.field(name))
            got = mine.xyz()[slot]
            assert got.shape == want.shape
            assert np.max(np.abs(got - want)) < 1e-6, f"{name} XYZ off by {np.max(np.abs(got - want))} m"
            # float32: XYZLutFloat's values, bit for bit
            want32, got32 = lut32(sdk.field(name)), mine.xyz(np.float32)[slot]
            assert got32.dtype == want32.dtype == np.float32 and got32.shape == want32.shape
            differ = np.count_nonzero(got32.view(np.uint32) != want32.view(np.uint32))
            assert differ == 0, f"{name} float32 XYZ: {differ} coordinates differ from XYZLutFloat"


@pytest.mark.parametrize("meta", sorted({j for _, jsons, _ in CAPTURES for j in jsons} | {"ouster-sdk/imu_zm_no_lidar_0.json"}))
def test_metadata_matches_ouster_sdk(meta):
    core = pytest.importorskip("ouster.sdk.core")
    md: OusterMetadata = load_metadata(external(meta))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        info = core.SensorInfo(external(meta).read_text())
    fmt = info.format
    # udp_port_lidar 0 turns the lidar stream off: ouster-sdk says profile OFF, lidarpkt keeps the layout and says so
    assert (md.profile.name if md.lidar_enabled else "OFF") == str(fmt.udp_profile_lidar).split(".")[-1]
    assert md.pixels_per_column == fmt.pixels_per_column
    assert md.columns_per_packet == fmt.columns_per_packet
    assert md.columns_per_frame == fmt.columns_per_frame
    assert md.column_window == tuple(fmt.column_window)
    assert np.array_equal(md.pixel_shift_by_row, np.asarray(fmt.pixel_shift_by_row))
    assert np.array_equal(md.beam_altitude_deg, np.asarray(info.beam_altitude_angles))
    assert np.array_equal(md.beam_azimuth_deg, np.asarray(info.beam_azimuth_angles))
    assert np.array_equal(md.beam_to_lidar_transform, info.beam_to_lidar_transform)
    assert np.array_equal(md.lidar_to_sensor_transform, info.lidar_to_sensor_transform)
    assert np.array_equal(md.imu_to_sensor_transform, info.imu_to_sensor_transform)
    assert md.lidar_origin_to_beam_origin_mm == info.lidar_origin_to_beam_origin_mm
    assert md.init_id == info.init_id
    assert (md.serial or "0") == str(info.sn or 0)
    pf = core.PacketFormat(info)
    assert md.packet_size == pf.lidar_packet_size or not md.lidar_enabled
    # firmware 3.x: header type, IMU profile and its packet size, zone packets, return order
    assert md.header_type == (None if md.profile.legacy else str(fmt.header_type).split(".")[-1])
    assert md.imu_profile == str(fmt.udp_profile_imu).split(".")[-1]
    if md.imu_profile != "LEGACY":
        assert md.imu_measurements_per_packet == fmt.imu_measurements_per_packet
    assert md.imu_packet_size == pf.imu_packet_size
    if not md.profile.legacy:
        assert md.zone_packet_size == pf.zone_packet_size
    if info.config.return_order is not None:
        assert md.return_order == str(info.config.return_order).split(".")[-1]


@pytest.mark.parametrize("pcap,jsons", [(p, j) for p, j, _ in CAPTURES if "empty" not in p], ids=lambda x: str(x).split("/")[-1])
def test_packet_header_fields_match_ouster_sdk(pcap, jsons):
    """Header fields (frame id, init_id, serial, countdowns, alert flags) as the SDK's PacketFormat reads them."""
    core = pytest.importorskip("ouster.sdk.core")
    from lidarpkt.vendors.ouster import decode_packets
    from test_ouster_cases import lidar_streams

    checked = 0
    for md, batch in lidar_streams(pcap, jsons):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            pf = core.PacketFormat(core.SensorInfo(external(next(j for j in jsons if load_metadata(external(j)).profile is md.profile)).read_text()))
        f = decode_packets(batch.payload, md)
        checked += len(batch)
        if md.profile.legacy:  # no packet header: the frame id is the first column's
            assert [int(x) for x in f.frame_id] == [pf.frame_id(row) for row in batch.payload]
            continue
        for i, row in enumerate(batch.payload):
            assert int(f.header["frame_id"][i]) == pf.frame_id(row)
            assert int(f.header["init_id"][i]) == pf.init_id(row)
            assert int(f.header["prod_sn"][i]) == pf.prod_sn(row)
            assert int(f.header["packet_type"][i]) == pf.packet_type(row)
            assert int(f.header["countdown_thermal_shutdown"][i]) == pf.countdown_thermal_shutdown(row)
            assert int(f.header["countdown_shot_limiting"][i]) == pf.countdown_shot_limiting(row)
            assert int(f.header["alert_flags"][i]) == pf.alert_flags(row)
            if md.footer_kind == "crc":
                assert bool(f.crc_ok[i]) == (pf.crc(row) == pf.calculate_crc(row))
    assert checked > 0


@pytest.mark.parametrize("pcap,meta", [("ouster-sdk/crc_test.pcap", "ouster-sdk/crc_test.json"), ("ouster-sdk/OS-1-64_1024x10_fw20.pcap", "ouster-sdk/OS-1-64_sensor_config_reduced.json")])
def test_imu_fields_match_ouster_sdk(pcap, meta):
    core = pytest.importorskip("ouster.sdk.core")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pf = core.PacketFormat(core.SensorInfo(external(meta).read_text()))
    rows = np.concatenate([b.payload for b in read_batches(external(pcap)) if b.payload_size == 48])
    ours = decode_imu(rows)
    assert len(ours) >= 10
    for i, row in enumerate(rows):
        assert ours["sys_timestamp_ns"][i] == pf.imu_sys_ts(row)
        assert ours["accel_timestamp_ns"][i] == pf.imu_accel_ts(row)
        assert ours["gyro_timestamp_ns"][i] == pf.imu_gyro_ts(row)
        assert np.float32(pf.imu_la_x(row)) == ours["accel_x_g"][i]
        assert np.float32(pf.imu_la_y(row)) == ours["accel_y_g"][i]
        assert np.float32(pf.imu_la_z(row)) == ours["accel_z_g"][i]
        assert np.float32(pf.imu_av_x(row)) == ours["gyro_x_deg_per_s"][i]
        assert np.float32(pf.imu_av_y(row)) == ours["gyro_y_deg_per_s"][i]
        assert np.float32(pf.imu_av_z(row)) == ours["gyro_z_deg_per_s"][i]


@pytest.mark.parametrize("pcap,jsons", [(p, j) for p, j, _ in CAPTURES if "empty" not in p], ids=[p.split("/")[-1] for p, _, _ in CAPTURES if "empty" not in p])
def test_every_pixel_field_of_every_packet_matches_packet_format(pcap, jsons):
    """All channel fields the SDK's PacketFormat knows (WINDOW and RAW32 words included), packet by packet."""
    core = pytest.importorskip("ouster.sdk.core")
    from lidarpkt.vendors.ouster import decode_packets
    from lidarpkt.vendors.ouster.decode import packet_view, read_pixel_field
    from lidarpkt.vendors.ouster.digest import raw_word_fields
    from test_ouster_cases import lidar_streams

    checked = set()
    for md, batch in lidar_streams(pcap, jsons):
        meta = next(j for j in jsons if load_metadata(external(j)).profile is md.profile and load_metadata(external(j)).pixels_per_column == md.pixels_per_column)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            pf = core.PacketFormat(core.SensorInfo(external(meta).read_text()))
        f = decode_packets(batch.payload, md)
        words = packet_view(batch.payload, md.profile, md.pixels_per_column, md.columns_per_packet)["columns"]["pixels"]
        raw = {bf.name: read_pixel_field(words, bf) for bf in raw_word_fields(md.profile)}
        names = list(pf.fields)
        assert set(names) == set(md.profile.field_names) | set(raw), "field sets differ"
        for i, row in enumerate(batch.payload):
            for name in names:
                ours = f.pixels[name][i] if name in f.pixels else raw[name][i]
                theirs = pf.packet_field(name, row)  # [H, C]
                assert np.array_equal(ours.T, theirs), f"packet {i} field {name}"
                checked.add(name)
    assert checked


@pytest.mark.parametrize("pcap,meta", [SENSOR_RUNS[0], SENSOR_RUNS[1], SENSOR_RUNS[-1]], ids=lambda x: x.split("/")[-1])
def test_destagger_matches_ouster_sdk(pcap, meta):
    core = pytest.importorskip("ouster.sdk.core")
    ours, _ = decode_frames(pcap, [meta])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        info = core.SensorInfo(external(meta).read_text())
    for f in ours:
        for img in (f.range_mm[0], f.near_ir, f.reflectivity[0]):
            assert np.array_equal(f.destaggered(img), core.destagger(info, img))
