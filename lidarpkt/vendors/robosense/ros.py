"""RoboSense packets in ROS messages: the ``robosense_msgs`` types nebula records and lidarpkt writes.

A ``robosense_msgs/msg/RobosenseScan`` is a header and a list of ``RobosensePacket``: the packet's
receive ``stamp``, ``is_difop`` (1 for a DIFOP packet), a fixed 1500-byte ``data`` buffer and the
payload's length in ``size``. :func:`packets_from_scan` takes the payloads out of a message (as a bag
reader deserialises it); :func:`scan_fields` gives the fields of one for a batch of payloads.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .detect import is_difop

SCAN_TYPE = "robosense_msgs/msg/RobosenseScan"
PACKET_TYPE = "robosense_msgs/msg/RobosensePacket"
BUFFER_SIZE = 1500  # RobosensePacket.data
#: the ``.msg`` definitions (nebula's ``robosense_msgs``), by ROS 2 type name
MESSAGE_DEFINITIONS: dict[str, str] = {
    PACKET_TYPE: "builtin_interfaces/Time stamp\nuint8 is_difop\nuint8[1500] data\nuint32 size\n",
    SCAN_TYPE: "std_msgs/Header header\nrobosense_msgs/RobosensePacket[] packets\n",
}
DEFAULT_TOPIC = "/robosense_packets"  # nebula's
FRAME_ID = "robosense"


def _stamp_ns(stamp: Any) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


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
    times = np.array([_stamp_ns(p.stamp) for p in packets], np.int64)
    times[times == 0] = bag_time_ns
    return payload, times


def scan_fields(payload: np.ndarray, host_ns: np.ndarray, stamp_ns: int | None = None,
                frame_id: str = FRAME_ID) -> dict[str, Any]:
    """The fields of a ``RobosenseScan`` holding ``uint8[N, L]`` payloads received at ``host_ns``
    (``header.stamp``: ``stamp_ns``, by default the first packet's): plain Python values and NumPy
    arrays, ready for a type store's message classes (``packets``: a list of field dicts)."""
    payload = np.asarray(payload, np.uint8)
    n, size = payload.shape
    if size > BUFFER_SIZE:
        raise ValueError(f"{size}-byte packets do not fit a RobosensePacket's {BUFFER_SIZE}-byte buffer")
    difop = is_difop(payload)
    stamp = int(host_ns[0]) if stamp_ns is None and n else int(stamp_ns or 0)
    packets = []
    for k in range(n):
        data = np.zeros(BUFFER_SIZE, np.uint8)
        data[:size] = payload[k]
        t = int(host_ns[k])
        packets.append({"stamp": {"sec": t // 1_000_000_000, "nanosec": t % 1_000_000_000},
                        "is_difop": int(difop[k]), "data": data, "size": size})
    return {"header": {"stamp": {"sec": stamp // 1_000_000_000, "nanosec": stamp % 1_000_000_000},
                       "frame_id": frame_id}, "packets": packets}
