"""The RoboSense capture of ``fixtures/external/nebula/robosense`` read for the tests: its rosbag2 with
``rosbags`` directly (the ``robosense_msgs`` definitions registered from the ``.msg`` files beside it),
nebula's ASCII PCDs, and the capture decoded by lidarpkt's decoder, message by message as nebula's
test feeds it."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from conftest import external
from lidarpkt.core.packet import PacketBatch

FOLDER = "nebula/robosense"
BAG = f"{FOLDER}/helios16p/rosbag2_2023_08_03-11_02_46"
CSV = f"{FOLDER}/RobosenseHelios16P.csv"
PCD_NAMES = ("1691031766781547066", "1691031766880833506", "1691031766980937333", "1691031767081713313")
PCD_FIELDS = ("x", "y", "z", "intensity", "return_type", "channel", "azimuth", "elevation", "distance", "time_stamp")


@dataclass(frozen=True)
class Message:
    """One ``RobosenseScan`` of the bag."""

    bag_time_ns: int
    payload: np.ndarray  # uint8[N, 1248]
    stamp_ns: np.ndarray  # int64[N], each packet's receive stamp
    is_difop: np.ndarray  # bool[N], the message's own flag


@functools.lru_cache(maxsize=1)
def _messages(root: str) -> tuple[Message, ...]:
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    folder = Path(root)
    store = get_typestore(Stores.ROS2_HUMBLE)
    types: dict = {}
    for name in ("RobosensePacket", "RobosenseScan"):
        types.update(get_types_from_msg((folder / f"{name}.msg").read_text(), f"robosense_msgs/msg/{name}"))
    store.register(types)
    out = []
    with Reader(folder / "helios16p" / "rosbag2_2023_08_03-11_02_46") as reader:
        for conn, bag_time, raw in reader.messages():
            msg = store.deserialize_cdr(raw, conn.msgtype)
            payload = np.stack([np.asarray(p.data[: p.size], np.uint8) for p in msg.packets])
            stamps = np.array([p.stamp.sec * 1_000_000_000 + p.stamp.nanosec for p in msg.packets], np.int64)
            out.append(Message(int(bag_time), payload, stamps, np.array([bool(p.is_difop) for p in msg.packets])))
    return tuple(out)


def messages() -> tuple[Message, ...]:
    """The bag's five messages, in bag order (skips the test when the capture is absent)."""
    external(BAG)
    return _messages(str(external(FOLDER)))


def all_packets() -> tuple[np.ndarray, np.ndarray]:
    """``(uint8[751, 1248], int64[751])``: every packet of the bag and its receive stamp, in order."""
    msgs = messages()
    return np.concatenate([m.payload for m in msgs]), np.concatenate([m.stamp_ns for m in msgs])


def batches() -> list[PacketBatch]:
    """One batch per message, indices counting packets across the bag."""
    out, first = [], 0
    for m in messages():
        out.append(PacketBatch.from_payloads(m.payload, m.stamp_ns, first_index=first))
        first += len(m.payload)
    return out


def decode(**options) -> tuple[list, object]:
    """Frames of the whole bag (and the decoder) by :class:`RobosenseDecoder` with ``options``."""
    from lidarpkt.vendors.robosense import RobosenseDecoder

    decoder = RobosenseDecoder(**options)
    frames = []
    for batch in batches():
        frames += decoder.push(batch)
    frames += decoder.finish()
    return frames, decoder


@functools.lru_cache(maxsize=4)
def pcd(name: str) -> np.ndarray:
    """nebula's cloud of the message whose bag time is ``name``: a structured array of :data:`PCD_FIELDS`."""
    path = external(f"{FOLDER}/helios16p/{name}.pcd")
    lines = path.read_text().splitlines()
    start = lines.index("DATA ascii") + 1
    header = dict(line.split(" ", 1) for line in lines[:start - 1] if not line.startswith("#"))
    assert header["FIELDS"].split() == list(PCD_FIELDS)
    values = np.loadtxt(lines[start:], dtype=np.float64)
    assert values.shape == (int(header["POINTS"]), len(PCD_FIELDS))
    out = np.empty(len(values), [(f, "f8") for f in PCD_FIELDS])
    for k, f in enumerate(PCD_FIELDS):
        out[f] = values[:, k]
    return out


def sensor_packets() -> list:
    """The bag's packets as the sensor sends them (:class:`~lidarpkt.core.packet.Packet`): from 192.168.1.200, MSOP to
    port 6699 and DIFOP to port 7788 of 192.168.1.102, at their receive stamps."""
    from lidarpkt.core.packet import Endpoint, Packet

    payload, stamps = all_packets()
    difop = np.all(payload[:, :8] == np.frombuffer(bytes.fromhex("a5ff005a11115555"), np.uint8), axis=1)
    return [Packet(int(t), Endpoint("192.168.1.200", port), Endpoint("192.168.1.102", port), row.tobytes())
            for t, row, port in zip(stamps, payload, np.where(difop, 7788, 6699).tolist())]


def write_sensor_pcap(path: Path) -> Path:
    """A pcap of :func:`sensor_packets`."""
    from lidarpkt.writers.pcap import write_pcap

    write_pcap(path, sensor_packets(), nanosecond=True)
    return path
