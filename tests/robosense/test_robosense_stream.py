"""The RoboSense pieces the rest of lidarpkt takes: the stream counter, the classifier, the ``info``
description, the ``robosense_msgs`` messages (out of a bag and back into CDR) and the angle CSV told
apart from other vendors' CSVs by content."""

from __future__ import annotations

import numpy as np
import pytest

from robosense_bag import CSV, FOLDER, all_packets, batches, messages
from conftest import external
from lidarpkt.core.packet import PacketBatch
from lidarpkt.errors import CalibrationError
from lidarpkt.vendors.robosense import (MESSAGE_DEFINITIONS, PacketCounter, classify, describe_stream,
                                        load_calibration, parse_calibration)
from lidarpkt.vendors.robosense import ros
from lidarpkt.vendors.robosense.stream import stream_kind


def test_the_counter_counts_packets_rotations_and_no_loss():
    counter = PacketCounter()
    starts = []
    for batch in batches():
        starts.append(counter.update(batch.payload, batch.timestamp_ns))
    c = counter.count
    assert (c.packets, c.lost, c.out_of_order, c.corrupted, c.interruptions) == (750, 0, 0, 0, 0)
    assert c.frames == 5  # the azimuth passed 0° five times
    payload, _ = all_packets()
    msop = payload[payload[:, 0] == 0x55]
    first_az = msop[:, 44].astype(int) * 256 + msop[:, 45]
    wraps = np.flatnonzero(np.diff(first_az) < -18000) + 1
    flags = np.concatenate(starts)[payload[:, 0] == 0x55]
    assert np.array_equal(np.flatnonzero(flags), wraps)
    assert stream_kind(1248) == "msop" and stream_kind(1206) is None
    with pytest.raises(Exception, match="RoboSense"):
        PacketCounter().update(np.zeros((3, 1206), np.uint8))


def test_classify_and_describe():
    msgs = messages()
    assert classify(PacketBatch.from_payloads(msgs[0].payload)) == ("msop", "helios")
    difop = msgs[3].payload[msgs[3].is_difop]
    assert classify(PacketBatch.from_payloads(difop)) == ("difop", None)
    assert classify(PacketBatch.from_payloads(np.zeros((4, 1248), np.uint8))) is None
    assert classify(PacketBatch.from_payloads(msgs[0].payload[:, :1206])) is None
    with_difop = describe_stream(PacketBatch.from_payloads(msgs[3].payload))
    assert (with_difop["model"], with_difop["return_mode"], with_difop["calibration"]) == ("RS-Helios", "strongest",
                                                                                         "DIFOP")
    assert (with_difop["packets"], with_difop["difop_packets"], with_difop["rotation_hz"]) == (150, 1, 10.0)
    assert with_difop["distance_unit_mm"] == 2.5 and with_difop["first_utc"].startswith("2017-01-06T17:48:04")
    without = describe_stream(PacketBatch.from_payloads(msgs[0].payload))
    assert without["model"] == "RS-Helios" and "DIFOP" in without["return_mode"]
    only = describe_stream(PacketBatch.from_payloads(difop))
    assert only["kind"] == "RoboSense DIFOP" and only["calibration"] == "DIFOP (32 lasers)"
    assert only["return_mode"] == "strongest" and only["return_mode_byte"] == 4
    assert only["serial_number"] == "2410bac9d50b" and (only["msop_port"], only["difop_port"]) == (6699, 7788)
    from lidarpkt.vendors.robosense.vendor import PORTS

    assert PORTS == {"msop": 6699, "difop": 7788}


def test_ros_messages_out_of_the_bag_and_back():
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    folder = external(FOLDER)
    for name in ("RobosensePacket", "RobosenseScan"):  # nebula's, the packet type named with its package
        ours = MESSAGE_DEFINITIONS[f"robosense_msgs/msg/{name}"].replace("robosense_msgs/RobosensePacket", "RobosensePacket")
        assert ours.split() == (folder / f"{name}.msg").read_text().split()
    store = get_typestore(Stores.ROS2_HUMBLE)
    types: dict = {}
    for name, text in MESSAGE_DEFINITIONS.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    for m in messages():
        ours = ros.encode_scan(m.payload, m.stamp_ns)
        msg = store.deserialize_cdr(ours, ros.SCAN_TYPE)
        payload, times = ros.packets_from_scan(msg, m.bag_time_ns)
        assert np.array_equal(payload, m.payload) and np.array_equal(times, m.stamp_ns)
        assert [bool(p.is_difop) for p in msg.packets] == m.is_difop.tolist()
        assert (msg.header.frame_id, msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec) == \
            ("robosense", int(m.stamp_ns[0]))
        assert ours == bytes(store.serialize_cdr(msg, ros.SCAN_TYPE))  # rosbags' bytes, byte for byte
    one = store.deserialize_cdr(store.serialize_cdr(msg.packets[0], ros.PACKET_TYPE), ros.PACKET_TYPE)
    payload, times = ros.packet_from_message(one, 7)
    assert payload.tobytes() == messages()[-1].payload[0].tobytes() and times[0] == messages()[-1].stamp_ns[0]
    with pytest.raises(ValueError, match="1500-byte buffer"):
        ros.encode_scan(np.zeros((1, 1501), np.uint8), np.zeros(1, np.int64))


def test_the_angle_csv_is_told_apart_by_content(tmp_path):
    """The registry tells the angle CSV from every other vendor's file by content (``metadata=``)."""
    from lidarpkt.errors import MetadataError
    from lidarpkt.vendors.registry import load_sensor_files

    path = external(CSV)
    (loaded,) = load_sensor_files([path])
    assert loaded.vendor == "robosense" and loaded.what == "RoboSense angle CSV" and loaded.loaded.lasers == 16
    hesai = sorted(external("nebula/hesai").glob("*.csv"))
    assert hesai and {f.vendor for f in load_sensor_files(hesai)} == {"hesai"}
    cal = load_calibration(path)
    assert cal.lasers == 16 and cal.elevation_deg[3] == 8.90 and cal.azimuth_offset_deg[0] == -4.05
    with pytest.raises(MetadataError, match="no such file"):
        load_sensor_files([tmp_path / "absent.csv"])
    one_column = tmp_path / "angles.csv"
    one_column.write_text("\n".join(str(15 - 2 * k) for k in range(16)) + "\n")
    assert load_sensor_files([one_column])[0].vendor == "robosense" and not load_calibration(one_column).azimuth_offset_deg.any()
    fifteen = tmp_path / "fifteen.csv"
    fifteen.write_text("1,2\n" * 15)
    with pytest.raises(MetadataError, match="not a sensor file"):
        load_sensor_files([fifteen])
    for text, why in (("1,2\n" * 15, "15 lines"), ("a,b\n" * 16, "not 'elevation,azimuth'"),
                      ("95,0\n" * 16, "out of range")):
        with pytest.raises(CalibrationError, match=why):
            parse_calibration(text, "x.csv")
    with pytest.raises(CalibrationError, match="cannot read"):
        load_calibration(tmp_path / "absent.csv")


def test_the_decoder_and_counter_meet_lidarpkts_protocols():
    from lidarpkt.core.decoder import Decoder, StreamCounter
    from lidarpkt.vendors.robosense import RobosenseDecoder

    decoder = RobosenseDecoder(model="RS-Helios")
    assert isinstance(decoder, Decoder) and isinstance(PacketCounter(), StreamCounter)
    info = decoder.sensor_info()
    assert (info.vendor, info.model, info.rows, info.return_labels) == ("robosense", "RS-Helios", 32, ("unknown",))
    assert decoder.finish() == [] and decoder.stats.packets == 0
