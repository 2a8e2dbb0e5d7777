"""The RoboSense entry of the vendor registry (:data:`VENDOR`, a :class:`~lidarpkt.core.vendor.Vendor`): what the
rest of lidarpkt asks of RoboSense sensors, answered by this package's modules (imported when asked).

A sensor sends two streams of 1248-byte packets: MSOP (the measurements, port 6699) and DIFOP (its device
information and calibration, port 7788, once a second). Both go to one decoder per sensor address; the
angle CSV (``metadata=``) serves where a capture holds no DIFOP. A ROS bag carries the two in one message
and keeps no ports: :func:`split` parts them, so that replay and pcap export send each to its own port.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Mapping

from lidarpkt.core.dropped import DropCounts
from lidarpkt.core.packet import Endpoint, PacketBatch
from lidarpkt.core.streams import StreamKind
from lidarpkt.core.vendor import DecodeSetup, Match, RosMessages, SensorFiles, Vendor

if TYPE_CHECKING:
    import numpy as np

NAME = "robosense"
MSOP = StreamKind(NAME, "msop", lidar=True)
DIFOP = StreamKind(NAME, "difop")

# the user manuals' factory settings: the sensor at 192.168.1.200 sends MSOP to port 6699 and DIFOP to port
# 7788 of the host 192.168.1.102
SENSOR_ADDRESS, HOST_ADDRESS = "192.168.1.200", "192.168.1.102"
PORTS = {"msop": 6699, "difop": 7788}


def _model(setup: DecodeSetup) -> Any:
    """The RoboSense model ``model=`` names, ``None`` when it names none (or another vendor's)."""
    from lidarpkt.errors import UnknownSensorError
    from .models import model_named

    name = setup.option("model")
    try:
        return model_named(str(name)) if name is not None else None
    except UnknownSensorError:
        return None


def classify(batch: PacketBatch, setup: DecodeSetup) -> Match | None:
    """MSOP or DIFOP packets (:func:`.detect.classify`: the packet identifiers, then the block flags); a ROS scan
    holding both is MSOP. Of several angle CSVs, the one of the model's laser count."""
    from .detect import classify as kind_of

    found = kind_of(batch)
    if found is None:
        return None
    from .calibration import DifopPacket

    model = _model(setup)
    files = setup.files(NAME)
    address = batch.src.address if batch.src is not None else None
    difop = next((f for f in files if isinstance(f, DifopPacket) and f.address == address), None)
    fitting = [f for f in files if not isinstance(f, DifopPacket) and (model is None or f.lasers == model.lasers)]
    calibration = fitting[0] if fitting else None
    cut_angle_deg = setup.option("cut_angle_deg")

    def make(source: str):
        from .frames import RobosenseDecoder

        return RobosenseDecoder(model=model, calibration=calibration, cut_angle_deg=cut_angle_deg, source=source,
                                difop=None if difop is None else difop.payload)

    used = tuple(f for f in (calibration, difop) if f is not None)
    return Match(MSOP if found.kind == "msop" else DIFOP, (), make, used)


def describe(batch: PacketBatch, setup: DecodeSetup) -> dict | None:
    """:func:`.describe.describe_stream`; the calibration source says the angle CSV where one was given and the
    packets described hold no DIFOP."""
    from .describe import describe_stream

    d = describe_stream(batch)
    files = setup.files(NAME)
    if d is not None and files and "model" in d and d.get("calibration") != "DIFOP":
        d["calibration"] = f"angle CSV {files[0].source} (until a DIFOP comes)"
    return d


def summary(d: dict) -> list[str]:
    """``info``'s words for a stream's description (after its kind)."""
    bits = []
    if d.get("return_mode"):
        bits.append(d["return_mode"])
    if d.get("calibration"):
        bits.append(f"calibration: {d['calibration']}")
    if d.get("rotation_hz"):
        bits.append(f"{d['rotation_hz']:.1f} Hz")
    if d.get("difop_packets") and d.get("model"):
        n = d["difop_packets"]
        bits.append(f"{n} DIFOP packet{'s' * (n != 1)} among them")
    if d.get("serial_number"):
        bits.append(f"serial {d['serial_number']}")
    if d.get("malformed_packets"):
        bits.append(f"{d['malformed_packets']} malformed")
    return bits


def counter(batch: PacketBatch, match: Match):
    """The loss and rotation counter of an MSOP stream (its model told by its first payloads)."""
    if match.stream != MSOP:
        return None
    from .stream import PacketCounter

    return PacketCounter()


def sensor_time_ns(batch: PacketBatch, match: Match) -> int | None:
    """The header time of the first MSOP packet of a batch (the sensor's clock), ``None`` when it has none
    that decodes."""
    if match.stream != MSOP:
        return None
    from .decode import decode_packets
    from .detect import detect_model, is_difop

    msop = batch.payload[~is_difop(batch.payload)][:16]
    model = detect_model(msop)
    if model is None:
        return None
    raw = decode_packets(msop, model)
    good = raw.timestamp_ns[raw.valid]
    return int(good[0]) if len(good) else None


def drops(st: Any) -> DropCounts:
    """:class:`~lidarpkt.vendors.robosense.stream.DecoderStats` by drop reason."""
    return DropCounts(**st.drops())


def endpoints(match: Match) -> tuple[Endpoint, Endpoint]:
    port = PORTS[match.kind]
    return Endpoint(SENSOR_ADDRESS, port), Endpoint(HOST_ADDRESS, port)


def split(batch: PacketBatch, match: Match) -> list[tuple[Match, np.ndarray]]:
    """A batch's MSOP and DIFOP packets (a ``RobosenseScan`` carries its DIFOP among the MSOP): the DIFOP rows
    by their identifier (:func:`.detect.is_difop`), every other row MSOP; each with ``match`` of its kind."""
    from dataclasses import replace

    from .detect import is_difop

    difop = is_difop(batch.payload)
    return [(replace(match, stream=MSOP), ~difop), (replace(match, stream=DIFOP), difop)]


def sensor_file_in_packets(batch: PacketBatch, match: Match) -> Any:
    """The first DIFOP of a batch that decodes, as a :class:`~lidarpkt.vendors.robosense.calibration.DifopPacket`
    (``None`` when it holds none)."""
    from .calibration import DifopPacket
    from .describe import device_info
    from .detect import is_difop

    for row in batch.payload[is_difop(batch.payload)]:
        if device_info(row[None, :])[0] is not None:
            return DifopPacket(row.tobytes(), batch.src.address if batch.src is not None else None)
    return None


def _recognise(text: str) -> bool:
    from .calibration import is_robosense_csv

    return is_robosense_csv(text)


def _is_loaded(obj: Any) -> bool:
    from .calibration import DifopPacket, RobosenseCalibration

    return isinstance(obj, (RobosenseCalibration, DifopPacket))


def _load(obj: Any) -> Any:
    """A :class:`~lidarpkt.vendors.robosense.calibration.RobosenseCalibration` (a loaded one, or a DIFOP packet,
    passes through)."""
    from .calibration import DifopPacket, load_calibration

    return obj if isinstance(obj, DifopPacket) else load_calibration(obj)


def models() -> tuple[str, ...]:
    from .models import MODELS

    return tuple(m.name for m in MODELS)


def geometry(sensor: Any, calibration: Mapping[str, Any] | None) -> Any:
    """The XYZ of frames read back from a file: the angles of each row their SensorInfo keeps, the distance unit
    and the model's lens centre (``None`` for frames decoded without a calibration)."""
    metadata = sensor.metadata or {}
    if metadata.get("calibration_source") is None or "distance_unit_mm" not in metadata:
        return None
    import numpy as np

    from .calibration import RobosenseCalibration
    from .geometry import RobosenseGeometry
    from .models import model_named

    model = model_named(sensor.model)
    angles = RobosenseCalibration(np.asarray(sensor.beam_altitude_deg, np.float64),
                                  np.asarray(sensor.beam_azimuth_deg, np.float64), metadata["calibration_source"])
    unit_um = int(round(float(metadata["distance_unit_mm"]) * 1000))
    return RobosenseGeometry(angles, np.arange(angles.lasers), unit_um, model.lens_rx_m, model.lens_rz_m)


def ros_messages() -> RosMessages:
    from .ros import ROS

    return ROS


VENDOR = Vendor(
    name=NAME,
    title="RoboSense",
    streams=(MSOP, DIFOP),
    classify=classify,
    describe=describe,
    summary=summary,
    counter=counter,
    sensor_time_ns=sensor_time_ns,
    drops=drops,
    endpoints=endpoints,
    ros_messages=ros_messages,
    sensor_files=SensorFiles("RoboSense angle CSV", _recognise, _is_loaded, _load, needed_for="xyz"),
    frame_ids_counted=True,
    models=models,
    geometry=geometry,
    sensor_file_in_packets=sensor_file_in_packets,
    split=split,
)
