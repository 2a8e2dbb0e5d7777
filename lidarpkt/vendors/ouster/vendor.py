"""The Ouster entry of the vendor registry (:data:`VENDOR`, a :class:`~lidarpkt.core.vendor.Vendor`): what the
rest of lidarpkt asks of Ouster sensors, answered by this package's modules (imported when asked).

Ouster packets are decoded with the sensor's metadata JSON (its sensor file, needed): with it a stream is
the sensor's whatever its size says otherwise; without one fitting, lidar and IMU streams are still
recognised by their size and headers (a guess, as ``lidarpkt info`` makes it), not decoded.
"""

from __future__ import annotations

import os
from typing import Any, Mapping, Sequence

from lidarpkt.core.dropped import DropCounts
from lidarpkt.core.packet import Endpoint, PacketBatch
from lidarpkt.core.streams import StreamKind
from lidarpkt.core.vendor import DecodeSetup, FrameFiles, Match, RosMessages, SensorFiles, Vendor

NAME = "ouster"
LIDAR = StreamKind(NAME, "lidar", lidar=True)
IMU = StreamKind(NAME, "imu")
ZONE = StreamKind(NAME, "zone")
_STREAMS = {k.name: k for k in (LIDAR, IMU, ZONE)}

# a sensor without a DHCP lease takes a link-local address; the host is the other end
SENSOR_ADDRESS = "169.254.0.2"
HOST_ADDRESS = "169.254.0.1"

# keys of the metadata JSON (either layout) that tell it from another JSON document
_METADATA_KEYS = frozenset({"beam_intrinsics", "beam_altitude_angles", "lidar_data_format", "data_format",
                            "sensor_info", "config_params", "lidar_mode", "lidar_intrinsics"})


def classify(batch: PacketBatch, setup: DecodeSetup) -> Match | None:
    """Lidar, IMU or zone-monitoring packets of a sensor whose metadata was given (:func:`.detect.classify`);
    else lidar or IMU packets by their size and headers, not decodable (:func:`.detect.guess`)."""
    mds = setup.files(NAME)
    if not mds:
        from .auxiliary import IMU_PACKET_SIZE
        from .profiles import guessable_packet_sizes

        if batch.payload_size != IMU_PACKET_SIZE and batch.payload_size not in guessable_packet_sizes():
            return None  # a size no Ouster stream has: another vendor's, without importing the detection
    from .detect import classify as of_sensor, guess

    found = of_sensor(batch, mds) if mds else None
    if found is None:
        kind = guess(batch)
        return None if kind is None else Match(_STREAMS[kind])
    kind, md = found
    verify_crc, soft_id_check = setup.option("verify_crc", True), bool(setup.option("soft_id_check", False))

    def make(source: str):
        from .frames import OusterDecoder

        return OusterDecoder(md, source=source, verify_crc=verify_crc, soft_id_check=soft_id_check)

    return Match(_STREAMS[kind], (id(md),), make, (md,))


def describe(batch: PacketBatch, setup: DecodeSetup) -> dict | None:
    from .detect import describe_stream

    return describe_stream(batch, setup.files(NAME))


def summary(d: dict) -> list[str]:
    """``info``'s words for a stream's description (after its kind)."""
    bits = []
    kind = d.get("kind")
    if "profile" in d:
        candidates = [str(c) for c in d.get("candidates", [])]
        if d.get("profile_source") == "guess" and len(candidates) > 1:
            bits.append("profile guessed from size and header: " + " or ".join(candidates))
        else:
            source = d.get("profile_source", "?")
            bits.append(f"{d['profile']} ({'guessed from size and header' if source == 'guess' else source})")
            if d.get("pixels_per_column"):
                bits.append(f"{d['pixels_per_column']} px")
        if "frame_id" in d:
            bits.append(f"frame ids {d['frame_id'][0]}–{d['frame_id'][1]}")
        if d.get("crc") and d["crc"] != "absent":
            bits.append(f"CRC {d['crc']}")
        if d.get("header_type") == "FUSA":
            bits.append("FUSA header")
        for key, what in (("shot_limiting_packets", "shot limiting"), ("thermal_shutdown_packets", "thermal shutdown")):
            if d.get(key):  # firmware 3.x packet-header status: worth a warning to the user
                bits.append(f"{what} reported in {d[key]} packets")
    if kind == "Ouster IMU" and d.get("imu_profile"):
        bits.append(f"{d['imu_profile']}, {d.get('samples', 0)} samples")
    if kind == "Ouster zone monitoring":
        bits.append(f"{d.get('zones_live', 0)} live zones, {d.get('zones_triggered', 0)} triggered")
    if d.get("note"):
        bits.append(d["note"])
    if kind == "Ouster lidar" and d.get("profile_source") == "guess":  # what decode & co will ask for
        bits.append("no metadata given: decoding needs the sensor's metadata JSON, --metadata M.json")
    return bits


def counter(batch: PacketBatch, match: Match):
    """The loss and frame counter of a lidar stream of a sensor whose metadata was given."""
    if match.stream != LIDAR or not match.sensor_files:
        return None
    from .stream import PacketCounter

    return PacketCounter(match.sensor_files[0])


def sensor_time_ns(batch: PacketBatch, match: Match) -> int | None:
    """The timestamp of the first column of a lidar packet (the sensor's clock, often from its boot)."""
    if match.stream != LIDAR or not match.sensor_files:
        return None
    import numpy as np

    md = match.sensor_files[0]
    dtype = md.profile.packet_dtype(md.pixels_per_column, md.columns_per_packet)
    first = np.ascontiguousarray(batch.payload[:1]).view(dtype)[0, 0]["columns"][0]
    return int(first["timestamp_ns"])


def drops(st: Any) -> DropCounts:
    """:class:`~lidarpkt.vendors.ouster.frames.OusterDecoderStats` by drop reason."""
    return DropCounts(lost=st.lost_packets, late=st.late, duplicate=st.duplicates,
                      malformed=st.crc_failures + st.bad_measurement_id, corrupted=st.corrupted,
                      mismatched=st.size_mismatch + st.id_mismatch)


def endpoints(match: Match) -> tuple[Endpoint, Endpoint]:
    """The metadata's ports (the default ones without it), from the link-local address to the host."""
    from .metadata import DEFAULT_IMU_PORT, DEFAULT_LIDAR_PORT

    if match.sensor_files:
        md = match.sensor_files[0]
        port = md.lidar_port if match.stream == LIDAR else md.zm_port if match.stream == ZONE and md.zm_port \
            else md.imu_port
    else:
        port = DEFAULT_LIDAR_PORT if match.stream == LIDAR else DEFAULT_IMU_PORT
    return Endpoint(SENSOR_ADDRESS, port), Endpoint(HOST_ADDRESS, port)


# --------------------------------------------------------------------------- sensor files
def _is_metadata_document(doc: Any) -> bool:
    return isinstance(doc, dict) and not _METADATA_KEYS.isdisjoint(doc)


def _recognise(text: str) -> bool:
    """A JSON object with the fields of the metadata (either layout)."""
    if not text.lstrip().startswith("{"):
        return False
    import json

    try:
        return _is_metadata_document(json.loads(text))
    except (ValueError, RecursionError):  # not JSON, or cut at 64 KiB: the opening of a metadata document
        head = text[:4096]
        return any(f'"{key}"' in head for key in _METADATA_KEYS)


def _is_loaded(obj: Any) -> bool:
    if _is_metadata_document(obj):
        return True
    from .metadata import OusterMetadata

    return isinstance(obj, OusterMetadata)


def _load(obj: Any) -> Any:
    """An :class:`~lidarpkt.vendors.ouster.metadata.OusterMetadata` (a loaded one passes through)."""
    from .metadata import OusterMetadata
    from .metadata_json import load_metadata

    return obj if isinstance(obj, OusterMetadata) else load_metadata(obj)


# --------------------------------------------------------------------------- no stream decoded
def _layouts(size: int) -> list[str]:
    """Lidar layouts (``"PROFILE (H px)"``) whose packets are ``size`` bytes, 16 columns each."""
    from .profiles import PROFILES

    return [f"{p.name} ({h} px)" for p in PROFILES.values() for h in (16, 32, 64, 128) if p.packet_size(h, 16) == size]


def undecoded_hint(path: Any, unrouted_streams: Mapping[Any, int], metadata: Sequence[Any]) -> str | None:
    """The error when no lidar stream was decoded but one has the size of Ouster lidar packets: the
    metadata is missing (and how to give it), or which packet size and profile of the given metadata
    disagree with the packets. ``None`` when no stream looks like Ouster lidar."""
    for key, count in unrouted_streams.items():  # keys: lidarpkt.core.streams.UnroutedStream
        size = key.payload_size
        layouts = _layouts(size) if size is not None else []
        if not layouts:
            continue
        if not metadata:
            return (f"{path}: the stream {key}, {count} packets, has the size of Ouster lidar packets "
                    f"({' or '.join(layouts)}) but no Ouster metadata was given; pass the sensor's metadata JSON "
                    "with --metadata M.json (metadata=... in Python)")
        return (f"{path}: the Ouster metadata does not fit the stream {key}: "
                f"{'; '.join(_difference(md, size, layouts) for md in metadata)}; give the metadata JSON of the sensor "
                "that recorded this capture")
    return None


def _difference(md: Any, size: int, layouts: list[str]) -> str:
    """What differs between the packets of one metadata's sensor and a stream of ``size`` B packets."""
    sensor = f"{md.prod_line or 'its sensor'} {md.profile.name} with {md.pixels_per_column} px"
    expected = md.profile.packet_size(md.pixels_per_column, md.columns_per_packet)
    if expected != size:
        return f"{sensor} sends {expected} B packets, but these are {size} B (which fits {' or '.join(layouts)})"
    if md.profile.legacy:
        return f"{sensor} sends {size} B packets as these are, but they do not read as its packets"
    ids = ", ".join(x for x in (f"init_id {md.init_id}" if md.init_id else "",
                                f"serial {md.serial}" if getattr(md, "serial", None) else "") if x)
    return (f"{sensor} sends {size} B packets as these are, but their header names another sensor "
            f"(not {ids or 'its init_id and serial'})")


# --------------------------------------------------------------------------- OSF files
def _open_osf(path: str | os.PathLike[str], stats: Any, include_partial: bool):
    from .osf import OsfReader

    return OsfReader(path, stats, include_partial=include_partial)


def _describe_osf(path: str | os.PathLike[str]) -> dict:
    from .osf import OsfFile

    osf = OsfFile(path)
    try:
        doc = osf.describe()
    finally:
        osf.close()
    for sensor in doc["sensors"]:
        sensor.update(kind="Ouster frames (OSF)", vendor=NAME)
    return doc


def _format_osf(doc: dict) -> str:
    n = len(doc["sensors"])
    head = f"{doc['file']}: OSF {doc['osf_version']}, {n} sensor{'s' * (n != 1)}, {doc['frames']} frames"
    lines = [head + (f", {doc['first_time']} + {doc['duration_s']:.6f} s" if doc["first_time"] else "")]
    for s in doc["sensors"]:
        ids = f", frame ids {s['frame_ids'][0]}–{s['frame_ids'][1]}" if s["frame_ids"] else ""
        lines.append(f"  {s['model']} {s['serial'] or '?'} ({s['firmware'] or 'firmware ?'}): {s['profile']}, "
                     f"{s['columns_per_frame']} × {s['rows']}, {s['frames']} frames{ids} (decoded frames: no packets)")
    if not doc["sensors"]:
        lines.append("  no sensor")
    return "\n".join(lines)


def _receive_span(path: str | os.PathLike[str]) -> tuple[int | None, int | None]:
    from .osf import receive_span

    return receive_span(path)


def geometry(sensor: Any, calibration: Mapping[str, Any] | None) -> Any:
    """The XYZ of frames read back from a file: from the metadata JSON their SensorInfo carries."""
    if not sensor.metadata:
        return None
    from .metadata_json import load_metadata

    return load_metadata(sensor.metadata).sensor_info().geometry


def ros_messages() -> RosMessages:
    from .ros import ROS

    return ROS


VENDOR = Vendor(
    name=NAME,
    title="Ouster",
    streams=(LIDAR, IMU, ZONE),
    classify=classify,
    describe=describe,
    summary=summary,
    counter=counter,
    sensor_time_ns=sensor_time_ns,
    drops=drops,
    endpoints=endpoints,
    ros_messages=ros_messages,
    sensor_files=SensorFiles("Ouster metadata JSON", _recognise, _is_loaded, _load, needed_for="decoding",
                             ports=lambda md: (md.lidar_port, md.imu_port)),
    frame_files={"osf": FrameFiles("OSF file", _open_osf, _describe_osf, _format_osf, _receive_span)},
    undecoded_hint=undecoded_hint,
    geometry=geometry,
)
