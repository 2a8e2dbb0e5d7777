"""ROS messages of raw packets, generic part: what a bag or MCAP reader is handed (:class:`BagMessages`: the
message types it reads packets from and the topics holding sensor files), the stamped-packet message
every vendor's unknown packets use, and rosbags type stores with the definitions a caller gives.

The vendors' own packet types (their driver packages' ``.msg`` text and extractors) are theirs: the
caller asks the vendor registry (:func:`lidarpkt.vendors.registry.bag_messages`) and hands the table
to the reader. Containers name no vendor.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np

from lidarpkt.core.vendor import Extractor

STAMPED_PACKET = "nebula_msgs/msg/NebulaPacket"
STRING = "std_msgs/msg/String"

#: Types no vendor owns, which rosbags' stock ROS 2 store lacks: the driver packages' ``.msg`` text.
DEFINITIONS: dict[str, str] = {
    # tier4/nebula, nebula_msgs: a stamped packet of any size (lidarpkt writes packets of no known stream with it)
    STAMPED_PACKET: "builtin_interfaces/Time stamp\nuint8[] data\n",
    # ros-drivers/nmea_msgs
    "nmea_msgs/msg/Sentence": "std_msgs/Header header\nstring sentence\n",
}


def stamp_ns(stamp: Any) -> int:
    """ns since the epoch of a ``builtin_interfaces/Time``."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def stamped_packet(msg: Any, bag_time_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """The packet of a ``NebulaPacket``: its stamp, else the bag's receive time."""
    t = stamp_ns(msg.stamp) or bag_time_ns
    return np.asarray(msg.data, dtype=np.uint8)[None, :], np.array([t], dtype=np.int64)


@dataclass(frozen=True)
class SensorFileTopic:
    """``std_msgs/String`` topics holding a sensor file as text (as a driver records it).

    Attributes:
        what: what the file is, for messages (``"Ouster metadata"``).
        matches: whether a topic's name is one.
        refusal: why a text found there is not such a file (``None``: it is one).
    """

    what: str
    matches: Callable[[str], bool]
    refusal: Callable[[str], str | None]


@dataclass(frozen=True)
class BagMessages:
    """What a bag or MCAP reader reads: the ``.msg`` definitions it registers (besides a file's own), the
    extractor of each packet message type, and the topics holding sensor files."""

    definitions: Mapping[str, str] = field(default_factory=lambda: dict(DEFINITIONS))
    packets: Mapping[str, Extractor] = field(default_factory=lambda: {STAMPED_PACKET: stamped_packet})
    sensor_file_topics: tuple[SensorFileTopic, ...] = ()

    def sensor_file_topic(self, topic: str) -> SensorFileTopic | None:
        """The kind of sensor file a ``std_msgs/String`` topic holds, ``None`` when it holds none."""
        return next((t for t in self.sensor_file_topics if t.matches(topic)), None)


def new_typestore(definitions: Mapping[str, str] = DEFINITIONS) -> Any:
    """A fresh rosbags type store (ROS 2 Humble) with ``definitions`` registered: a reader registers the
    definitions a file carries into it, so each reader has its own."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    types: dict = {}
    for name, text in definitions.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


def typestore(definitions: Mapping[str, str] = DEFINITIONS) -> Any:
    """A store of :func:`new_typestore` shared by every caller with the same definitions, built once, for
    encoding and decoding only (register nothing into it)."""
    return _shared(tuple(sorted(definitions.items())))


@functools.lru_cache(maxsize=8)
def _shared(definitions: tuple[tuple[str, str], ...]) -> Any:
    return new_typestore(dict(definitions))


# --- CDR of the messages written at packet rate, as NumPy byte operations -------------------------------
CDR_LE = b"\x00\x01\x00\x00"  # encapsulation: little-endian plain CDR


def pad4(n: int) -> int:
    """Bytes that align an offset ``n`` (from the byte after the encapsulation) to 4."""
    return (-n) % 4


def header_cdr(stamp_ns: int, frame_id: str) -> bytes:
    """CDR of a std_msgs/Header, from the byte after the encapsulation (offset 0), unpadded."""
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    name = frame_id.encode() + b"\x00"
    return (np.array([sec], "<i4").tobytes() + np.array([nanosec, len(name)], "<u4").tobytes() + name)


def encode_stamped_packet(payload: bytes, host_time_ns: int) -> bytes:
    """CDR of a ``nebula_msgs/msg/NebulaPacket`` (``stamp`` = host receive time)."""
    sec, nanosec = divmod(int(host_time_ns), 1_000_000_000)
    return (CDR_LE + int(sec).to_bytes(4, "little", signed=True) + int(nanosec).to_bytes(4, "little")
            + len(payload).to_bytes(4, "little") + bytes(payload))


def decode_stamped_packet(data: bytes) -> tuple[int, bytes]:
    """``(stamp_ns, payload)`` of a ``NebulaPacket`` CDR message.

    Raises:
        CaptureFormatError: the message is truncated.
    """
    from lidarpkt.errors import CaptureFormatError

    sec = int.from_bytes(data[4:8], "little", signed=True)
    nanosec = int.from_bytes(data[8:12], "little")
    n = int.from_bytes(data[12:16], "little")
    if len(data) < 16 or len(data) < 16 + n:
        raise CaptureFormatError(f"NebulaPacket says {n} bytes but holds {len(data) - 16}")
    return sec * 1_000_000_000 + nanosec, bytes(data[16:16 + n])


# --- rosbags messages of the standard types ------------------------------------------------------------
def encode(msgtype: str, message: object, store: Any = None) -> bytes:
    """CDR bytes (with the 4-byte encapsulation header) of a rosbags message object made with ``store`` (by
    default :func:`typestore`, which knows the standard types)."""
    return bytes((store or typestore()).serialize_cdr(message, msgtype))


def ros_time(ns: int, store: Any = None) -> object:
    """``builtin_interfaces/msg/Time`` of ``ns`` nanoseconds since the epoch (of ``store``, as :func:`encode`)."""
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    return (store or typestore()).types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)


def header(stamp_ns: int, frame_id: str, store: Any = None) -> object:
    """``std_msgs/msg/Header`` (of ``store``, as :func:`encode`)."""
    return (store or typestore()).types["std_msgs/msg/Header"](stamp=ros_time(stamp_ns, store), frame_id=frame_id)


def encode_string(text: str) -> bytes:
    """CDR of a ``std_msgs/msg/String``."""
    return encode(STRING, typestore().types[STRING](data=text))


IMU = "sensor_msgs/msg/Imu"


def encode_imu_samples(samples: Any, frame_id: str) -> list[bytes]:
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
