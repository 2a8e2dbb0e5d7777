"""The ROS 2 messages lidarpkt writes to MCAP: definitions, topics, QoS, and CDR encoding.

Every message type is declared once, as ``.msg`` text (the messages the ROS drivers use: each vendor's
are in its registry record, ``Vendor.ros`` of :mod:`lidarpkt.core.vendor`; the standard ``std_msgs`` /
``sensor_msgs`` / ``builtin_interfaces`` ones come from the rosbags type store). The MCAP schema text
(``ros2msg`` encoding, dependencies appended after ``====`` lines, as rosbag2 writes it) and the CDR
serialisers are derived from these definitions by rosbags. The messages written at packet rate have
NumPy codecs (one array operation per message instead of one Python object per packet); the test
suite checks them byte for byte against rosbags and the official ``mcap_ros2`` decoder.

Topics (all CDR, ``ros2msg`` schemas), besides each vendor's packet topics and decoded messages
(``lidarpkt info`` of the MCAP lists them; the vendor modules' ``ros`` say what they hold):

================================  =====================================  ==================================
topic                             type                                   content
================================  =====================================  ==================================
``/lidarpkt/other_packets``       ``nebula_msgs/msg/NebulaPacket``       datagrams of no stream with a topic
                                                                         of its own (kept, never dropped)
``<points>`` (``2``)              ``sensor_msgs/msg/PointCloud2``        organised frame, return slot 0 (1);
                                                                         NaN x/y/z where no return; the
                                                                         vendor's driver's topic
``<prefix>/range_image`` (``2``)  ``sensor_msgs/msg/Image``              ``32FC1`` range in metres
``<prefix>/reflectivity_image``   ``sensor_msgs/msg/Image``              ``mono8`` reflectivity
``/gps/nmea_sentence``            ``nmea_msgs/msg/Sentence``             one verified NMEA sentence
``/tf_static``                    ``tf2_msgs/msg/TFMessage``             each sensor's mount on the base frame
                                                                         (``--base-frame``), latched
================================  =====================================  ==================================

MCAP log time is always the host receive time (ns since the Unix epoch), inside the capture's
time span: latched sensor files and ``/tf_static`` are logged at the first packet's time.
"""

from __future__ import annotations

import functools
from typing import Any

from lidarpkt.containers import rosmsgs
from lidarpkt.containers.rosmsgs import STAMPED_PACKET
from lidarpkt.core.ros import QOS_LATCHED, QOS_RELIABLE, Topic

POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
IMAGE = "sensor_msgs/msg/Image"
NMEA_SENTENCE = "nmea_msgs/msg/Sentence"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"

OTHER_PACKETS = Topic("/lidarpkt/other_packets", STAMPED_PACKET)
NMEA = Topic("/gps/nmea_sentence", NMEA_SENTENCE, QOS_RELIABLE)
TF_STATIC = Topic("/tf_static", TF_MESSAGE, QOS_LATCHED)


def points_topic(vendor: str, slot: int) -> Topic:
    """PointCloud2 topic of return slot ``slot`` (0 or 1) of a ``vendor`` frame (its driver's topic)."""
    from lidarpkt.vendors import registry

    base = registry.vendor(vendor).ros.frames.points
    return Topic(base + ("" if slot == 0 else str(slot + 1)), POINTCLOUD2)


def image_topic(vendor: str, field: str, slot: int) -> Topic:
    """Image topic of one field (``range``, ``reflectivity``) and return slot."""
    from lidarpkt.vendors import registry

    prefix = registry.vendor(vendor).ros.frames.images
    return Topic(f"{prefix}/{field}_image" + ("" if slot == 0 else str(slot + 1)), IMAGE)


@functools.lru_cache(maxsize=1)
def typestore() -> Any:
    """The rosbags type store of every message lidarpkt writes (each vendor's definitions registered), built
    once, for encoding, decoding and schemas only (register nothing into it)."""
    from lidarpkt.vendors import registry

    return rosmsgs.typestore(registry.ros_definitions())


@functools.lru_cache(maxsize=None)
def schema_text(msgtype: str) -> str:
    """The ``ros2msg`` schema of ``msgtype`` for an MCAP Schema record (dependencies appended)."""
    text, _ = typestore().generate_msgdef(msgtype, ros_version=2)
    return text


def decode(msgtype: str, data: bytes) -> object:
    """A rosbags message object from CDR bytes (any type lidarpkt writes)."""
    return typestore().deserialize_cdr(data, msgtype)
