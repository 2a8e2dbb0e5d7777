"""ROS topics as lidarpkt writes them to MCAP: a name, a ROS 2 message type and the QoS a recorder offers
(rosbag2's YAML form), so that ``ros2 bag play`` accepts the file. Declared here, below the vendors (who
name their packet topics) and the writers (who write them)."""

from __future__ import annotations

from dataclasses import dataclass

# rosbag2's YAML form: history 3 = unknown, reliability 1/2 = reliable/best effort, durability 1/2 =
# transient local/volatile, liveliness 1 = automatic; "infinite" durations
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
