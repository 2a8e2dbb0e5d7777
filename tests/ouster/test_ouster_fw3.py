"""Ouster firmware 3.x: every lidar profile of the manual, header types, return order, column windows,
IMU profiles and zone monitoring, against ouster-sdk 1.0.1 (test-only) and the real captures."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from conftest import external
from test_ouster_cases import decode_frames, lidar_streams

from lidarpkt.core import kernels
from lidarpkt.vendors.ouster import OusterDecoder, decode_packets, encode_packets, load_metadata
from lidarpkt.vendors.ouster.encode import empty_fields, encode_frame
from lidarpkt.vendors.ouster.imu import imu_samples
from lidarpkt.vendors.ouster.profiles import FUSA_HEADER, PROFILES, STANDARD_HEADER
from lidarpkt.vendors.ouster.bitfield import read_bits
from lidarpkt.vendors.ouster.zone import decode_zone_packets
from lidarpkt.core.packet import PacketBatch
from lidarpkt.containers.pcap_reader import read_batches

SDK = "ouster-sdk/"
SHOT = (SDK + "shot_limiting_test.pcap", [SDK + "shot_limiting_test.json"])
FUSA = (SDK + "OS-1-128_767798045_1024x10_20230712_120049.pcap", [SDK + "OS-1-128_767798045_1024x10_20230712_120049.json"])
IMU_ZM = (SDK + "imu_zm_no_lidar.pcap", SDK + "imu_zm_no_lidar_0.json")
WINDOWED = [(SDK + f"windowed_frame{i}.pcap", [SDK + f"windowed_frame{i}_0.json"]) for i in (1, 2)] + [
    (SDK + "same_ports.pcap", [SDK + "same_ports.1.json"])]


@pytest.fixture(params=["native", "numpy"])
def assembly(request, monkeypatch):
    if request.param == "numpy":
        monkeypatch.setattr(kernels, "native", None)
    return request.param


def _sdk_core():
    return pytest.importorskip("ouster.sdk.core")


def _sdk_info(doc: dict):
    core = _sdk_core()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return core.SensorInfo(json.dumps(doc))


# ----------------------------------------------------------------------------- packet header layouts


@pytest.mark.parametrize("capture,header_type", [(SHOT, "STANDARD"), (FUSA, "FUSA")], ids=["STANDARD", "FUSA"])
def test_header_layout_is_pinned_by_the_real_captures(capture, header_type):
    """The manual's tables and ouster-sdk 1.0.1 place frame_id and init_id differently in the STANDARD header.
    Evidence: in shot_limiting_test (STANDARD, firmware 3.2) the 24 bits at bit 32 read 15109686 and the 40 bits at
    bit 56 read 122406002141, the metadata's initialization_id and prod_sn, with packet_type 1 in bits 0-15 and
    frame_id in bits 16-31 (ouster-sdk's layout); in the FUSA capture (firmware 3.1) init_id is bits 8-31 (390076),
    frame_id bits 32-63 (229, the frame ouster-sdk reports), prod_sn bits 88-127. The other layout reads neither."""
    md, batch = lidar_streams(*capture)[0]
    assert md.header_type == header_type
    head = batch.payload[:, :32]
    for fields, ok in ((STANDARD_HEADER, header_type == "STANDARD"), (FUSA_HEADER, header_type == "FUSA")):
        f = {b.name: b for b in fields}
        ids_match = (read_bits(head, f["init_id"]) == md.init_id).all() and (
            read_bits(head, f["prod_sn"]) == md.serial_int).all()
        assert ids_match == ok
        if ok:
            assert (read_bits(head, f["packet_type"]) == 1).all()
    frame_id = int(decode_packets(batch.payload, md).frame_id[0])
    assert frame_id == {"STANDARD": 9496, "FUSA": 229}[header_type]


def test_shot_limiting_header_fields_are_decoded_and_in_the_frame():
    core = _sdk_core()
    md, batch = lidar_streams(*SHOT)[0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pf = core.PacketFormat(core.SensorInfo(external(SHOT[1][0]).read_text()))
    f = decode_packets(batch.payload, md)
    row = batch.payload[0]
    assert int(f.header["shot_limiting"][0]) == int(pf.shot_limiting(row).value) == 1
    assert int(f.header["thermal_shutdown"][0]) == int(pf.thermal_shutdown(row).value) == 1
    assert int(f.header["countdown_thermal_shutdown"][0]) == pf.countdown_thermal_shutdown(row) == 5
    assert int(f.header["countdown_shot_limiting"][0]) == pf.countdown_shot_limiting(row)
    assert int(f.header["alert_flags"][0]) == pf.alert_flags(row)
    (frame,), decs = decode_frames(*SHOT)
    cols = frame.column_valid
    assert (frame.extra["shot_limiting"][cols] == 1).all() and (frame.extra["thermal_shutdown"][cols] == 1).all()
    assert (frame.extra["shot_limiting"][~cols] == 0).all()
    (dec,) = decs.values()
    assert dec.stats.shot_limiting_packets == dec.stats.thermal_shutdown_packets == 1


# ----------------------------------------------------------------------------- metadata of firmware 3.x


def test_return_order_labels_the_slots_and_is_in_frame_sensor():
    core = _sdk_core()
    (frame,), _ = decode_frames(*SHOT)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        info = core.SensorInfo(external(SHOT[1][0]).read_text())
    assert str(info.config.return_order).endswith("FARTHEST_TO_NEAREST")
    assert frame.sensor.return_order == "FARTHEST_TO_NEAREST"
    assert frame.return_labels == frame.sensor.return_labels == ("farthest",)
    md = load_metadata(external(SHOT[1][0]))
    assert md.imu_profile == "ACCEL32_GYRO32_NMEA" and md.timestamp_mode == "TIME_FROM_INTERNAL_OSC"
    assert md.azimuth_window == (0, 360000) and md.header_type == "STANDARD"
    # a dual profile under each order
    doc = json.loads(external(SDK + "same_ports.1.json").read_text())
    for order, labels in (("NEAREST_TO_FARTHEST", ("nearest", "second_nearest")),
                          ("STRONGEST_TO_WEAKEST", ("strongest", "second_strongest"))):
        doc["config_params"]["return_order"] = order
        assert load_metadata(doc).return_labels == labels


@pytest.mark.parametrize("pcap,jsons", WINDOWED, ids=lambda x: str(x).split("/")[-1])
def test_columns_outside_the_window_are_not_lost(pcap, jsons, assembly):
    frames, decoders = decode_frames(pcap, jsons, soft_id_check=False)
    md = load_metadata(external(jsons[0]))
    assert md.column_window != (0, md.columns_per_frame - 1)
    assert frames
    for f in frames:
        assert f.counters.lost_packets == 0
        assert not f.column_valid[~md.window_mask].any()
    assert sum(d.stats.lost_packets for d in decoders.values()) == 0
    if "windowed" in pcap:  # each holds one whole window
        assert [f.partial for f in frames] == [False]
        assert frames[0].column_valid[md.window_mask].all()


# ----------------------------------------------------------------------------- profiles without a capture

NO_CAPTURE = ["RNG15_RFL8_NIR8_DUAL", "RNG15_RFL8_NIR8_ZONE16", "RNG19_RFL8_SIG16_NIR16_ZONE16",
              "RNG19_RFL8_SIG16_ZONE16_DUAL", "RNG19_RFL8_SIG16_NIR16_RGB16", "RNG19_RFL8_SIG16_NIR16_RGB16_DUAL",
              "RNG15_RFL8_WIN8", "FIVE_WORD_PIXEL"]


def _metadata_doc(profile: str, h: int = 32, header_type: str = "STANDARD") -> dict:
    """shot_limiting_test.json (firmware 3.2) turned into a sensor of ``profile`` with ``h`` beams."""
    doc = json.loads(external(SHOT[1][0]).read_text())
    for section in ("lidar_data_format", "config_params"):
        doc[section]["udp_profile_lidar"] = profile
        doc[section]["header_type"] = header_type
    doc["lidar_data_format"]["pixels_per_column"] = h
    doc["lidar_data_format"]["pixel_shift_by_row"] = doc["lidar_data_format"]["pixel_shift_by_row"][:h]
    for key in ("beam_altitude_angles", "beam_azimuth_angles"):
        doc["beam_intrinsics"][key] = doc["beam_intrinsics"][key][:h]
    doc["config_params"]["return_order"] = "STRONGEST_TO_WEAKEST"
    return doc


def _compare_with_sdk(payload: np.ndarray, md, info) -> int:
    core = _sdk_core()
    pf = core.PacketFormat(info)
    assert pf.lidar_packet_size == md.packet_size == payload.shape[1]
    ours = decode_packets(payload, md, verify_crc=False)
    sdk_names = set(pf.fields)
    assert set(md.profile.field_names) <= sdk_names
    assert {n for n in sdk_names if not n.startswith("RAW") and n != "RGB"} == set(md.profile.field_names)
    for i, row in enumerate(payload):
        for name in md.profile.field_names:
            theirs = pf.packet_field(name, row)  # [H, C]
            assert ours.pixels[name][i].dtype == theirs.dtype, name
            assert np.array_equal(ours.pixels[name][i].T, theirs), f"packet {i} field {name}"
        assert int(ours.header["frame_id"][i]) == pf.frame_id(row)
        assert int(ours.header["init_id"][i]) == pf.init_id(row)
        assert int(ours.header["prod_sn"][i]) == pf.prod_sn(row)
        assert int(ours.header["shot_limiting"][i]) == int(pf.shot_limiting(row).value)
    return len(payload)


@pytest.mark.parametrize("name", NO_CAPTURE)
def test_profile_from_the_encoder_and_from_random_bytes_reads_as_ouster_sdk(name):
    doc = _metadata_doc(name)
    md, info = load_metadata(doc), _sdk_info(doc)
    assert md.profile.name == name and md.profile is PROFILES[name]
    rng = np.random.default_rng(len(name))
    n = 3
    # 1. the encoder: random values in every field of the profile
    fields = empty_fields(md, n)
    for f in md.profile.pixel_fields:
        if not f.reserved:
            fields.pixels[f.name] = (rng.integers(0, f.mask + 1, fields.pixels[f.name].shape, dtype=np.uint64)
                                     << np.uint64(f.upshift)).astype(f.dtype)
    fields.measurement_id[:] = np.arange(n * md.columns_per_packet).reshape(n, -1)
    fields.status[:] = 1
    fields.header["frame_id"] = np.arange(n, dtype=np.uint32) + 7
    encoded = encode_packets(fields, md)
    assert _compare_with_sdk(encoded, md, info) == n
    again = decode_packets(encoded, md)
    for k in md.profile.field_names:
        assert np.array_equal(again.pixels[k], fields.pixels[k]), k
    # 2. random bytes under a valid header (packet type 1, the metadata's init_id and serial)
    head = encoded[:, :32]
    random = rng.integers(0, 256, encoded.shape, dtype=np.uint8)
    random[:, :32] = head
    assert _compare_with_sdk(random, md, info) == n


@pytest.mark.parametrize("name", NO_CAPTURE)
def test_frames_of_every_profile_hold_every_field(name, assembly):
    """Frames assembled from encoded packets (both paths; 20-byte pixels always take the NumPy twin) hold every
    field of the profile: the slot fields, NEAR_IR, and the others in Frame.extra; frame → packets → frame is exact."""
    doc = _metadata_doc(name, h=16)
    doc["lidar_data_format"]["columns_per_frame"] = 64
    doc["lidar_data_format"]["column_window"] = [0, 63]
    doc["config_params"]["lidar_mode"] = "512x10"
    md = load_metadata(doc)
    rng = np.random.default_rng(len(name) + 1)
    n = 4
    fields = empty_fields(md, n)
    for f in md.profile.pixel_fields:
        if not f.reserved:
            fields.pixels[f.name] = (rng.integers(0, f.mask + 1, fields.pixels[f.name].shape, dtype=np.uint64)
                                     << np.uint64(f.upshift)).astype(f.dtype)
    fields.measurement_id[:] = np.arange(64).reshape(n, -1)
    fields.timestamp_ns[:] = np.arange(64).reshape(n, -1) * 1000 + 10**9
    fields.status[:] = 1
    fields.header["frame_id"] = np.full(n, 3, np.uint32)
    fields.header["shot_limiting"] = np.array([0, 2, 0, 9], np.uint8)
    payload = encode_packets(fields, md)
    dec = OusterDecoder(md)
    (frame,) = dec.push(PacketBatch.from_payloads(payload)) + dec.finish()
    assert not frame.partial and frame.column_valid.all()

    def image(name):  # [N, C, H] -> [H, W]
        return fields.pixels[name].reshape(-1, md.pixels_per_column).T

    slot_of = {"RANGE": ("range_mm", 0), "RANGE2": ("range_mm", 1), "REFLECTIVITY": ("reflectivity", 0),
               "REFLECTIVITY2": ("reflectivity", 1), "SIGNAL": ("signal", 0), "SIGNAL2": ("signal", 1),
               "FLAGS": ("flags", 0), "FLAGS2": ("flags", 1)}
    for k in md.profile.field_names:
        if k in slot_of:
            attr, slot = slot_of[k]
            got = getattr(frame, attr)[slot]
        elif k == "NEAR_IR":
            got = frame.near_ir
        else:
            got = frame.extra[k.lower()]
        assert got.dtype == fields.pixels[k].dtype and np.array_equal(got, image(k)), k
    assert np.array_equal(frame.extra["shot_limiting"], np.repeat([0, 2, 0, 9], 16))
    assert np.array_equal(encode_frame(frame, md), payload)


def test_rng15_dual_under_a_fusa_header_is_the_deprecated_fusa_profile():
    """header_type FUSA (firmware 3.2) with RNG15_RFL8_NIR8_DUAL reads the bytes of the older
    FUSA_RNG15_RFL8_NIR8_DUAL name exactly; ouster-sdk agrees."""
    md_old, batch = lidar_streams(*FUSA)[0]
    doc = json.loads(external(FUSA[1][0]).read_text())
    doc["lidar_data_format"]["udp_profile_lidar"] = doc["config_params"]["udp_profile_lidar"] = "RNG15_RFL8_NIR8_DUAL"
    doc["lidar_data_format"]["header_type"] = "FUSA"
    md_new = load_metadata(doc)
    assert md_new.profile.header_type == "FUSA" and md_new.footer_kind == "zero"
    a, b = decode_packets(batch.payload, md_old), decode_packets(batch.payload, md_new)
    assert all(np.array_equal(a.pixels[k], b.pixels[k]) for k in a.pixels)
    assert all(np.array_equal(a.header[k], b.header[k]) for k in a.header)
    assert _compare_with_sdk(batch.payload, md_new, _sdk_info(doc)) == len(batch)


# ----------------------------------------------------------------------------- IMU and zone monitoring


def _packets(pcap: str, size: int) -> np.ndarray:
    return np.concatenate([b.payload for b in read_batches(external(pcap)) if b.payload_size == size])


def test_accel32_gyro32_nmea_samples_equal_ouster_sdk():
    core = _sdk_core()
    md = load_metadata(external(IMU_ZM[1]))
    rows = _packets(IMU_ZM[0], md.imu_packet_size)
    assert rows.shape == (8, 452)
    ours = imu_samples(rows, md)
    assert len(ours) == 64
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pf = core.PacketFormat(core.SensorInfo(external(IMU_ZM[1]).read_text()))
    acc, gyro, ts = [], [], []
    for row in rows:
        p = core.ImuPacket(pf)
        p.buf[:] = row
        acc.append(p.accel())
        gyro.append(p.gyro())
        ts.append(p.timestamp())
    acc, gyro, ts = np.concatenate(acc), np.concatenate(gyro), np.concatenate(ts)
    assert np.array_equal(ours.acceleration_mps2, acc.astype(np.float64))  # float32 on the wire, exact
    assert np.array_equal(ours.angular_velocity_radps, gyro.astype(np.float64))
    assert np.array_equal(ours.timestamp_ns, ts.astype(np.int64))
    assert np.all(np.abs(np.linalg.norm(ours.acceleration_mps2, axis=1) - 9.81) < 0.4)  # a sensor at rest
    assert (ours.extra["measurement_id"] == np.arange(31, 64 * 32, 32)).all()


def test_legacy_imu_of_the_os2_reads_gravity_at_rest():
    md = load_metadata(external(SDK + "OS-2-128-U1_v2.3.0_1024x10.json"))
    s = imu_samples(_packets(SDK + "OS-2-128-U1_v2.3.0_1024x10.pcap", 48), md)
    assert len(s) == 10
    g = np.linalg.norm(s.acceleration_mps2, axis=1)
    assert abs(g.mean() - 9.81) < 0.2 and np.all(np.abs(g - 9.81) < 0.5), g  # accelerometer noise ~0.1 m/s²
    assert np.all(np.abs(s.angular_velocity_radps) < 0.1)  # at rest: gyroscope noise only
    assert np.array_equal(s.timestamp_ns, s.extra["gyro_timestamp_ns"])


def test_legacy_imu_matches_ouster_sdk_units():
    core = _sdk_core()
    meta = SDK + "OS-2-128-U1_v2.3.0_1024x10.json"
    md = load_metadata(external(meta))
    rows = _packets(SDK + "OS-2-128-U1_v2.3.0_1024x10.pcap", 48)
    ours = imu_samples(rows, md)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pf = core.PacketFormat(core.SensorInfo(external(meta).read_text()))
    for i, row in enumerate(rows):
        p = core.ImuPacket(pf)
        p.buf[:] = row
        # ouster-sdk multiplies in float32; ours in float64 from the same float32 reading
        assert np.allclose(ours.acceleration_mps2[i], p.accel()[0], rtol=1e-6, atol=0)
        assert np.allclose(ours.angular_velocity_radps[i], p.gyro()[0], rtol=1e-6, atol=1e-12)
        assert ours.timestamp_ns[i] == p.timestamp()[0]


def _sdk_batched(rows: np.ndarray, packet_type: str):
    """ouster-sdk's FrameBatcher fed the packets ``rows`` (IMU or zone) of imu_zm_no_lidar: its LidarFrame."""
    core = _sdk_core()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        info = core.SensorInfo(external(IMU_ZM[1]).read_text())
    pf = core.PacketFormat(info)
    batcher, frame = core.FrameBatcher(info), core.LidarFrame(info)
    for row in rows:
        p = getattr(core, packet_type)(pf)
        p.buf[:] = row
        batcher.batch(p, frame)
    return frame


def test_imu_samples_equal_ouster_sdk_imu_acc_and_gyro_fields():
    md = load_metadata(external(IMU_ZM[1]))
    rows = _packets(IMU_ZM[0], md.imu_packet_size)
    ours = imu_samples(rows, md)
    frame = _sdk_batched(rows, "ImuPacket")
    acc, gyro, ts = frame.field("IMU_ACC"), frame.field("IMU_GYRO"), frame.field("IMU_TIMESTAMP")
    assert acc.shape == (64, 3) and len(ours) == 64
    assert np.array_equal(ours.acceleration_mps2, acc.astype(np.float64))
    assert np.array_equal(ours.angular_velocity_radps, gyro.astype(np.float64))
    assert np.array_equal(ours.timestamp_ns, ts.astype(np.int64))


def test_zone_states_equal_ouster_sdk():
    md = load_metadata(external(IMU_ZM[1]))
    rows = _packets(IMU_ZM[0], md.zone_packet_size)
    assert len(rows) == 1
    z = decode_zone_packets(rows)
    frame = _sdk_batched(rows, "ZonePacket")  # the field is a view into the frame: keep it alive
    states = frame.field("ZONE_STATES").copy()
    assert len(states) == 16
    names = {"min_range_mm": "min_range", "max_range_mm": "max_range", "mean_range_mm": "mean_range"}
    assert {names.get(k, k) for k in z.zones} == set(states.dtype.names)
    for k, v in z.zones.items():
        assert np.array_equal(v[0].astype(np.int64), states[names.get(k, k)].astype(np.int64)), k
    assert int(z.zones["live"].sum()) > 0  # not a test of zeros


def test_imu_and_zone_packets_without_lidar_give_no_frame_and_no_error():
    import lidarpkt

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        reader = lidarpkt.open(external(IMU_ZM[0]), metadata=str(external(IMU_ZM[1])))
        frames = list(reader)
    assert frames == []
    assert reader.stats.packets_of("ouster", "imu") == 8 and reader.stats.packets_of("ouster", "zone") == 1
    (dec,) = reader.decoders.values()
    assert len(dec.imu_samples()) == 64 and dec.stats.zone_packets == 1
    (states,) = dec.zone_states()
    assert states.zones["live"].shape == (1, 16) and int(states.header["packet_type"][0]) == 3


def test_info_names_imu_and_zone_packets(tmp_path):
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-m", "lidarpkt", "info", str(external(IMU_ZM[0])), "--metadata",
                          str(external(IMU_ZM[1]))], capture_output=True, text=True, timeout=60, check=False)
    assert out.returncode == 0, out.stderr
    text = out.stdout + out.stderr
    assert "Ouster IMU" in text and "ACCEL32_GYRO32_NMEA" in text and "zone monitoring" in text


@pytest.mark.parametrize("pcap,meta,samples", [
    (IMU_ZM[0], IMU_ZM[1], 64), (SDK + "OS-2-128-U1_v2.3.0_1024x10.pcap", SDK + "OS-2-128-U1_v2.3.0_1024x10.json", 10)])
def test_decode_writes_one_imu_message_per_sample(tmp_path, pcap, meta, samples):
    import subprocess
    import sys

    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out = tmp_path / "o.mcap"
    run = subprocess.run([sys.executable, "-m", "lidarpkt", "decode", str(external(pcap)), "--metadata",
                          str(external(meta)), "-o", str(out), "--quiet"], capture_output=True, text=True, timeout=120, check=False)
    assert run.returncode == 0, run.stderr
    md = load_metadata(external(meta))
    want = imu_samples(_packets(pcap, md.imu_packet_size), md)
    got, zones = [], []
    with open(out, "rb") as fh:  # read with the official MCAP ROS 2 decoder, not ours
        for schema, channel, _, msg in make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
                topics=["/ouster/imu", "/ouster/zone_states"]):
            if channel.topic == "/ouster/imu":
                assert schema.name == "sensor_msgs/msg/Imu"
                got.append((msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec,
                            (msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z),
                            (msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z),
                            msg.orientation_covariance[0]))
            else:
                zones.append(json.loads(msg.data))
    assert len(got) == samples == len(want)
    assert [g[0] for g in got] == want.timestamp_ns.tolist()
    assert np.array_equal(np.array([g[1] for g in got]), want.acceleration_mps2)
    assert np.array_equal(np.array([g[2] for g in got]), want.angular_velocity_radps)
    assert all(g[3] == -1.0 for g in got)  # no orientation
    acc = np.linalg.norm(np.array([g[1] for g in got]), axis=1)
    assert abs(acc.mean() - 9.81) < 0.2  # m/s², at rest
    if "imu_zm" in pcap:
        (z,) = zones
        assert len(z["zones"]) == 16 and sum(x["live"] for x in z["zones"]) == 4


# ----------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("key,value,match", [
    ("header_type", "WIDE", "header_type 'WIDE'"),
    ("return_order", "LOUDEST_FIRST", "return_order 'LOUDEST_FIRST'"),
    ("azimuth_window", [0, 400000], "azimuth_window"),
    ("udp_port_zm", 70000, "udp_port_zm"),
])
def test_bad_fw3_metadata_fields_are_named(key, value, match):
    from lidarpkt.errors import MetadataError

    doc = json.loads(external(SHOT[1][0]).read_text())
    doc["config_params"][key] = value
    if key == "header_type":
        doc["lidar_data_format"][key] = value
    with pytest.raises(MetadataError, match=match):
        load_metadata(doc)


def test_an_unknown_imu_profile_keeps_the_lidar_data(tmp_path):
    import lidarpkt

    doc = json.loads(external(SHOT[1][0]).read_text())
    doc["lidar_data_format"]["udp_profile_imu"] = doc["config_params"]["udp_profile_imu"] = "ACCEL64_GYRO64"
    md = load_metadata(doc)
    assert md.imu_packet_size is None
    (tmp_path / "m.json").write_text(json.dumps(doc))
    frames = list(lidarpkt.open(external(SHOT[0]), metadata=str(tmp_path / "m.json"), include_partial=True))
    assert len(frames) == 1 and frames[0].column_valid.sum() == 16


def test_wrong_sizes_and_junk_give_clear_errors_or_counts():
    from hypothesis import given, settings, strategies as st

    from lidarpkt.errors import PacketFormatError
    from lidarpkt.vendors.ouster.imu import decode_imu_nmea

    md = load_metadata(external(IMU_ZM[1]))
    with pytest.raises(PacketFormatError, match="452 bytes"):
        decode_imu_nmea(np.zeros((2, 451), np.uint8), 8)
    with pytest.raises(PacketFormatError, match="680 bytes"):
        decode_zone_packets(np.zeros((1, 600), np.uint8))
    dec = OusterDecoder(md)
    dec.push_imu(PacketBatch.from_payloads(np.zeros((3, 451), np.uint8)))
    dec.push_zone(PacketBatch.from_payloads(np.zeros((2, 679), np.uint8)))
    assert dec.stats.size_mismatch == 5 and len(dec.imu_samples()) == 0 and dec.zone_states() == []

    @settings(max_examples=40, deadline=None)
    @given(st.binary(min_size=452, max_size=452), st.binary(min_size=680, max_size=680))
    def junk(imu: bytes, zone: bytes):
        s = imu_samples(np.frombuffer(imu, np.uint8), md)  # NaN or huge floats are values, not errors
        measurements = np.frombuffer(imu, np.uint8)[132:420].reshape(8, 36)  # after header and NMEA block
        assert len(s) == int((measurements[:, 10] & 1).sum())  # status bit 0: valid
        z = decode_zone_packets(zone)
        assert z.zones["min_range_mm"].max() < 1 << 19

    junk()
