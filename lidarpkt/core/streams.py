"""What a stream of datagrams is (:class:`StreamKind`), and what a read of a capture saw, counted per
stream kind (:class:`SourceStats`).

A stream kind is data: the vendor that names it (a :mod:`lidarpkt.vendors` registry entry), the
vendor's name of the stream and whether frames are made of it. Each vendor declares its kinds; the
vendor registry's one classifier says which kind a batch of packets is (:data:`OTHER` for none).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple


@dataclass(frozen=True)
class StreamKind:
    """One kind of stream a vendor's sensors send.

    Attributes:
        vendor: the vendor's registry name (``""`` for :data:`OTHER`).
        name: the vendor's name of the stream (``"data"``, ``"position"``, ``"lidar"``, ``"imu"``...).
        lidar: True for the stream frames are made of (range measurements), False for auxiliary ones.

    ``str()`` gives ``"vendor_name"`` (``"other"`` for :data:`OTHER`), as ``lidarpkt info --json`` writes it.
    """

    vendor: str
    name: str
    lidar: bool = False

    def __str__(self) -> str:
        return f"{self.vendor}_{self.name}" if self.vendor else self.name

    def __format__(self, spec: str) -> str:
        return format(str(self), spec)

    @classmethod
    def parse(cls, text: str, lidar: bool = False) -> "StreamKind":
        """The kind a ``str()`` of it gave (``lidar`` is not in the text: give it where it matters)."""
        vendor, sep, name = str(text).partition("_")
        return cls(vendor, name, lidar) if sep else OTHER


#: a stream of no kind any vendor declares
OTHER = StreamKind("", "other")


class UnroutedStream(NamedTuple):
    """A stream a read did not decode, as :attr:`SourceStats.unrouted_streams` keys it; ``str()`` gives
    ``"src → dst (size B)"``."""

    src: str
    dst: str
    payload_size: int | None  # None: the streams beyond the listed ones, summed

    def __str__(self) -> str:
        return self.src if self.payload_size is None else f"{self.src} → {self.dst} ({self.payload_size} B)"


OTHER_STREAMS = UnroutedStream("(other streams)", "", None)


@dataclass
class SourceStats:
    """What a read of a capture saw: packets routed to decoders by stream kind, and streams it could not use.

    Attributes:
        batches, packets: batches and packets read.
        routed: packets handed to a decoder, by stream kind.
        unrouted_packets: packets of no stream lidarpkt could decode (or of sensors beyond the limit).
        unrouted_streams: those packets by stream (the first 1000 streams; the rest under
            :data:`OTHER_STREAMS`).
        filtered_sources: packets of the sources ``source=`` left out, by source address.
        frames: frames yielded.
    """

    batches: int = 0
    packets: int = 0
    routed: dict[StreamKind, int] = field(default_factory=dict)
    unrouted_packets: int = 0
    unrouted_streams: dict[UnroutedStream, int] = field(default_factory=dict)  # stream → packets
    filtered_sources: dict[str, int] = field(default_factory=dict)  # sources left out by source= → packets
    frames: int = 0

    def packets_of(self, vendor: str, name: str) -> int:
        """Packets routed of the stream kind ``name`` of ``vendor`` (``packets_of("velodyne", "data")``)."""
        return sum(n for kind, n in self.routed.items() if (kind.vendor, kind.name) == (vendor, name))

    @property
    def lidar_packets(self) -> int:
        """Packets routed of the streams frames are made of."""
        return sum(n for kind, n in self.routed.items() if kind.lidar)
