"""Independent references the tests compare lidarpkt against, written once.

Each helper drives a tool nobody here wrote (ouster-sdk's pcap reader, the official ``mcap_ros2``
writer) and skips the calling test when that tool is not installed. The VelodyneScan schema text
below is written out from the ROS message definitions on purpose, not imported from
``lidarpkt.writers.mcap.schemas``, so that a test reading such a file checks our reader against an
independently written one.
"""

from __future__ import annotations

import io
import warnings

import numpy as np
import pytest

from lidarpkt.core.packet import Endpoint

VELODYNE_SCAN_SCHEMA = (
    "std_msgs/Header header\nvelodyne_msgs/VelodynePacket[] packets\n" + "=" * 80 + "\nMSG: std_msgs/Header\n"
    "builtin_interfaces/Time stamp\nstring frame_id\n" + "=" * 80 + "\nMSG: velodyne_msgs/VelodynePacket\n"
    "builtin_interfaces/Time stamp\nuint8[1206] data\n"
)


def _stamp(ns: int) -> dict:
    return {"sec": int(ns) // 10**9, "nanosec": int(ns) % 10**9}


def velodyne_scan_mcap(
    payloads, times_ns, *, packets_per_message: int = 1, chunk_size: int | None = None, frame_id: str = "v"
) -> bytes:
    """An MCAP file of ``/velodyne_packets`` (``velodyne_msgs/msg/VelodyneScan``) written by the official
    ``mcap_ros2`` writer: ``packets_per_message`` 1206-byte payloads per message, each packet stamped with
    its time, the message logged at the time of its last packet and stamped with its first."""
    writer_mod = pytest.importorskip("mcap_ros2.writer")
    fh = io.BytesIO()
    w = writer_mod.Writer(fh) if chunk_size is None else writer_mod.Writer(fh, chunk_size=chunk_size)
    schema = w.register_msgdef("velodyne_msgs/msg/VelodyneScan", VELODYNE_SCAN_SCHEMA)
    payloads = [bytes(p) for p in payloads]
    times = [int(t) for t in times_ns]
    for start in range(0, len(payloads), packets_per_message):
        rows = range(start, min(start + packets_per_message, len(payloads)))
        msg = {"header": {"stamp": _stamp(times[start]), "frame_id": frame_id},
               "packets": [{"stamp": _stamp(times[i]), "data": payloads[i]} for i in rows]}
        w.write_message("/velodyne_packets", schema, msg, log_time=times[rows[-1]], publish_time=times[rows[-1]])
    w.finish()
    return fh.getvalue()


def ouster_sdk_pcap_packets(path) -> list[tuple[Endpoint, Endpoint, float, bytes]]:
    """(src, dst, time in float seconds, payload) of every UDP datagram of a capture, as ouster-sdk's
    libtins-based reader sees it (it reassembles IPv4 fragments). Raises RuntimeError for a link type
    libtins does not know."""
    pytest.importorskip("ouster.sdk")
    from ouster.sdk._bindings import pcap as sdk_pcap

    out = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        handle = sdk_pcap.replay_initialize(str(path))
        info = sdk_pcap.PacketInfo()
        buf = np.zeros(1 << 17, np.uint8)
        try:
            while sdk_pcap.next_packet_info(handle, info):
                n = sdk_pcap.read_packet(handle, buf)
                out.append((Endpoint(info.src_ip, info.src_port), Endpoint(info.dst_ip, info.dst_port),
                            info.timestamp, buf[:n].tobytes()))
        finally:
            sdk_pcap.replay_uninitialize(handle)
    return out
