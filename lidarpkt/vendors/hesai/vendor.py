"""The Hesai entry of the vendor registry (:data:`VENDOR`, a :class:`~lidarpkt.core.vendor.Vendor`): what the
rest of lidarpkt asks of Hesai Pandar sensors, answered by this package's modules (imported when asked)."""

from __future__ import annotations

from typing import Any

from lidarpkt.core.dropped import DropCounts
from lidarpkt.core.packet import Endpoint, PacketBatch
from lidarpkt.core.streams import StreamKind
from lidarpkt.core.vendor import DecodeSetup, Match, RosMessages, SensorFiles, Vendor

NAME = "hesai"
DATA = StreamKind(NAME, "data", lidar=True)

# Pandar user manuals, factory settings: the sensor at 192.168.1.201 sends to port 2368, broadcast
SENSOR_ADDRESS, PORT, BROADCAST = "192.168.1.201", 2368, "255.255.255.255"


def classify(batch: PacketBatch, setup: DecodeSetup) -> Match | None:
    """A stream of some Pandar model: sizes only Pandars send, then their header or block start bytes
    (:func:`.detect.classify`). Of several angle-correction files, the one of the model's channel count."""
    from .detect import classify as model_of

    model = model_of(batch)
    if model is None:
        return None
    files = setup.files(NAME)
    fitting = [f for f in files if getattr(f, "channels", None) == model.channels]
    calibration = fitting[0] if fitting else files[0] if len(files) == 1 else None
    cut_angle_deg = setup.option("cut_angle_deg")

    def make(source: str):
        from .frames import HesaiDecoder

        return HesaiDecoder(model=model, source=source, calibration=calibration, cut_angle_deg=cut_angle_deg)

    return Match(DATA, (model.name,), make, () if calibration is None else (calibration,))


def describe(batch: PacketBatch, setup: DecodeSetup) -> dict | None:
    from .detect import describe_stream

    return describe_stream(batch)


def summary(d: dict) -> list[str]:
    """``info``'s words for a stream's description (after its kind)."""
    bits = []
    if "protocol" in d:
        bits.append(f"protocol {d['protocol']}")
    if "return_mode" in d:
        mode = d["return_mode"]
        bits.append(mode if isinstance(mode, str) else "/".join(mode))
    if d.get("rotation_hz"):
        bits.append(f"{d['rotation_hz']:.1f} Hz")
    if d.get("note"):
        bits.append(d["note"])
    return bits


def counter(batch: PacketBatch, match: Match):
    """The loss and rotation counter of a Pandar stream (its model told by its first payloads)."""
    from .stream import PacketCounter

    return PacketCounter()


def sensor_time_ns(batch: PacketBatch, match: Match) -> int | None:
    return None  # frames are logged at their capture time


def drops(st: Any) -> DropCounts:
    """:class:`~lidarpkt.vendors.hesai.frames.DecoderStats` by drop reason."""
    return DropCounts(lost=st.lost_packets, late=st.late_packets, duplicate=st.duplicate_packets, malformed=st.malformed)


def endpoints(match: Match) -> tuple[Endpoint, Endpoint]:
    return Endpoint(SENSOR_ADDRESS, PORT), Endpoint(BROADCAST, PORT)


def _recognise(text: str) -> bool:
    """An angle-correction CSV: an optional header naming the elevation and azimuth, then lines
    ``channel,elevation,azimuth`` numbered from 1."""
    lines = [line.strip().lstrip("\ufeff") for line in text.splitlines() if line.strip()]
    if lines and not lines[0][:1].isdigit():
        head = lines.pop(0).lower()
        if "elevation" not in head or "azimuth" not in head:
            return False
    if not lines:
        return False
    cells = [c.strip() for c in lines[0].split(",")]
    try:
        return len(cells) >= 3 and int(cells[0]) == 1 and all(abs(float(c)) <= 360 for c in cells[1:3])
    except ValueError:
        return False


def _is_loaded(obj: Any) -> bool:
    from .calibration import HesaiCalibration

    return isinstance(obj, HesaiCalibration)


def _load(obj: Any) -> Any:
    """A :class:`~lidarpkt.vendors.hesai.calibration.HesaiCalibration` (a loaded one passes through)."""
    from .calibration import load_calibration

    return load_calibration(obj)


def ros_messages() -> RosMessages:
    from .ros import ROS

    return ROS


VENDOR = Vendor(
    name=NAME,
    title="Hesai",
    streams=(DATA,),
    classify=classify,
    describe=describe,
    summary=summary,
    counter=counter,
    sensor_time_ns=sensor_time_ns,
    drops=drops,
    endpoints=endpoints,
    ros_messages=ros_messages,
    sensor_files=SensorFiles("Hesai angle-correction CSV", _recognise, _is_loaded, _load, needed_for="xyz"),
    frame_ids_counted=True,
)
