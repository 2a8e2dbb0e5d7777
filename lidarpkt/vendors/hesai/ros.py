"""Hesai packets as ROS messages: the ``pandar_msgs`` of tier4/nebula, read from bags (a ``PandarScan`` of
fixed 1500-byte buffers, each packet's length in ``size``). lidarpkt writes a Pandar's raw packets as the
stamped packets of no vendor (``/lidarpkt/other_packets``, nebula's ``NebulaPacket``), which it reads
back. Frames: ``/pandar_points``, ``/pandar/<field>_image``, frame id ``hesai``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from lidarpkt.containers.rosmsgs import stamp_ns
from lidarpkt.core.vendor import FrameTopics, RosMessages

PANDAR_SCAN = "pandar_msgs/msg/PandarScan"
PANDAR_PACKET = "pandar_msgs/msg/PandarPacket"
DEFINITIONS = {
    PANDAR_PACKET: "builtin_interfaces/Time stamp\nuint8[1500] data\nuint32 size\n",
    PANDAR_SCAN: "std_msgs/Header header\npandar_msgs/PandarPacket[] packets\n",
}


def _scan_packets(msg: Any, bag_time_ns: int) -> tuple[np.ndarray, np.ndarray]:
    packets = msg.packets
    if not packets:
        return np.zeros((0, 0), np.uint8), np.zeros(0, np.int64)
    sizes = {int(p.size) for p in packets}
    if len(sizes) != 1:  # one sensor sends one size; a batch holds one size
        raise ValueError(f"packets of {len(sizes)} sizes ({sorted(sizes)[:4]}) in one PandarScan")
    size = sizes.pop()
    if not 0 < size <= 1500:
        raise ValueError(f"packet size {size} outside the 1500-byte buffer")
    payload = np.stack([np.asarray(p.data, dtype=np.uint8)[:size] for p in packets])
    times = np.array([stamp_ns(p.stamp) for p in packets], dtype=np.int64)
    times[times == 0] = bag_time_ns
    return payload, times


ROS = RosMessages(
    frames=FrameTopics(frame_id="hesai", points="/pandar_points", images="/pandar"),
    definitions=DEFINITIONS,
    packets={PANDAR_SCAN: _scan_packets},
)
