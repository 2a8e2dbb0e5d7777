"""The ROS message types of lidar packets that rosbags' stock ROS 2 store lacks, declared once: the bag
and MCAP readers (:mod:`lidarpkt.containers.bags`) read with them when a file carries no definitions of
its own, and the MCAP writer (:mod:`lidarpkt.writers.mcap.schemas`) writes with them.

Each definition is the driver package's ``.msg`` text. A new packet type is one entry here (and, to
read it, an extractor in :data:`lidarpkt.containers.bags.PACKET_EXTRACTORS`).
"""

from __future__ import annotations

import functools
from typing import Any

MESSAGE_DEFINITIONS: dict[str, str] = {
    # ros-drivers/velodyne, velodyne_msgs (ROS 2)
    "velodyne_msgs/msg/VelodynePacket": "builtin_interfaces/Time stamp\nuint8[1206] data\n",
    "velodyne_msgs/msg/VelodyneScan": "std_msgs/Header header\nvelodyne_msgs/VelodynePacket[] packets\n",
    # ouster-ros, ouster_sensor_msgs: the lidar and IMU packet topics (/ouster/lidar_packets, /ouster/imu_packets)
    "ouster_sensor_msgs/msg/PacketMsg": "uint8[] buf\n",
    # ouster-ros on ROS 1, before it moved its messages into ouster_sensor_msgs (/os_node/lidar_packets ...)
    "ouster_ros/msg/PacketMsg": "uint8[] buf\n",
    # tier4/nebula, nebula_msgs: a stamped packet of any size (lidarpkt writes VLP-16 position packets with it)
    "nebula_msgs/msg/NebulaPacket": "builtin_interfaces/Time stamp\nuint8[] data\n",
    # tier4/nebula, pandar_msgs: a Hesai scan of fixed 1500-byte buffers, each packet's length in `size`
    "pandar_msgs/msg/PandarPacket": "builtin_interfaces/Time stamp\nuint8[1500] data\nuint32 size\n",
    "pandar_msgs/msg/PandarScan": "std_msgs/Header header\npandar_msgs/PandarPacket[] packets\n",
    # ros-drivers/nmea_msgs
    "nmea_msgs/msg/Sentence": "std_msgs/Header header\nstring sentence\n",
}


def new_typestore() -> Any:
    """A fresh rosbags type store (ROS 2 Humble) with :data:`MESSAGE_DEFINITIONS` registered: a reader
    registers the definitions a file carries into it, so each reader has its own."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    types: dict = {}
    for name, text in MESSAGE_DEFINITIONS.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


@functools.lru_cache(maxsize=1)
def typestore() -> Any:
    """The shared store of :func:`new_typestore`, built once, for encoding and decoding only (register
    nothing into it)."""
    return new_typestore()
