"""ROS 2 recordings made by another writer (rosbags' rosbag2 writer, sqlite3 storage), holding the
topics ouster-ros and the velodyne driver publish, read back by lidarpkt.open into the same frames
as the pcap they came from."""

from __future__ import annotations

import json

import numpy as np
import pytest

import lidarpkt
from conftest import external
from lidarpkt.containers.pcap_reader import read_packets
from lidarpkt.writers.mcap import schemas
from lidarpkt.vendors.velodyne import ros as vros
from lidarpkt.vendors.ouster import ros as oros
from lidarpkt.containers import rosmsgs
from lidarpkt.core.ros import QOS_LATCHED

rosbag2 = pytest.importorskip("rosbags.rosbag2")

OS1 = "ouster-sdk/OS-1-64_1024x10_fw20.pcap"
OS1_JSON = "ouster-sdk/OS-1-64_sensor_config_reduced.json"


def _frames_equal(direct, again):
    assert len(direct) == len(again) > 0
    for a, b in zip(direct, again):
        assert a.frame_id == b.frame_id
        for name in ("range_mm", "reflectivity", "signal", "near_ir", "column_valid", "column_timestamp_ns",
                     "measurement_id", "azimuth_deg"):
            x, y = getattr(a, name), getattr(b, name)
            assert (x is None and y is None) or np.array_equal(x, y), name


def test_ouster_ros_style_rosbag2_reads_like_the_pcap(tmp_path):
    store = schemas.typestore()
    packets = list(read_packets(external(OS1)))
    bag = tmp_path / "ouster_bag"
    with rosbag2.Writer(bag) as w:
        # the metadata first, latched, as ouster-ros publishes it
        meta = w.add_connection("/ouster/metadata", rosmsgs.STRING, typestore=store,
                                offered_qos_profiles=QOS_LATCHED)
        lidar = w.add_connection("/ouster/lidar_packets", oros.PACKET_MSG, typestore=store)
        imu = w.add_connection("/ouster/imu_packets", oros.PACKET_MSG, typestore=store)
        text = json.dumps(json.loads(external(OS1_JSON).read_text()))
        w.write(meta, packets[0].timestamp_ns - 1, store.serialize_cdr(store.types[rosmsgs.STRING](data=text),
                                                                        rosmsgs.STRING))
        for p in packets:
            conn = imu if len(p.payload) == 48 else lidar
            msg = store.types[oros.PACKET_MSG](buf=np.frombuffer(p.payload, np.uint8))
            w.write(conn, p.timestamp_ns, store.serialize_cdr(msg, oros.PACKET_MSG))
    direct = list(lidarpkt.open(external(OS1), metadata=external(OS1_JSON)))
    again = list(lidarpkt.open(bag))  # metadata from the bag's /ouster/metadata
    _frames_equal(direct, again)


def test_velodyne_driver_style_rosbag2_reads_like_the_pcap(tmp_path):
    store = schemas.typestore()
    pcap = external("rust-lidar-utils/velodyne_example.pcap")
    packets = [p for p in read_packets(pcap) if len(p.payload) == 1206]
    bag = tmp_path / "velodyne_bag"
    pkt, scan = store.types["velodyne_msgs/msg/VelodynePacket"], store.types[vros.VELODYNE_SCAN]
    with rosbag2.Writer(bag) as w:
        conn = w.add_connection("/velodyne_packets", vros.VELODYNE_SCAN, typestore=store)
        for start in range(0, len(packets), 40):  # scans cut anywhere: the decoder re-frames them
            part = packets[start:start + 40]
            msg = scan(header=rosmsgs.header(part[0].timestamp_ns, "velodyne", schemas.typestore()),
                       packets=[pkt(stamp=rosmsgs.ros_time(p.timestamp_ns, schemas.typestore()), data=np.frombuffer(p.payload, np.uint8))
                                for p in part])
            w.write(conn, part[-1].timestamp_ns, store.serialize_cdr(msg, vros.VELODYNE_SCAN))
    _frames_equal(list(lidarpkt.open(pcap)), list(lidarpkt.open(bag)))
