"""What streams and sensors a capture holds (:func:`describe_capture`), and its text report
(:func:`format_capture`): what ``lidarpkt info`` prints and ``lidarpkt catalog`` tabulates.

One line per stream (source address:port → destination port, one payload size): packet
count, size, first/last host time, duration, and what it is, as the sensor modules
describe it (:func:`lidarpkt.vendors.velodyne.describe_stream`, :func:`lidarpkt.vendors.ouster.describe_stream`,
:func:`lidarpkt.vendors.hesai.describe_stream`: Hesai Pandar data, model, protocol, return mode, motor speed):
VLP-16 data (return mode, product id) or position (PPS status, NMEA time of the first),
Ouster lidar (profile from the metadata given, else a guess from size and header) or IMU, or
unknown. Then the reader's counts: reassembled datagrams, orphaned fragments, malformed
records.
"""

from __future__ import annotations

import datetime as _dt
import os
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from lidarpkt.core.packet import Endpoint, PacketBatch
from lidarpkt.containers.magic import is_osf

__all__ = ["describe_capture", "format_capture"]

# a stream is described from its first packets only, so that info stays bounded in memory
DESCRIBE_MAX_BYTES = 64 * 1024 * 1024
DESCRIBE_MAX_PACKETS = 20_000


@dataclass
class _Stream:
    src: Endpoint | None
    dst: Endpoint | None
    size: int
    packets: int = 0
    first_ns: int = 0
    last_ns: int = 0
    first_index: int = 0
    kept: list[PacketBatch] = field(default_factory=list)
    kept_packets: int = 0


def _iso(ns: int) -> str:
    t = _dt.datetime.fromtimestamp(ns // 1_000_000_000, _dt.timezone.utc)
    return t.strftime("%Y-%m-%dT%H:%M:%S") + f".{ns % 1_000_000_000:09d}Z"


def _describe(batch: PacketBatch, metadata: Sequence[Any]) -> tuple[dict | None, str | None]:
    """(the vendor module's description of the stream, the vendor whose module described it)."""
    # the detect modules only: not the frame assembly, encoders or XYZ of either sensor package
    from lidarpkt.vendors.hesai.detect import describe_stream as hesai_stream
    from lidarpkt.vendors.ouster.detect import describe_stream as ouster_stream
    from lidarpkt.vendors.velodyne.detect import describe_stream as velodyne_stream

    found = velodyne_stream(batch)
    if found is not None:
        return found, "velodyne"
    found = hesai_stream(batch)  # sizes no VLP-16 or Ouster profile sends, checked by their bytes
    if found is not None:
        return found, "hesai"
    found = ouster_stream(batch, metadata) if metadata else ouster_stream(batch)
    return found, None if found is None else "ouster"


def _stream_kind(batch: PacketBatch, metadata: Sequence[Any]) -> str:
    """What ``lidarpkt.open``'s router makes of the stream (:class:`lidarpkt.core.streams.StreamKind`): a
    stream of frames (``velodyne_data``, ``ouster_lidar``), an auxiliary one, or ``other``."""
    from lidarpkt.pipeline.router import RouteOptions, Router
    from lidarpkt.core.streams import StreamKind

    match = Router(RouteOptions(metadata)).classify(batch)
    return str(StreamKind.OTHER if match is None else StreamKind.of(match.vendor, match.kind))


def describe_capture(path: str | os.PathLike[str], metadata: Sequence[Any] = ()) -> dict:
    """A JSON-ready description of one capture.

    Args:
        path: a pcap/pcapng file (or an MCAP file / ROS bag of raw packets: then the pcap-only
            counts are absent, and an Ouster metadata recorded in the file is used; or an OSF file:
            then ``{"file", "format": "osf", "osf_version", "sensors": [...], "frames", "first_time",
            "last_time", "duration_s", "streams": []}``, each sensor's model, serial, firmware,
            profile, size, frame count, frame ids and receive times).
        metadata: parsed Ouster metadata (:func:`lidarpkt.vendors.ouster.load_metadata`) for the
            sensors in the capture; used to name Ouster profiles exactly.

    Returns:
        ``{"file", "format", "link_types", "records", "udp_packets", "non_udp", "fragments",
        "reassembled", "orphaned_fragments", "duplicate_fragments", "malformed",
        "malformed_reasons", "truncated", "first_time", "last_time", "duration_s", "streams": [...]}``;
        each stream: ``src``, ``dst``, ``dst_port``, ``payload_size``, ``packets``, first/last time
        (ISO 8601 UTC and ``*_timestamp_ns``), ``duration_s``, ``kind`` (for people: ``"VLP-16 data"``),
        ``stream_kind`` (for programs: a :class:`lidarpkt.core.streams.StreamKind` value, what ``lidarpkt.open``
        routes it as), ``vendor`` (the sensor module that described it, None when none did) and ``details``
        (the sensor module's description, or None when unknown).

    Raises:
        lidarpkt.errors.CaptureFormatError: the file is not a readable capture.
    """
    if is_osf(path):
        return _describe_osf(path)
    reader, kind = _open_reader(path)
    streams: dict[tuple, _Stream] = {}
    for batch in reader.batches():
        key = (batch.src, batch.dst, batch.payload_size)
        s = streams.get(key)
        if s is None:
            s = streams[key] = _Stream(batch.src, batch.dst, batch.payload_size, first_ns=int(batch.timestamp_ns[0]),
                                       first_index=int(batch.index[0]))
        s.packets += len(batch)
        s.first_ns = min(s.first_ns, int(batch.timestamp_ns.min()))
        s.last_ns = max(s.last_ns, int(batch.timestamp_ns.max()))
        room = min(DESCRIBE_MAX_PACKETS - s.kept_packets, (DESCRIBE_MAX_BYTES // max(1, s.size)) - s.kept_packets)
        if room > 0:
            s.kept.append(batch if len(batch) <= room else batch.select(np.arange(room)))
            s.kept_packets += min(room, len(batch))
    if kind != "pcap" and not metadata:
        text = reader.ouster_metadata()  # recorded next to Ouster packets by lidarpkt record / the ROS driver
        if text:
            from lidarpkt.vendors.ouster import load_metadata

            metadata = [load_metadata(text)]
    out_streams = []
    for s in sorted(streams.values(), key=lambda s: s.first_index):
        batch = PacketBatch.concatenate(s.kept)
        s.kept = []
        try:
            details, vendor = _describe(batch, metadata)
            stream_kind = _stream_kind(batch, metadata)
            error = None
        except Exception as exc:  # a description must never stop info: say what failed
            details, vendor, stream_kind, error = None, None, "other", f"{type(exc).__name__}: {exc}"
        entry = {
            "src": str(s.src) if s.src else None,
            "dst": str(s.dst) if s.dst else None,
            "dst_port": s.dst.port if s.dst else None,
            "payload_size": s.size,
            "packets": s.packets,
            "first_time": _iso(s.first_ns),
            "last_time": _iso(s.last_ns),
            "first_timestamp_ns": s.first_ns,
            "last_timestamp_ns": s.last_ns,
            "duration_s": (s.last_ns - s.first_ns) / 1e9,
            "kind": (details or {}).get("kind", "unknown"),
            "stream_kind": stream_kind,
            "vendor": vendor,
            "details": details,
        }
        if s.kept_packets < s.packets:
            entry["described_from_first_packets"] = s.kept_packets
        if error:
            entry["describe_error"] = error
        out_streams.append(entry)
    first = min((s["first_timestamp_ns"] for s in out_streams), default=None)
    last = max((s["last_timestamp_ns"] for s in out_streams), default=None)
    doc: dict[str, Any] = {"file": os.fspath(path), "format": kind}
    if kind == "pcap":
        st = reader.stats
        doc.update(
            format=st.format,
            nanosecond=st.nanosecond,
            big_endian=st.big_endian,
            snaplen=st.snaplen,
            interfaces=st.interfaces,
            link_types=dict(st.link_types),
            bytes=st.bytes_read,
            records=st.records,
            udp_packets=st.udp_packets,
            non_udp=st.non_udp,
            fragments=st.fragments,
            reassembled=st.reassembled,
            orphaned_fragments=st.orphaned_fragments,
            duplicate_fragments=st.duplicate_fragments,
            malformed=st.malformed,
            malformed_reasons=dict(st.malformed_reasons),
            truncated=st.truncated,
            truncated_reason=st.truncated_reason or None,
        )
    else:  # a ROS bag or MCAP file: packets without network framing
        bs = reader.stats
        doc.update(
            records=bs.get("messages", 0),
            udp_packets=bs.get("packets", 0),
            skipped_topics=dict(bs.get("skipped_topics", {})),
            ouster_metadata_in_file=reader.ouster_metadata() is not None,
        )
    doc.update(
        first_time=_iso(first) if first is not None else None,
        last_time=_iso(last) if last is not None else None,
        duration_s=(last - first) / 1e9 if first is not None else 0.0,
        streams=out_streams,
    )
    return doc


def _describe_osf(path: str | os.PathLike[str]) -> dict:
    """:func:`describe_capture` of an OSF file: its version and, per sensor, its frames (no packets, no streams)."""
    from lidarpkt.vendors.ouster.osf import OsfFile

    osf = OsfFile(path)
    try:
        doc: dict[str, Any] = {"file": os.fspath(path), "format": "osf", **osf.describe()}
    finally:
        osf.close()
    firsts = [s["first_timestamp_ns"] for s in doc["sensors"] if s["first_timestamp_ns"] is not None]
    lasts = [s["last_timestamp_ns"] for s in doc["sensors"] if s["last_timestamp_ns"] is not None]
    for s in doc["sensors"]:
        for key in ("first", "last"):
            ns = s[f"{key}_timestamp_ns"]
            s[f"{key}_time"] = _iso(ns) if ns is not None else None
    doc.update(frames=sum(s["frames"] for s in doc["sensors"]),
               first_time=_iso(min(firsts)) if firsts else None, last_time=_iso(max(lasts)) if lasts else None,
               duration_s=(max(lasts) - min(firsts)) / 1e9 if firsts else 0.0, streams=[])
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


def _open_reader(path: str | os.PathLike[str]):
    """(reader, kind): the capture's packet reader (:func:`lidarpkt.containers.open_packet_source`) and its
    container kind (``"pcap"`` for pcap/pcapng, else ``"mcap"``, ``"rosbag1"``, ``"rosbag2"``)."""
    from lidarpkt.containers import container_kind, open_packet_source

    return open_packet_source(path), container_kind(path)


def _summary(stream: dict) -> str:
    d = stream.get("details") or {}
    kind = stream["kind"]
    if kind == "unknown":
        return "unknown" + (f" (description failed: {stream['describe_error']})" if "describe_error" in stream else "")
    bits = [kind]
    if "protocol" in d:  # Hesai
        bits.append(f"protocol {d['protocol']}")
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
    return ", ".join(str(b) for b in bits)


def format_capture(doc: dict) -> str:
    """The text report of one :func:`describe_capture` result."""
    if doc.get("format") == "osf":
        return _format_osf(doc)
    pcap = "link_types" in doc
    if pcap:
        links = ", ".join(f"{k}" for k in doc["link_types"]) or "no records"
        head = f"{doc['file']}: {doc['format']} ({links}), {doc['records']} records, {doc['udp_packets']} UDP packets"
    else:
        other = doc.get("skipped_topics") or {}
        head = (f"{doc['file']}: {doc['format']}, {doc['records']} packet messages, {doc['udp_packets']} packets"
                + (f" (not read: {', '.join(other)})" if other else ""))
    lines = [head + (f", {doc['first_time']} + {doc['duration_s']:.6f} s" if doc["first_time"] else "")]
    for s in doc["streams"]:
        where = f"{s['src']} → {s['dst_port']}" if s["src"] else "(no addresses)"
        lines.append(
            f"  {where}  {s['packets']} × {s['payload_size']} B  "
            f"{s['first_time'][11:]} → {s['last_time'][11:]} ({s['duration_s']:.6f} s)  {_summary(s)}"
        )
    if not doc["streams"]:
        lines.append("  no UDP packets" if pcap else "  no packets")
    if not pcap:
        return "\n".join(lines)
    counts = (
        f"  reassembled {doc['reassembled']} (from {doc['fragments']} fragments), orphaned fragments "
        f"{doc['orphaned_fragments']}, duplicate fragments {doc['duplicate_fragments']}, malformed {doc['malformed']}, "
        f"non-UDP {doc['non_udp']}"
    )
    lines.append(counts)
    if doc["malformed_reasons"]:
        lines.append("  malformed: " + "; ".join(f"{k}: {v}" for k, v in doc["malformed_reasons"].items()))
    if doc["truncated"]:
        lines.append(f"  TRUNCATED: {doc['truncated_reason']}")
    return "\n".join(lines)
