"""Ouster packets as ROS messages, as ouster-ros records them: ``ouster_sensor_msgs/msg/PacketMsg`` (and
``ouster_ros/msg/PacketMsg`` of ROS 1) read from bags and written to MCAP, the sensor metadata JSON on a
``std_msgs/String`` ``<namespace>/metadata`` topic, and the messages lidarpkt decodes beside the packets.

Written topics: ``/ouster/lidar_packets`` and ``/ouster/imu_packets`` (one packet per message),
``/ouster/metadata`` (the metadata JSON, latched), ``/ouster/imu`` (``sensor_msgs/msg/Imu``: one IMU
sample, m/s², rad/s, ``header.stamp`` = sensor time, orientation unknown), ``/ouster/zone_states`` (one
zone-monitoring packet's 16 zone states as JSON). Frames: ``/ouster/points`` (destaggered),
``/ouster/<field>_image``, frame id ``os_sensor``, ``intensity`` = signal.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from lidarpkt.containers.rosmsgs import CDR_LE, IMU, STRING, encode_imu_samples, encode_string
from lidarpkt.core.packet import PacketBatch
from lidarpkt.core.ros import QOS_LATCHED, QOS_RELIABLE, Topic
from lidarpkt.core.vendor import FrameTopics, LatchedMessage, Match, PacketTopic, RosMessages
from lidarpkt.errors import CaptureFormatError

PACKET_MSG = "ouster_sensor_msgs/msg/PacketMsg"
ROS1_PACKET_MSG = "ouster_ros/msg/PacketMsg"  # ouster-ros on ROS 1, before it moved its messages into ouster_sensor_msgs

DEFINITIONS = {PACKET_MSG: "uint8[] buf\n", ROS1_PACKET_MSG: "uint8[] buf\n"}
LIDAR_TOPIC = Topic("/ouster/lidar_packets", PACKET_MSG)
IMU_TOPIC = Topic("/ouster/imu_packets", PACKET_MSG)
METADATA_TOPIC = Topic("/ouster/metadata", STRING, QOS_LATCHED)
IMU_SAMPLES_TOPIC = Topic("/ouster/imu", IMU)
ZONE_STATES_TOPIC = Topic("/ouster/zone_states", STRING, QOS_RELIABLE)

# Topics holding the sensor metadata JSON (std_msgs/msg/String) as ouster-ros names them: its node's
# namespace (``/ouster``, ``/os_node``, ``/os_node0``, a user's own) then ``metadata``; every std_msgs/String
# topic named so is read (:func:`is_metadata_topic`), these are examples.
METADATA_TOPICS = ("/ouster/metadata", "/os_node/metadata", "/os_node0/metadata", "/metadata")


def is_metadata_topic(topic: str) -> bool:
    """Is ``topic`` (of type std_msgs/String) where ouster-ros records the sensor metadata: ``/metadata`` or
    any ``<namespace>/metadata``?"""
    return topic == "/metadata" or topic.endswith("/metadata")


def metadata_refusal(text: str) -> str | None:
    """Why ``text`` on a metadata topic is not the sensor metadata (``None``: it is a JSON object, as the
    metadata is; :func:`~lidarpkt.vendors.ouster.metadata_json.load_metadata` checks the rest)."""
    try:
        doc = json.loads(text)
        reason = f"a JSON {type(doc).__name__}, not an object"
    except (ValueError, RecursionError) as exc:  # not JSON; an int of > 4300 digits; nested too deep
        doc, reason = None, f"not JSON: {str(exc)[:80]}"
    return None if isinstance(doc, dict) else reason


def _packet(msg: Any, bag_time_ns: int) -> tuple[np.ndarray, np.ndarray]:
    # PacketMsg has no stamp: the bag's receive (log) time is the packet's host time
    return np.asarray(msg.buf, dtype=np.uint8)[None, :], np.array([bag_time_ns], dtype=np.int64)


def encode_packet_msg(payload: bytes, host_time_ns: int = 0) -> bytes:
    """CDR of a ``PacketMsg`` carrying ``payload`` (the message has no stamp: ``host_time_ns`` is not used)."""
    return CDR_LE + len(payload).to_bytes(4, "little") + bytes(payload)


def decode_packet_msg(data: bytes) -> bytes:
    """The payload of a ``PacketMsg`` CDR message. Raises :class:`CaptureFormatError` if truncated."""
    n = int.from_bytes(data[4:8], "little")
    if len(data) < 8 or len(data) < 8 + n:
        raise CaptureFormatError(f"PacketMsg says {n} bytes but holds {len(data) - 8}")
    return bytes(data[8:8 + n])


def sensor_file_messages(md: Any, log_time_ns: int) -> tuple[list[LatchedMessage], dict[str, str]]:
    """The metadata JSON on ``/ouster/metadata`` (one per sensor: its serial and lidar port), and the sensor's
    ``lidarpkt.sensor`` record."""
    text = json.dumps(md.raw)
    info = md.sensor_info().describe()
    record = {
        "vendor": "ouster", "model": str(info["model"]), "profile": md.profile.name,
        "columns_per_frame": str(md.columns_per_frame), "pixels_per_column": str(md.pixels_per_column),
        "lidar_port": str(md.lidar_port), "imu_port": str(md.imu_port),
        "serial": str(md.serial), "firmware": str(md.firmware),
        "sensor_info": json.dumps(info), "metadata_json": text,
    }
    return [LatchedMessage(METADATA_TOPIC, encode_string(text), f"{md.serial}:{md.lidar_port}")], record


def decoded(batch: PacketBatch, match: Match) -> list[tuple[Topic, bytes, int]]:
    """Beside the raw packets: one ``sensor_msgs/Imu`` per IMU sample (log time: its packet's receive time),
    and the zone states of zone-monitoring packets as JSON, for streams of a sensor whose metadata was given."""
    if not match.sensor_files:
        return []
    md = match.sensor_files[0]
    host = batch.timestamp_ns
    if match.kind == "imu" and batch.payload_size == md.imu_packet_size:
        from .imu import imu_samples

        samples = imu_samples(batch.payload, md, str(batch.src))
        times = host[samples.extra["packet_index"]].tolist()
        return [(IMU_SAMPLES_TOPIC, data, t) for t, data in zip(times, encode_imu_samples(samples, "os_imu"))]
    if match.kind == "zone":
        from .zone import decode_zone_packets

        states = decode_zone_packets(batch.payload, md.header_type or "STANDARD")
        return [(ZONE_STATES_TOPIC, encode_string(json.dumps(record)), t)
                for t, record in zip(host.tolist(), states.records())]
    return []


ROS = RosMessages(
    frames=FrameTopics(frame_id="os_sensor", points="/ouster/points", images="/ouster", intensity="signal"),
    definitions=DEFINITIONS,
    packets={PACKET_MSG: _packet, ROS1_PACKET_MSG: _packet},
    sensor_file_topic=is_metadata_topic,
    sensor_file_refusal=metadata_refusal,
    packet_topics={"lidar": PacketTopic(LIDAR_TOPIC, encode=encode_packet_msg),
                   "imu": PacketTopic(IMU_TOPIC, encode=encode_packet_msg)},
    sensor_file_messages=sensor_file_messages,
    decoded=decoded,
)
