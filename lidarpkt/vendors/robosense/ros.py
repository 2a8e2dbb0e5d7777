"""RoboSense packets in ROS messages: the ``robosense_msgs`` types nebula records, read and written as nebula
writes them.

A ``robosense_msgs/msg/RobosenseScan`` is a header and a list of ``RobosensePacket``: the packet's
receive ``stamp``, ``is_difop`` (1 for a DIFOP packet), a fixed 1500-byte ``data`` buffer and the
payload's length in ``size``. nebula publishes one scan per rotation on ``/robosense_packets``, its DIFOP
packets among the MSOP ones, ``header.stamp`` the first packet's receive time, frame id ``robosense``.
lidarpkt writes the same: an MSOP stream one scan per rotation, a DIFOP stream of its own (a pcap's port
7788) one scan per packet, both on ``/robosense_packets``. Frames: ``/robosense_points``,
``/robosense/<field>_image``.

:func:`packets_from_scan` takes the payloads out of a message (as a bag reader deserialises it);
:func:`encode_scan` is the CDR of one, as NumPy byte operations (one array operation per scan).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from lidarpkt.containers.rosmsgs import CDR_LE, header_cdr, pad4, stamp_ns
from lidarpkt.core.ros import Topic
from lidarpkt.core.vendor import FrameTopics, PacketTopic, RosMessages

SCAN_TYPE = "robosense_msgs/msg/RobosenseScan"
PACKET_TYPE = "robosense_msgs/msg/RobosensePacket"
BUFFER_SIZE = 1500  # RobosensePacket.data
#: the ``.msg`` definitions (nebula's ``robosense_msgs``), by ROS 2 type name
MESSAGE_DEFINITIONS: dict[str, str] = {
    PACKET_TYPE: "builtin_interfaces/Time stamp\nuint8 is_difop\nuint8[1500] data\nuint32 size\n",
    SCAN_TYPE: "std_msgs/Header header\nrobosense_msgs/RobosensePacket[] packets\n",
}
PACKETS_TOPIC = Topic("/robosense_packets", SCAN_TYPE)  # nebula's
FRAME_ID = "robosense"

# one RobosensePacket of a RobosenseScan: int32 sec, uint32 nanosec, uint8 is_difop, uint8[1500] data, then
# uint32 size at the next 4-aligned offset (1512); 1516 bytes, a multiple of 4, so elements need no padding
PACKET_CDR = np.dtype({"names": ["sec", "nanosec", "is_difop", "data", "size"],
                       "formats": ["<i4", "<u4", "u1", (np.uint8, BUFFER_SIZE), "<u4"],
                       "offsets": [0, 4, 8, 9, 12 + BUFFER_SIZE], "itemsize": 16 + BUFFER_SIZE})


def packets_from_scan(msg: Any, bag_time_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """``(uint8[N, L] payloads, int64[N] receive times ns)`` of a deserialised ``RobosenseScan``; a packet
    without a stamp takes the bag's receive time of the message.

    Raises ``ValueError`` for packets of several sizes in one message or a size beyond the buffer (the
    bag readers turn it into a :class:`~lidarpkt.errors.CaptureFormatError` naming the file)."""
    packets = msg.packets
    if not packets:
        return np.zeros((0, 0), np.uint8), np.zeros(0, np.int64)
    sizes = {int(p.size) for p in packets}
    if len(sizes) != 1:  # RoboSense packets are one size (1248 B); a batch holds one size
        raise ValueError(f"packets of {len(sizes)} sizes ({sorted(sizes)[:4]}) in one RobosenseScan")
    size = sizes.pop()
    if not 0 < size <= BUFFER_SIZE:
        raise ValueError(f"packet size {size} outside the {BUFFER_SIZE}-byte buffer")
    payload = np.stack([np.asarray(p.data, dtype=np.uint8)[:size] for p in packets])
    times = np.array([stamp_ns(p.stamp) for p in packets], np.int64)
    times[times == 0] = bag_time_ns
    return payload, times


def packet_from_message(msg: Any, bag_time_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """The payload of one deserialised ``RobosensePacket`` and its receive time (the bag's when unstamped).

    Raises ``ValueError`` for a size beyond the buffer."""
    size = int(msg.size)
    if not 0 < size <= BUFFER_SIZE:
        raise ValueError(f"packet size {size} outside the {BUFFER_SIZE}-byte buffer")
    t = stamp_ns(msg.stamp) or bag_time_ns
    return np.asarray(msg.data, dtype=np.uint8)[None, :size], np.array([t], np.int64)


def encode_scan(payload: np.ndarray, host_ns: np.ndarray, stamp: int | None = None, frame_id: str = FRAME_ID) -> bytes:
    """CDR of a ``RobosenseScan`` holding ``uint8[N, L]`` payloads received at ``host_ns`` (``int64[N]`` ns);
    ``header.stamp`` = ``stamp``, by default the first packet's receive time (nebula's). ``is_difop`` is each
    payload's own (by its identifier).

    Raises ``ValueError`` for payloads longer than the 1500-byte buffer."""
    from .detect import is_difop  # here: the registry imports this module, and most captures hold no RoboSense

    payload = np.asarray(payload, np.uint8)
    if payload.ndim != 2 or payload.shape[1] > BUFFER_SIZE:
        raise ValueError(f"payloads of shape {payload.shape} do not fit a RobosensePacket's {BUFFER_SIZE}-byte buffer")
    n, size = payload.shape
    host = np.asarray(host_ns, np.int64)
    head = header_cdr(int(host[0]) if stamp is None and n else int(stamp or 0), frame_id)
    head += b"\x00" * pad4(len(head)) + np.array([n], "<u4").tobytes()
    elems = np.zeros(n, PACKET_CDR)
    elems["sec"], elems["nanosec"] = np.divmod(host, 1_000_000_000)
    elems["is_difop"] = is_difop(payload)
    elems["data"][:, :size] = payload
    elems["size"] = size
    return CDR_LE + head + elems.tobytes()


def _packet_scan(payload: bytes, host_time_ns: int) -> bytes:
    """One packet as a scan of its own (a DIFOP stream's)."""
    return encode_scan(np.frombuffer(payload, np.uint8)[None, :], np.array([host_time_ns], np.int64))


ROS = RosMessages(
    frames=FrameTopics(frame_id=FRAME_ID, points="/robosense_points", images="/robosense"),
    definitions=MESSAGE_DEFINITIONS,
    packets={SCAN_TYPE: packets_from_scan, PACKET_TYPE: packet_from_message},
    packet_topics={"msop": PacketTopic(PACKETS_TOPIC, encode_rotation=encode_scan),
                   "difop": PacketTopic(PACKETS_TOPIC, encode=_packet_scan)},
)
