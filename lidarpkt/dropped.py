"""What a read of a capture skipped, lost or discarded, and why: one summary in the same words everywhere.

:class:`lidarpkt.source.FrameReader` warns once at the end of iteration with
:func:`dropped_summary` (a :class:`~lidarpkt.errors.DroppedPacketsWarning`), so every verb that
decodes, and every Python caller of :func:`lidarpkt.open`, is told the same thing. The container
readers warn about their own damage (truncated files, malformed records) themselves.

The reasons, in the words every report uses (:data:`REASONS`):

- ``lost``: missing from the stream (gaps in the sensor's own counters or timing), never received;
- ``late``: arrived after their frame was released, discarded;
- ``duplicate``: a copy of a packet already received, discarded;
- ``malformed``: wrong layout, flag, CRC or measurement id, skipped;
- ``mismatched``: do not fit the Ouster metadata given (size, init_id or serial), skipped;
- ``unrouted``: of no VLP-16 or Ouster stream lidarpkt could identify, not decoded.
"""

from __future__ import annotations

import re
from typing import Any

REASONS: dict[str, str] = {
    "lost": "lost (missing from the stream, never received)",
    "late": "discarded as late (their frame was already complete)",
    "duplicate": "discarded as duplicates",
    "malformed": "skipped as malformed (layout, flag, CRC or measurement id)",
    "mismatched": "skipped as not fitting the Ouster metadata (size, init_id or serial)",
    "unrouted": "not decoded (of no VLP-16 or Ouster stream)",
}


def dropped_counts(reader: Any) -> dict[str, int]:
    """Packets per reason (keys of :data:`REASONS`, zeros left out) over every decoder of a
    :class:`~lidarpkt.source.FrameReader`."""
    counts = dict.fromkeys(REASONS, 0)
    for decoder in getattr(reader, "decoders", {}).values():
        st = getattr(decoder, "stats", None)
        if st is None:
            continue
        if hasattr(st, "late_packets"):  # VLP-16
            counts["lost"] += st.lost_packets
            counts["late"] += st.late_packets
            counts["duplicate"] += st.duplicate_packets
            counts["malformed"] += st.malformed + getattr(st, "position_malformed", 0)
        else:  # Ouster
            counts["lost"] += getattr(st, "lost_packets", 0)
            counts["late"] += getattr(st, "late", 0)
            counts["duplicate"] += getattr(st, "duplicates", 0)
            counts["malformed"] += getattr(st, "crc_failures", 0) + getattr(st, "bad_measurement_id", 0)
            counts["mismatched"] += getattr(st, "size_mismatch", 0) + getattr(st, "id_mismatch", 0)
    counts["unrouted"] += getattr(getattr(reader, "stats", None), "unrouted_packets", 0)
    return {k: v for k, v in counts.items() if v}


def format_dropped(counts: dict[str, int], total_packets: int | None = None) -> str:
    """``"12 lost (missing …), 3755 discarded as late (…)"``, or ``""`` when nothing was dropped."""
    parts = [f"{n} {REASONS[k]}" for k, n in counts.items() if n]
    if not parts:
        return ""
    head = f"of {total_packets} packets, " if total_packets is not None else ""
    return head + ", ".join(parts)


def dropped_summary(reader: Any) -> str | None:
    """The end-of-read summary line of a FrameReader (``None`` when nothing was dropped)."""
    text = format_dropped(dropped_counts(reader), getattr(getattr(reader, "stats", None), "packets", None))
    if not text:
        return None
    return f"{reader.path}: {text}; the frames hold what arrived (counts per decoder in .decoders[...].stats)"


# ------------------------------------------------------------------------------ no sensor found
_SIZE = re.compile(r"\((\d+) B\)$")


def ouster_layouts(size: int) -> list[str]:
    """Ouster lidar layouts (``"PROFILE (H px)"``) whose packets are ``size`` bytes, 16 columns each."""
    from .ouster.profiles import PROFILES

    return [f"{p.name} ({h} px)" for p in PROFILES.values() for h in (16, 32, 64, 128) if p.packet_size(h, 16) == size]


def no_sensor_hint(path: Any, unrouted_streams: dict[str, int], metadata: list) -> str | None:
    """The error when no lidar stream was decoded but one has the size of Ouster lidar packets: the
    metadata is missing (and how to give it), or which packet size and profile of the given metadata
    disagree with the packets. ``None`` when no stream looks like Ouster lidar."""
    for key, count in unrouted_streams.items():
        m = _SIZE.search(key)
        layouts = ouster_layouts(int(m.group(1))) if m else []
        if not layouts or m is None:
            continue
        size = int(m.group(1))
        if not metadata:
            return (f"{path}: the stream {key}, {count} packets, has the size of Ouster lidar packets "
                    f"({' or '.join(layouts)}) but no Ouster metadata was given; pass the sensor's metadata JSON "
                    "with --metadata M.json (metadata=... in Python)")
        expected = "; ".join(
            f"{md.prod_line or 'its sensor'} {md.profile.name} with {md.pixels_per_column} px sends "
            f"{md.profile.packet_size(md.pixels_per_column, md.columns_per_packet)} B packets" for md in metadata)
        return (f"{path}: the Ouster metadata does not fit the stream {key}: {expected}, but these packets are "
                f"{size} B (which fits {' or '.join(layouts)}); give the metadata JSON of the sensor that recorded "
                "this capture")
    return None
