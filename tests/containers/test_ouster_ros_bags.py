"""Bags written by ouster-ros (ROS 1 ``ouster_ros/PacketMsg``, ROS 2 ``ouster_sensor_msgs/msg/PacketMsg``): decoded
with the metadata the bag records, equal to ouster-sdk 1.0.1's reading of the same bag."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import lidarpkt
from conftest import external
from lidarpkt.containers.bags import BagReader
from lidarpkt.vendors.registry import bag_messages
from lidarpkt.vendors.ouster.ros import is_metadata_topic as is_ouster_metadata_topic

BAG = "ouster-sdk/512x10_raw.bag"  # ouster-ros ROS 1: /os_node0/{lidar,imu}_packets, /os_node0/metadata

# ours (attribute, return slot) for each SDK channel field
FIELD_MAP = {"RANGE": ("range_mm", 0), "RANGE2": ("range_mm", 1), "SIGNAL": ("signal", 0), "SIGNAL2": ("signal", 1),
             "REFLECTIVITY": ("reflectivity", 0), "REFLECTIVITY2": ("reflectivity", 1), "FLAGS": ("flags", 0),
             "FLAGS2": ("flags", 1), "NEAR_IR": ("near_ir", None)}


def sdk_bag(path):
    """ouster-sdk's frames of a bag (open_source reads the metadata topic itself) and its IMU packets' bytes."""
    sdk = pytest.importorskip("ouster.sdk")
    bag = pytest.importorskip("ouster.sdk.bag")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        frames = [f for fs in sdk.open_source(str(path)) for f in fs if f is not None]
        packets = [item[1] if isinstance(item, tuple) else item for item in bag.BagPacketSource(str(path))]
        imu = [bytes(p.buf) for p in packets if type(p).__name__ == "ImuPacket"]
    return frames, imu


def assert_frames_equal_sdk(ours, theirs):
    assert [f.frame_id for f in ours] == [f.frame_id for f in theirs]
    for mine, sdk in zip(ours, theirs):
        assert set(sdk.fields) <= set(FIELD_MAP)
        for name in sdk.fields:
            attr, slot = FIELD_MAP[name]
            arr = getattr(mine, attr)
            arr = arr if slot is None else arr[slot]
            assert np.array_equal(arr, sdk.field(name)), f"frame {mine.frame_id} field {name}"
        np.testing.assert_array_equal(mine.column_timestamp_ns, sdk.timestamp.astype(np.int64))
        np.testing.assert_array_equal(mine.measurement_id, sdk.measurement_id)
        np.testing.assert_array_equal(mine.status, sdk.status)
        assert mine.partial == (not sdk.complete())


@pytest.mark.crosscheck
def test_ouster_ros1_bag_decodes_without_metadata_to_ouster_sdk_frame():
    path = external(BAG)
    theirs, imu = sdk_bag(path)
    with lidarpkt.open(path) as reader:
        ours = list(reader)
    assert len(ours) == 1 and not ours[0].partial
    assert_frames_equal_sdk(ours, theirs)
    # every packet routed: the metadata is recorded after the first lidar packet and still serves it
    st = reader.stats
    assert (st.packets_of("ouster", "lidar"), st.packets_of("ouster", "imu"), st.unrouted_packets) == (32, 10, 0)
    (decoder,) = reader.decoders.values()
    assert len(decoder.imu_samples()) == len(imu) == 10
    routed = [bytes(b.payload[i]) for b in BagReader(path, messages=bag_messages()).batches() if b.payload_size == 48 for i in range(len(b))]
    assert routed == imu


def _ros2_messages(src):
    """The messages of the ROS 1 ouster-ros bag as ouster-ros 2 records them, in the same time order:
    ``(topic, type, time ns, fields)``, packets as ouster_sensor_msgs/msg/PacketMsg on /ouster/*_packets, the
    metadata as a std_msgs/msg/String on /ouster/metadata."""
    from rosbags.highlevel import AnyReader

    with AnyReader([src]) as reader:
        for conn, t, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            topic = "/ouster/" + conn.topic.rsplit("/", 1)[1]
            if conn.msgtype == "std_msgs/msg/String":
                yield topic, "std_msgs/msg/String", t, {"data": msg.data}
            else:
                yield topic, "ouster_sensor_msgs/msg/PacketMsg", t, {"buf": np.asarray(msg.buf, np.uint8)}


def _as_rosbag2(src, dst):
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore, get_types_from_msg

    store = get_typestore(Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg("uint8[] buf\n", "ouster_sensor_msgs/msg/PacketMsg"))
    with Writer(dst) as writer:
        conns = {}
        for topic, kind, t, fields in _ros2_messages(src):
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, kind, typestore=store)
            writer.write(conns[topic], t, store.serialize_cdr(store.types[kind](**fields), kind))
    return dst


def _as_mcap(src, dst):
    from mcap_ros2.writer import Writer

    defs = {"ouster_sensor_msgs/msg/PacketMsg": "uint8[] buf", "std_msgs/msg/String": "string data"}
    with open(dst, "wb") as fh:
        writer = Writer(fh)
        schemas = {k: writer.register_msgdef(k, v) for k, v in defs.items()}
        for topic, kind, t, fields in _ros2_messages(src):
            if kind != "std_msgs/msg/String":
                fields = {"buf": bytes(fields["buf"])}
            writer.write_message(topic, schemas[kind], fields, log_time=t, publish_time=t)
        writer.finish()
    return dst


@pytest.mark.crosscheck
@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_ouster_ros2_bag_decodes_like_the_ros1_one(tmp_path, storage):
    path = external(BAG)
    theirs, _ = sdk_bag(path)
    bag2 = _as_rosbag2(path, tmp_path / "ros2") if storage == "sqlite3" else _as_mcap(path, tmp_path / "ros2.mcap")
    with lidarpkt.open(bag2) as reader:
        ours = list(reader)
    assert_frames_equal_sdk(ours, theirs)
    assert (reader.stats.packets_of("ouster", "lidar"), reader.stats.packets_of("ouster", "imu")) == (32, 10)


def test_metadata_topics_are_any_namespace():
    assert all(is_ouster_metadata_topic(t) for t in ("/metadata", "/ouster/metadata", "/os_node0/metadata", "/a/b/metadata"))
    assert not any(is_ouster_metadata_topic(t) for t in ("/ouster/metadata_raw", "/metadatax", "metadata/x"))


def test_bag_without_metadata_topic_still_asks_for_metadata(tmp_path):
    """The same bag without its metadata topic: the packets are there, the error asks for --metadata."""
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag1 import Writer

    src = external(BAG)
    dst = tmp_path / "no_metadata.bag"
    with AnyReader([src]) as reader, Writer(dst) as writer:
        conns = {}
        for conn, t, raw in reader.messages():
            if conn.topic.endswith("/metadata"):
                continue
            if conn.topic not in conns:
                conns[conn.topic] = writer.add_connection(conn.topic, conn.msgtype, msgdef=conn.msgdef,
                                                          md5sum=conn.digest)
            writer.write(conns[conn.topic], t, raw)
    from lidarpkt.errors import UnknownSensorError

    with pytest.raises(UnknownSensorError, match="metadata"):
        list(lidarpkt.open(dst))
