"""What streams and sensors a capture holds (:func:`describe_capture`), and its text report
(:func:`format_capture`): what ``lidarpkt info`` prints and ``lidarpkt catalog`` tabulates.

One line per stream (source address:port → destination port, one payload size): packet
count, size, first/last host time, duration, and what it is: the vendor registry's classifier
names the vendor, whose module describes the stream (``Vendor.describe``: model, return mode,
profile from the sensor file given, else a guess from the packets...) and words it
(``Vendor.summary``), or unknown. Then the reader's counts: reassembled datagrams, orphaned
fragments, malformed records.
"""

from __future__ import annotations

import datetime as _dt
import os
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from lidarpkt.core.packet import Endpoint, PacketBatch

if TYPE_CHECKING:
    from lidarpkt.core.vendor import DecodeSetup, FrameFiles

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


def _describe(batch: PacketBatch, setup: DecodeSetup) -> tuple[dict | None, str | None, str]:
    """(the vendor's description of the stream, the vendor that recognised it, what ``lidarpkt.open``'s router
    makes of it: a :class:`~lidarpkt.core.streams.StreamKind` text, ``"other"`` when it decodes none)."""
    from lidarpkt.core.streams import OTHER
    from lidarpkt.vendors import registry

    match = registry.classify(batch, setup)
    if match is None:
        return None, None, str(OTHER)
    details = registry.vendor(match.vendor).describe(batch, setup)
    return details, match.vendor if details is not None else None, str(match.stream if match.decodable else OTHER)


def describe_capture(path: str | os.PathLike[str], metadata: Any = ()) -> dict:
    """A JSON-ready description of one capture.

    Args:
        path: a pcap/pcapng file (or an MCAP file / ROS bag of raw packets: then the pcap-only
            counts are absent, and a sensor file recorded in the file is used; or a file of decoded
            frames a vendor records, OSF: then ``{"file", "format", "sensors": [...], "frames",
            "first_time", "last_time", "duration_s", "streams": []}`` and what its vendor adds, each
            sensor's kind, vendor, model, serial, firmware, profile, size, frame count, frame ids and
            receive times).
        metadata: the sensor files of the capture's sensors, as ``lidarpkt.open`` takes them (paths or
            loaded); they name what the packets are exactly (an Ouster profile...).

    Returns:
        ``{"file", "format", "link_types", "records", "udp_packets", "non_udp", "fragments",
        "reassembled", "orphaned_fragments", "duplicate_fragments", "malformed",
        "malformed_reasons", "truncated", "first_time", "last_time", "duration_s", "streams": [...]}``;
        each stream: ``src``, ``dst``, ``dst_port``, ``payload_size``, ``packets``, first/last time
        (ISO 8601 UTC and ``*_timestamp_ns``), ``duration_s``, ``kind`` (for people: ``"VLP-16 data"``),
        ``stream_kind`` (for programs: a :class:`lidarpkt.core.streams.StreamKind` value, what ``lidarpkt.open``
        routes it as), ``vendor`` (the vendor that described it, None when none did) and ``details``
        (the vendor's description, or None when unknown).

    Raises:
        lidarpkt.errors.CaptureFormatError: the file is not a readable capture.
    """
    from lidarpkt.vendors import registry

    frame_files = registry.frame_files(path)
    if frame_files is not None:
        return _describe_frame_file(path, frame_files)
    files = registry.load_sensor_files(list(metadata) if isinstance(metadata, (list, tuple)) else metadata)
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
    recorded = reader.recorded_sensor_file() if kind != "pcap" else None  # lidarpkt record's, a ROS driver's
    if recorded:
        f = registry.load_sensor_files([recorded])[0]
        if not any(g.vendor == f.vendor for g in files):
            files.append(f)
    setup = registry.setup(files)
    out_streams = []
    for s in sorted(streams.values(), key=lambda s: s.first_index):
        batch = PacketBatch.concatenate(s.kept)
        s.kept = []
        try:
            details, vendor, stream_kind = _describe(batch, setup)
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
            sensor_file_in_capture=recorded is not None,
        )
    doc.update(
        first_time=_iso(first) if first is not None else None,
        last_time=_iso(last) if last is not None else None,
        duration_s=(last - first) / 1e9 if first is not None else 0.0,
        streams=out_streams,
    )
    return doc


def _describe_frame_file(path: str | os.PathLike[str], files: FrameFiles) -> dict:
    """:func:`describe_capture` of a file of decoded frames: its vendor's summary, per sensor its frames (no packets,
    no streams)."""
    from lidarpkt.containers.magic import container_kind

    doc: dict[str, Any] = {"file": os.fspath(path), "format": container_kind(path), **files.describe(path)}
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


def _open_reader(path: str | os.PathLike[str]):
    """(reader, kind): the capture's packet reader (:func:`lidarpkt.vendors.registry.open_packets`) and its
    container kind (``"pcap"`` for pcap/pcapng, else ``"mcap"``, ``"rosbag1"``, ``"rosbag2"``)."""
    from lidarpkt.containers import container_kind
    from lidarpkt.vendors.registry import open_packets

    return open_packets(path), container_kind(path)


def _summary(stream: dict) -> str:
    d = stream.get("details") or {}
    kind = stream["kind"]
    if kind == "unknown":
        return "unknown" + (f" (description failed: {stream['describe_error']})" if "describe_error" in stream else "")
    from lidarpkt.vendors import registry

    bits = [kind] + (registry.vendor(stream["vendor"]).summary(d) if stream.get("vendor") else [])
    return ", ".join(str(b) for b in bits)


def format_capture(doc: dict) -> str:
    """The text report of one :func:`describe_capture` result."""
    if "sensors" in doc and not doc["streams"]:  # a file of decoded frames
        from lidarpkt.vendors import registry

        files = registry.frame_files(doc["file"])
        if files is not None:
            return files.summary(doc)
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
