"""What a read of a capture skipped, lost or discarded, and why: one summary in the same words everywhere.

:class:`lidarpkt.pipeline.reader.FrameReader` warns once at the end of iteration with
:func:`format_dropped` of its counts (a :class:`~lidarpkt.errors.DroppedPacketsWarning`), so every verb that
decodes, and every Python caller of :func:`lidarpkt.open`, is told the same thing. Each vendor says how
its decoder's counters fall under these reasons (:attr:`lidarpkt.core.vendor.Vendor.drops`). The container
readers warn about their own damage (truncated files, malformed records) themselves.

The reasons, in the words every report uses (:data:`REASONS`):

- ``lost``: missing from the stream (gaps in the sensor's own counters or timing), never received;
- ``late``: arrived after their frame was released, discarded;
- ``duplicate``: a copy of a packet already received, discarded;
- ``malformed``: wrong layout, flag, CRC or measurement id, skipped;
- ``corrupted``: their clock or counters jumped further than the capture time allows, off the packets
  on both sides (:mod:`lidarpkt.core.continuity`), skipped; never counted as packets lost;
- ``mismatched``: do not fit the sensor file given for them (size, init_id or serial), skipped;
- ``unrouted``: of no stream lidarpkt could decode, not decoded.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Iterator

REASONS: dict[str, str] = {
    "lost": "lost (missing from the stream, never received)",
    "late": "discarded as late (their frame was already complete)",
    "duplicate": "discarded as duplicates",
    "malformed": "skipped as malformed (layout, flag, CRC or measurement id)",
    "corrupted": "skipped as corrupted (their time or frame id jumped further than the capture time allows)",
    "mismatched": "skipped as not fitting the sensor file given (size, init_id or serial)",
    "unrouted": "not decoded (of no stream lidarpkt decodes)",
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


def format_dropped(counts: DropCounts, total_packets: int | None = None) -> str:
    """``"12 lost (missing …), 3755 discarded as late (…)"``, or ``""`` when nothing was dropped."""
    parts = [f"{n} {REASONS[k]}" for k, n in counts.items()]
    if not parts:
        return ""
    head = f"of {total_packets} packets, " if total_packets is not None else ""
    return head + ", ".join(parts)
