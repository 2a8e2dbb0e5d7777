"""The Velodyne entry of the vendor registry (:data:`VENDOR`, a :class:`~lidarpkt.core.vendor.Vendor`): what
the rest of lidarpkt asks of Velodyne sensors, answered by this package's modules (imported when asked)."""

from __future__ import annotations

from typing import Any, Mapping

from lidarpkt.core.dropped import DropCounts
from lidarpkt.core.packet import Endpoint, PacketBatch
from lidarpkt.core.streams import StreamKind
from lidarpkt.core.vendor import DecodeSetup, Match, RosMessages, SensorFiles, Vendor

NAME = "velodyne"
DATA = StreamKind(NAME, "data", lidar=True)
POSITION = StreamKind(NAME, "position")

# VLP-16 user manual, factory settings: sensor 192.168.1.201, data port 2368, position port 8308, destination
# broadcast (the HDL-32E's and the others' too)
SENSOR_ADDRESS = "192.168.1.201"
PORTS = {"data": 2368, "position": 8308}
BROADCAST = "255.255.255.255"


def classify(batch: PacketBatch, setup: DecodeSetup) -> Match | None:
    """Data or position packets of any Velodyne model (size, then content: :func:`.detect.classify`)."""
    from .detect import classify as kind_of

    kind = kind_of(batch)
    if kind is None:
        return None
    files = setup.files(NAME)
    calibration: Any = None if not files else files[0] if len(files) == 1 else files

    def make(source: str):
        from .frames import VelodyneDecoder

        return VelodyneDecoder(source=source, calibration=calibration, cut_angle_deg=setup.option("cut_angle_deg"),
                               cut_on_block=bool(setup.option("cut_on_block", False)), model=setup.option("model"))

    return Match(DATA if kind == "data" else POSITION, (), make, files)


def describe(batch: PacketBatch, setup: DecodeSetup) -> dict | None:
    from .detect import describe_stream

    return describe_stream(batch)


def summary(d: dict) -> list[str]:
    """``info``'s words for a stream's description (after its kind)."""
    bits = []
    if "return_mode" in d:
        mode = d["return_mode"]
        bits.append(mode if isinstance(mode, str) else "/".join(mode))
    if "product_id" in d:
        bits.append(f"product 0x{d['product_id']:02x} ({d.get('product_name', '?')})")
    if d.get("rotation_hz"):
        bits.append(f"{d['rotation_hz']:.1f} Hz")
    if "pps_status" in d:
        bits.append(f"PPS {d['pps_status']}")
        if d.get("gps_time_first"):
            bits.append(f"NMEA time {d['gps_time_first']}")
        elif d.get("nmea_first"):
            bits.append(f"NMEA {d['nmea_first'][:40]}")
        else:
            bits.append("no NMEA sentence")
    if d.get("note"):
        bits.append(d["note"])
    return bits


def counter(batch: PacketBatch, match: Match):
    """The loss and rotation counter of a data stream, with the packet period of its model (VLP-16, HDL-32E;
    another model: packets and rotations only)."""
    if match.stream != DATA:
        return None
    from .detect import data_kind
    from .models import HDL32E_PACKET_PERIOD_US
    from .packet import SINGLE_PACKET_PERIOD_US
    from .stream import PacketCounter

    kind = data_kind(batch)
    period = None if kind is None else {"vlp16": SINGLE_PACKET_PERIOD_US, "hdl32e": HDL32E_PACKET_PERIOD_US}.get(kind)
    return PacketCounter(period)


def sensor_time_ns(batch: PacketBatch, match: Match) -> int | None:
    """A data packet's time: µs past the hour, in the hour nearest its capture time."""
    if match.stream != DATA:
        return None
    from .packet import as_data_packets
    from .ros import sensor_time_ns as in_hour

    ts_us = as_data_packets(batch.payload[:1])["timestamp_us"]
    return int(in_hour(ts_us, batch.timestamp_ns[:1])[0])


def drops(st: Any) -> DropCounts:
    """:class:`~lidarpkt.vendors.velodyne.accounting.DecoderStats` by drop reason."""
    return DropCounts(lost=st.lost_packets, late=st.late_packets, duplicate=st.duplicate_packets,
                      malformed=st.malformed + st.position_malformed, corrupted=st.corrupted_packets)


def endpoints(match: Match) -> tuple[Endpoint, Endpoint]:
    port = PORTS[match.kind]
    return Endpoint(SENSOR_ADDRESS, port), Endpoint(BROADCAST, port)


def _recognise(text: str) -> bool:
    """A ROS driver calibration YAML (a ``lasers`` list with ``vert_correction``) or a VeloView XML (``points_``)."""
    head = text.lstrip()
    if head.startswith("<"):
        return "<points_" in head or "<px>" in head
    return "lasers:" in head and "vert_correction" in head


def _is_loaded(obj: Any) -> bool:
    from .calibration import VelodyneCalibration

    return isinstance(obj, VelodyneCalibration)


def _load(obj: Any) -> Any:
    """A path stays a path (read for the model its packets name); a loaded calibration passes through."""
    return obj


def models() -> tuple[str, ...]:
    from .models import MODELS

    return tuple(m.name for m in MODELS)


def geometry(sensor: Any, calibration: Mapping[str, Any] | None) -> Any:
    """The XYZ of frames read back from a file: the calibration's fields the file kept, else the stock one."""
    from .calibration import VelodyneCalibration
    from .geometry import VelodyneGeometry

    return VelodyneGeometry(None if calibration is None else VelodyneCalibration(**calibration))


def ros_messages() -> RosMessages:
    from .ros import ROS

    return ROS


VENDOR = Vendor(
    name=NAME,
    title="Velodyne",
    streams=(DATA, POSITION),
    classify=classify,
    describe=describe,
    summary=summary,
    counter=counter,
    sensor_time_ns=sensor_time_ns,
    drops=drops,
    endpoints=endpoints,
    ros_messages=ros_messages,
    sensor_files=SensorFiles("Velodyne calibration (ROS YAML or VeloView XML)", _recognise, _is_loaded, _load),
    frame_ids_counted=True,
    live_auxiliary=False,
    models=models,  # position packets: a GPS fix mid-stream would move the hour of the packets
    geometry=geometry,
)
