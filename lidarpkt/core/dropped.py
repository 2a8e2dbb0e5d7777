"""What a read of a capture skipped, lost or discarded, and why: one summary in the same words everywhere.

:class:`lidarpkt.pipeline.reader.FrameReader` warns once at the end of iteration with
:func:`dropped_summary` (a :class:`~lidarpkt.errors.DroppedPacketsWarning`), so every verb that
decodes, and every Python caller of :func:`lidarpkt.open`, is told the same thing. The container
readers warn about their own damage (truncated files, malformed records) themselves.

The reasons, in the words every report uses (:data:`REASONS`):

- ``lost``: missing from the stream (gaps in the sensor's own counters or timing), never received;
- ``late``: arrived after their frame was released, discarded;
- ``duplicate``: a copy of a packet already received, discarded;
- ``malformed``: wrong layout, flag, CRC or measurement id, skipped;
- ``corrupted``: their clock or counters jumped further than the capture time allows, off the packets
  on both sides (:mod:`lidarpkt.core.continuity`), skipped; never counted as packets lost;
- ``mismatched``: do not fit the Ouster metadata given (size, init_id or serial), skipped;
- ``unrouted``: of no VLP-16 or Ouster stream lidarpkt could identify, not decoded.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any, Callable, Iterator

REASONS: dict[str, str] = {
    "lost": "lost (missing from the stream, never received)",
    "late": "discarded as late (their frame was already complete)",
    "duplicate": "discarded as duplicates",
    "malformed": "skipped as malformed (layout, flag, CRC or measurement id)",
    "corrupted": "skipped as corrupted (their time or frame id jumped further than the capture time allows)",
    "mismatched": "skipped as not fitting the Ouster metadata (size, init_id or serial)",
    "unrouted": "not decoded (of no VLP-16 or Ouster stream)",
}


@dataclass
class DropCounts:
    """Packets dropped, by reason: its fields are the keys of :data:`REASONS`, in their order."""

    lost: int = 0
    late: int = 0
    duplicate: int = 0
    malformed: int = 0
    corrupted: int = 0
    mismatched: int = 0
    unrouted: int = 0

    def __iadd__(self, other: "DropCounts") -> "DropCounts":
        for f in fields(self):
            setattr(self, f.name, getattr(self, f.name) + getattr(other, f.name))
        return self

    def items(self) -> Iterator[tuple[str, int]]:
        """(reason, packets) of the reasons with packets, in :data:`REASONS` order."""
        return ((f.name, getattr(self, f.name)) for f in fields(self) if getattr(self, f.name))

    def total(self) -> int:
        return sum(n for _, n in self.items())


if [f.name for f in fields(DropCounts)] != list(REASONS):  # a reason is a field, and a field a reason
    raise ImportError("lidarpkt.core.dropped: DropCounts fields and REASONS differ")


def _velodyne(st: Any) -> DropCounts:
    return DropCounts(lost=st.lost_packets, late=st.late_packets, duplicate=st.duplicate_packets,
                      malformed=st.malformed + st.position_malformed, corrupted=st.corrupted_packets)


def _ouster(st: Any) -> DropCounts:
    return DropCounts(lost=st.lost_packets, late=st.late, duplicate=st.duplicates,
                      malformed=st.crc_failures + st.bad_measurement_id, corrupted=st.corrupted,
                      mismatched=st.size_mismatch + st.id_mismatch)


def _hesai(st: Any) -> DropCounts:
    return DropCounts(lost=st.lost_packets, late=st.late_packets, duplicate=st.duplicate_packets, malformed=st.malformed)


#: each vendor decoder's ``stats`` → its :class:`DropCounts` (by the vendor of the router's sensor key)
VENDOR_DROPS: dict[str, Callable[[Any], DropCounts]] = {"velodyne": _velodyne, "ouster": _ouster, "hesai": _hesai}


def dropped_counts(reader: Any) -> DropCounts:
    """Packets per reason over every decoder of a :class:`~lidarpkt.pipeline.reader.FrameReader` (its ``decoders``:
    sensor key (vendor, …) → decoder) and its unrouted packets."""
    counts = DropCounts()
    for key, decoder in getattr(reader, "decoders", {}).items():
        counts += VENDOR_DROPS[key[0]](decoder.stats)
    counts.unrouted += getattr(getattr(reader, "stats", None), "unrouted_packets", 0)
    return counts


def format_dropped(counts: DropCounts, total_packets: int | None = None) -> str:
    """``"12 lost (missing …), 3755 discarded as late (…)"``, or ``""`` when nothing was dropped."""
    parts = [f"{n} {REASONS[k]}" for k, n in counts.items()]
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
def ouster_layouts(size: int) -> list[str]:
    """Ouster lidar layouts (``"PROFILE (H px)"``) whose packets are ``size`` bytes, 16 columns each."""
    from lidarpkt.vendors.ouster.profiles import PROFILES

    return [f"{p.name} ({h} px)" for p in PROFILES.values() for h in (16, 32, 64, 128) if p.packet_size(h, 16) == size]


def no_sensor_hint(path: Any, unrouted_streams: dict[Any, int], metadata: list) -> str | None:
    """The error when no lidar stream was decoded but one has the size of Ouster lidar packets: the
    metadata is missing (and how to give it), or which packet size and profile of the given metadata
    disagree with the packets. ``None`` when no stream looks like Ouster lidar."""
    for key, count in unrouted_streams.items():  # keys: lidarpkt.pipeline.reader.UnroutedStream
        size = key.payload_size
        layouts = ouster_layouts(size) if size is not None else []
        if not layouts:
            continue
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
