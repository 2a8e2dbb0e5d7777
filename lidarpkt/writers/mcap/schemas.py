"""The ROS 2 messages lidarpkt writes to MCAP: definitions, topics, QoS, and CDR encoding.

Every message type is declared once here, as ``.msg`` text (the messages the ROS drivers
use; the standard ``std_msgs`` / ``sensor_msgs`` / ``builtin_interfaces`` ones come from the
rosbags type store). The MCAP schema text (``ros2msg`` encoding, dependencies appended
after ``====`` lines, as rosbag2 writes it) and the CDR serialisers are derived from these
definitions by rosbags. The two messages written at packet rate — ``VelodyneScan`` and
``PacketMsg`` — also have NumPy codecs (one array operation per message instead of one
Python object per packet); the test suite checks them byte for byte against rosbags and
the official ``mcap_ros2`` decoder.

Topics (all CDR, ``ros2msg`` schemas):

================================  =====================================  ==================================
topic                             type                                   content
================================  =====================================  ==================================
``/velodyne_packets``             ``velodyne_msgs/msg/VelodyneScan``     one rotation of VLP-16 data packets;
                                                                         ``packets[i].stamp`` = host receive
                                                                         time, ``header.stamp`` = sensor time
                                                                         of the first packet
``/velodyne_position_packets``    ``nebula_msgs/msg/NebulaPacket``       one VLP-16 position packet (512 B)
                                                                         per message; ``stamp`` = host time
``/ouster/lidar_packets``         ``ouster_sensor_msgs/msg/PacketMsg``   one Ouster lidar packet per message
``/ouster/imu_packets``           ``ouster_sensor_msgs/msg/PacketMsg``   one Ouster IMU packet per message
``/ouster/metadata``              ``std_msgs/msg/String``                the sensor metadata JSON (latched)
``/ouster/imu``                   ``sensor_msgs/msg/Imu``                one IMU sample (decode, with metadata):
                                                                         m/s², rad/s, ``header.stamp`` = sensor
                                                                         time, orientation unknown
``/ouster/zone_states``           ``std_msgs/msg/String``                one zone-monitoring packet's 16 zone
                                                                         states as JSON
``/lidarpkt/other_packets``       ``nebula_msgs/msg/NebulaPacket``       datagrams of no known stream (kept,
                                                                         never dropped)
``/velodyne_points`` (``2``)      ``sensor_msgs/msg/PointCloud2``        organised frame, return slot 0 (1);
                                                                         NaN x/y/z where no return
``/ouster/points`` (``2``)        ``sensor_msgs/msg/PointCloud2``        organised frame, destaggered
``/pandar_points`` (``2``)        ``sensor_msgs/msg/PointCloud2``        Hesai frame (nebula's topic name)
``<prefix>/range_image`` (``2``)  ``sensor_msgs/msg/Image``              ``32FC1`` range in metres
``<prefix>/reflectivity_image``   ``sensor_msgs/msg/Image``              ``mono8`` reflectivity
``/gps/nmea_sentence``            ``nmea_msgs/msg/Sentence``             one verified NMEA sentence
``/tf_static``                    ``tf2_msgs/msg/TFMessage``             each sensor's mount on the base frame
                                                                         (``--base-frame``), latched
================================  =====================================  ==================================

MCAP log time is always the host receive time (ns since the Unix epoch), inside the capture's
time span: ``/ouster/metadata`` and ``/tf_static`` are logged at the first packet's time.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from lidarpkt.errors import CaptureFormatError, PacketFormatError
# the message types rosbags' store lacks (the drivers' packet types) and the store built with them: one
# table for the readers and this writer
from lidarpkt.containers.rosmsgs import MESSAGE_DEFINITIONS, typestore  # noqa: F401 (public here too)

VELODYNE_SCAN = "velodyne_msgs/msg/VelodyneScan"
PACKET_MSG = "ouster_sensor_msgs/msg/PacketMsg"
NEBULA_PACKET = "nebula_msgs/msg/NebulaPacket"
STRING = "std_msgs/msg/String"
POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
IMAGE = "sensor_msgs/msg/Image"
NMEA_SENTENCE = "nmea_msgs/msg/Sentence"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"

VELODYNE_PACKET_BYTES = 1206

# --- QoS (rosbag2's YAML form: history 3 = unknown, reliability 1/2 = reliable/best effort,
# durability 1/2 = transient local/volatile, liveliness 1 = automatic; "infinite" durations) ---
_QOS_TEMPLATE = """- history: 3
  depth: 0
  reliability: {reliability}
  durability: {durability}
  deadline:
    sec: 2147483647
    nsec: 4294967295
  lifespan:
    sec: 2147483647
    nsec: 4294967295
  liveliness: 1
  liveliness_lease_duration:
    sec: 2147483647
    nsec: 4294967295
  avoid_ros_namespace_conventions: false
"""
QOS_SENSOR_DATA = _QOS_TEMPLATE.format(reliability=2, durability=2)  # best effort, volatile
QOS_RELIABLE = _QOS_TEMPLATE.format(reliability=1, durability=2)
QOS_LATCHED = _QOS_TEMPLATE.format(reliability=1, durability=1)  # metadata: late joiners get it


@dataclass(frozen=True)
class Topic:
    """A topic lidarpkt writes: name, message type, the QoS it offers (rosbag2 YAML)."""

    name: str
    msgtype: str
    qos: str = QOS_SENSOR_DATA


VELODYNE_PACKETS = Topic("/velodyne_packets", VELODYNE_SCAN)
VELODYNE_POSITION = Topic("/velodyne_position_packets", NEBULA_PACKET)
OUSTER_LIDAR = Topic("/ouster/lidar_packets", PACKET_MSG)
OUSTER_IMU = Topic("/ouster/imu_packets", PACKET_MSG)
OUSTER_METADATA = Topic("/ouster/metadata", STRING, QOS_LATCHED)
OTHER_PACKETS = Topic("/lidarpkt/other_packets", NEBULA_PACKET)
IMU = "sensor_msgs/msg/Imu"
OUSTER_IMU_SAMPLES = Topic("/ouster/imu", IMU)
OUSTER_ZONE_STATES = Topic("/ouster/zone_states", STRING, QOS_RELIABLE)
NMEA = Topic("/gps/nmea_sentence", NMEA_SENTENCE, QOS_RELIABLE)
TF_STATIC = Topic("/tf_static", TF_MESSAGE, QOS_LATCHED)


def points_topic(vendor: str, slot: int) -> Topic:
    """PointCloud2 topic of return slot ``slot`` (0 or 1) of a ``vendor`` frame."""
    base = {"velodyne": "/velodyne_points", "hesai": "/pandar_points"}.get(vendor, "/ouster/points")
    return Topic(base + ("" if slot == 0 else str(slot + 1)), POINTCLOUD2)


def image_topic(vendor: str, field: str, slot: int) -> Topic:
    """Image topic of one field (``range``, ``reflectivity``) and return slot."""
    prefix = {"velodyne": "/velodyne", "hesai": "/pandar"}.get(vendor, "/ouster")
    return Topic(f"{prefix}/{field}_image" + ("" if slot == 0 else str(slot + 1)), IMAGE)


@functools.lru_cache(maxsize=None)
def schema_text(msgtype: str) -> str:
    """The ``ros2msg`` schema of ``msgtype`` for an MCAP Schema record (dependencies appended)."""
    text, _ = typestore().generate_msgdef(msgtype, ros_version=2)
    return text


def encode(msgtype: str, message: object) -> bytes:
    """CDR bytes (with the 4-byte encapsulation header) of a rosbags message object."""
    return bytes(typestore().serialize_cdr(message, msgtype))


def decode(msgtype: str, data: bytes) -> object:
    """A rosbags message object from CDR bytes."""
    return typestore().deserialize_cdr(data, msgtype)


def ros_time(ns: int) -> object:
    """``builtin_interfaces/msg/Time`` of ``ns`` nanoseconds since the epoch."""
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    return typestore().types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)


def header(stamp_ns: int, frame_id: str) -> object:
    """``std_msgs/msg/Header``."""
    return typestore().types["std_msgs/msg/Header"](stamp=ros_time(stamp_ns), frame_id=frame_id)


# --- CDR fast paths for the messages written at packet rate -------------------------------------
_CDR_LE = b"\x00\x01\x00\x00"  # encapsulation: little-endian plain CDR

# one VelodynePacket element of a VelodyneScan, with the 2 alignment bytes that precede the
# next element (int32 sec at a 4-aligned offset; 8 + 1206 = 1214 → next at 1216)
VELODYNE_PACKET_CDR = np.dtype(
    {"names": ["sec", "nanosec", "data"], "formats": ["<i4", "<u4", (np.uint8, VELODYNE_PACKET_BYTES)],
     "offsets": [0, 4, 8], "itemsize": 1216}
)


def _header_cdr(stamp_ns: int, frame_id: str) -> bytes:
    """CDR of a std_msgs/Header, from the byte after the encapsulation (offset 0), unpadded."""
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    name = frame_id.encode() + b"\x00"
    return (np.array([sec], "<i4").tobytes() + np.array([nanosec, len(name)], "<u4").tobytes() + name)


def _pad4(n: int) -> int:
    return (-n) % 4


def encode_velodyne_scan(payload: np.ndarray, host_time_ns: np.ndarray, stamp_ns: int,
                         frame_id: str = "velodyne") -> bytes:
    """CDR of a ``VelodyneScan`` holding ``payload`` (``uint8[N, 1206]``) received at
    ``host_time_ns`` (``int64[N]``), with ``header.stamp`` = ``stamp_ns``.

    Raises :class:`~lidarpkt.errors.PacketFormatError` if the payloads are not 1206 bytes long.
    """
    payload = np.asarray(payload, np.uint8)
    if payload.ndim != 2 or payload.shape[1] != VELODYNE_PACKET_BYTES:
        raise PacketFormatError(f"VelodyneScan packets must be 1206 bytes, got shape {payload.shape}")
    n = payload.shape[0]
    head = _header_cdr(stamp_ns, frame_id)
    head += b"\x00" * _pad4(len(head)) + np.array([n], "<u4").tobytes()
    elems = np.zeros(n, VELODYNE_PACKET_CDR)
    sec, nanosec = np.divmod(np.asarray(host_time_ns, np.int64), 1_000_000_000)
    elems["sec"] = sec
    elems["nanosec"] = nanosec
    elems["data"] = payload
    body = elems.tobytes()
    if n:
        body = body[:-2]  # no alignment after the last element
    return _CDR_LE + head + body


def decode_velodyne_scan(data: bytes | memoryview) -> tuple[int, str, np.ndarray, np.ndarray]:
    """``(header_stamp_ns, frame_id, host_time_ns int64[N], payload uint8[N, 1206])`` of a
    ``VelodyneScan`` CDR message (views into ``data`` where possible).

    Raises :class:`~lidarpkt.errors.CaptureFormatError` if the message is truncated or not
    little-endian CDR.
    """
    buf = np.frombuffer(data, np.uint8)
    if buf.size < 16 or bytes(buf[:2]) != b"\x00\x01":
        raise CaptureFormatError("a VelodyneScan message that is not little-endian CDR "
                                 f"(starts with {bytes(buf[:4]).hex(' ')})")
    body = buf[4:]
    sec, = body[0:4].view("<i4")
    nanosec, strlen = body[4:12].view("<u4")
    frame_id = bytes(body[12:12 + strlen - 1]).decode("utf-8", "replace")
    pos = 12 + int(strlen)
    pos += _pad4(pos)
    if body.size < pos + 4:
        raise CaptureFormatError("VelodyneScan message truncated in its header")
    n = int(body[pos:pos + 4].view("<u4")[0])
    pos += 4
    need = pos + n * VELODYNE_PACKET_CDR.itemsize - (2 if n else 0)
    if body.size < need:
        raise CaptureFormatError(f"VelodyneScan message says {n} packets but holds {body.size - pos} bytes of them")
    raw = body[pos:need]
    if n:
        raw = np.concatenate([raw, np.zeros(2, np.uint8)])  # restore the last element's alignment bytes
    elems = raw.view(VELODYNE_PACKET_CDR)
    host = elems["sec"].astype(np.int64) * 1_000_000_000 + elems["nanosec"].astype(np.int64)
    stamp = int(sec) * 1_000_000_000 + int(nanosec)
    return stamp, frame_id, host, np.ascontiguousarray(elems["data"])


def encode_packet_msg(payload: bytes) -> bytes:
    """CDR of an ``ouster_sensor_msgs/msg/PacketMsg`` carrying ``payload``."""
    return _CDR_LE + len(payload).to_bytes(4, "little") + bytes(payload)


def decode_packet_msg(data: bytes) -> bytes:
    """The payload of a ``PacketMsg`` CDR message. Raises :class:`CaptureFormatError` if truncated."""
    n = int.from_bytes(data[4:8], "little")
    if len(data) < 8 or len(data) < 8 + n:
        raise CaptureFormatError(f"PacketMsg says {n} bytes but holds {len(data) - 8}")
    return bytes(data[8:8 + n])


def encode_stamped_packet(payload: bytes, host_time_ns: int) -> bytes:
    """CDR of a ``nebula_msgs/msg/NebulaPacket`` (``stamp`` = host receive time)."""
    sec, nanosec = divmod(int(host_time_ns), 1_000_000_000)
    return (_CDR_LE + int(sec).to_bytes(4, "little", signed=True) + int(nanosec).to_bytes(4, "little")
            + len(payload).to_bytes(4, "little") + bytes(payload))


def decode_stamped_packet(data: bytes) -> tuple[int, bytes]:
    """``(stamp_ns, payload)`` of a ``NebulaPacket`` CDR message. Raises :class:`CaptureFormatError`
    if truncated."""
    sec = int.from_bytes(data[4:8], "little", signed=True)
    nanosec = int.from_bytes(data[8:12], "little")
    n = int.from_bytes(data[12:16], "little")
    if len(data) < 16 or len(data) < 16 + n:
        raise CaptureFormatError(f"NebulaPacket says {n} bytes but holds {len(data) - 16}")
    return sec * 1_000_000_000 + nanosec, bytes(data[16:16 + n])


def encode_imu_samples(samples, frame_id: str) -> list[bytes]:
    """One ``sensor_msgs/msg/Imu`` (CDR) per sample of :class:`lidarpkt.core.imu.ImuSamples`: ``header.stamp`` = the
    sample's time, angular velocity (rad/s) and linear acceleration (m/s²) as given, covariances unknown (0), and
    no orientation (``orientation_covariance[0] = -1``, REP 145)."""
    store = typestore()
    imu_t, vec_t, quat_t = store.types[IMU], store.types["geometry_msgs/msg/Vector3"], store.types["geometry_msgs/msg/Quaternion"]
    no_orientation = np.zeros(9)
    no_orientation[0] = -1.0
    unknown = np.zeros(9)
    out = []
    for t, a, w in zip(samples.timestamp_ns.tolist(), samples.acceleration_mps2.tolist(), samples.angular_velocity_radps.tolist()):
        msg = imu_t(header=header(t, frame_id), orientation=quat_t(x=0.0, y=0.0, z=0.0, w=0.0),
                    orientation_covariance=no_orientation, angular_velocity=vec_t(x=w[0], y=w[1], z=w[2]),
                    angular_velocity_covariance=unknown, linear_acceleration=vec_t(x=a[0], y=a[1], z=a[2]),
                    linear_acceleration_covariance=unknown)
        out.append(encode(IMU, msg))
    return out
