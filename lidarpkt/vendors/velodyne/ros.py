"""Velodyne packets as ROS messages: the ``velodyne_msgs`` of ros-drivers/velodyne (read from bags,
written to MCAP), the NumPy codec of ``VelodyneScan`` (one array operation per scan, checked byte for
byte against rosbags and ``mcap_ros2``), and what the MCAP writer records of a stream.

Written topics: ``/velodyne_packets`` (``velodyne_msgs/msg/VelodyneScan``: one rotation of data
packets; ``packets[i].stamp`` = host receive time, ``header.stamp`` = sensor time of the first packet)
and ``/velodyne_position_packets`` (``nebula_msgs/msg/NebulaPacket``: one 512-byte position packet per
message, ``stamp`` = host time). Frames: ``/velodyne_points``, ``/velodyne/<field>_image``, frame id
``velodyne``, ``ring`` counted from the lowest beam as the ROS driver does.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from lidarpkt.containers.rosmsgs import CDR_LE, STAMPED_PACKET, encode_stamped_packet, header_cdr, pad4, stamp_ns
from lidarpkt.core.packet import PacketBatch
from lidarpkt.core.ros import Topic
from lidarpkt.core.vendor import FrameTopics, PacketTopic, RosMessages
from lidarpkt.errors import CaptureFormatError, PacketFormatError
from .clock import in_nearest_hour_ns

VELODYNE_SCAN = "velodyne_msgs/msg/VelodyneScan"
VELODYNE_PACKET = "velodyne_msgs/msg/VelodynePacket"
VELODYNE_PACKET_BYTES = 1206

#: ros-drivers/velodyne, velodyne_msgs (ROS 2)
DEFINITIONS = {
    VELODYNE_PACKET: "builtin_interfaces/Time stamp\nuint8[1206] data\n",
    VELODYNE_SCAN: "std_msgs/Header header\nvelodyne_msgs/VelodynePacket[] packets\n",
}
SCAN_TOPIC = Topic("/velodyne_packets", VELODYNE_SCAN)
POSITION_TOPIC = Topic("/velodyne_position_packets", STAMPED_PACKET)


# --------------------------------------------------------------------------- reading bags
def _scan_packets(msg: Any, bag_time_ns: int) -> tuple[np.ndarray, np.ndarray]:
    packets = msg.packets
    if not packets:
        return np.zeros((0, 1206), np.uint8), np.zeros(0, np.int64)
    payload = np.stack([np.asarray(p.data, dtype=np.uint8) for p in packets])
    times = np.array([stamp_ns(p.stamp) for p in packets], dtype=np.int64)
    times[times == 0] = bag_time_ns  # drivers that leave the packet stamp empty
    return payload, times


def _packet(msg: Any, bag_time_ns: int) -> tuple[np.ndarray, np.ndarray]:
    t = stamp_ns(msg.stamp) or bag_time_ns
    return np.asarray(msg.data, dtype=np.uint8)[None, :], np.array([t], dtype=np.int64)


# --------------------------------------------------------------------------- the scan codec
# one VelodynePacket element of a VelodyneScan, with the 2 alignment bytes that precede the
# next element (int32 sec at a 4-aligned offset; 8 + 1206 = 1214 → next at 1216)
VELODYNE_PACKET_CDR = np.dtype(
    {"names": ["sec", "nanosec", "data"], "formats": ["<i4", "<u4", (np.uint8, VELODYNE_PACKET_BYTES)],
     "offsets": [0, 4, 8], "itemsize": 1216}
)


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
    head = header_cdr(stamp_ns, frame_id)
    head += b"\x00" * pad4(len(head)) + np.array([n], "<u4").tobytes()
    elems = np.zeros(n, VELODYNE_PACKET_CDR)
    sec, nanosec = np.divmod(np.asarray(host_time_ns, np.int64), 1_000_000_000)
    elems["sec"] = sec
    elems["nanosec"] = nanosec
    elems["data"] = payload
    body = elems.tobytes()
    if n:
        body = body[:-2]  # no alignment after the last element
    return CDR_LE + head + body


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
    pos += pad4(pos)
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


def sensor_time_ns(timestamp_us: np.ndarray, host_time_ns: np.ndarray) -> np.ndarray:
    """Sensor time (ns since the epoch) of data packets: their µs past the hour, in the hour nearest their
    host receive time (the convention of velodyne_decoder; ±30 min), as the decoder resolves it
    (:func:`lidarpkt.vendors.velodyne.clock.in_nearest_hour_ns`)."""
    return in_nearest_hour_ns(timestamp_us, host_time_ns)


def _scan(payload: np.ndarray, host_ns: np.ndarray) -> bytes:
    """The ``VelodyneScan`` of one rotation's packets: ``header.stamp`` = its first packet's sensor time."""
    from .packet import as_data_packets

    ts_us = as_data_packets(payload[:1])["timestamp_us"]
    stamp = int(sensor_time_ns(ts_us, host_ns[:1])[0])
    return encode_velodyne_scan(payload, host_ns, stamp)


# --------------------------------------------------------------------------- what the writer records
def stream_record(batch: PacketBatch, src: str) -> dict[str, str] | None:
    """The ``lidarpkt.sensor`` MCAP metadata record of a data stream (model, return mode, factory byte,
    the model's stock elevations), from its first batch; ``None`` for a position stream."""
    from lidarpkt.errors import LidarpktError
    from . import packet as vlp
    from .decode import decode_packets
    from .detect import describe_stream, detect_model
    from .models import PRODUCT_NAMES

    if batch.payload_size != VELODYNE_PACKET_BYTES:
        return None
    p = vlp.as_data_packets(batch.payload[:1])[0]
    mode = vlp.RETURN_MODES.get(int(p["return_mode"]), f"0x{int(p['return_mode']):02x}")
    product = PRODUCT_NAMES.get(int(p["product_id"]), f"0x{int(p['product_id']):02x}")
    described = describe_stream(batch) or {}
    try:  # the model's own stock elevations (an HDL-32E's 32, not the VLP-16's 16)
        model = detect_model(decode_packets(batch.payload, copy=False), src)
    except LidarpktError:  # an unknown or ambiguous factory byte: the decoder says so; no elevations here
        model = None
    return {
        "vendor": "velodyne", "model": model.name if model is not None else
        described.get("kind", "Velodyne data").replace(" data", ""),
        "return_mode": mode, "product_id": f"0x{int(p['product_id']):02x} ({product})", "source": src,
        **({"laser_elevation_deg": json.dumps([float(e) for e in model.elevation_deg])} if model is not None else {}),
        "stream": json.dumps(described, default=str),
    }


ROS = RosMessages(
    frames=FrameTopics(frame_id="velodyne", points="/velodyne_points", images="/velodyne", ring_from_bottom=True),
    definitions=DEFINITIONS,
    packets={VELODYNE_SCAN: _scan_packets, VELODYNE_PACKET: _packet},
    packet_topics={"data": PacketTopic(SCAN_TOPIC, encode_rotation=_scan),
                   "position": PacketTopic(POSITION_TOPIC, encode=encode_stamped_packet)},
    stream_record=stream_record,
)
