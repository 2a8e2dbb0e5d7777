"""From packet batches to one decoder per sensor: the one router of files (``lidarpkt.open``) and live
sources (``record --points``, ``view``), driven by :class:`lidarpkt.pipeline.reader.Driver`.

Each batch is recognised by the vendor registry's one classifier (:func:`lidarpkt.vendors.registry.classify`):
its :class:`~lidarpkt.core.vendor.Match` says which vendor's stream it is, whether frames are made of it
(lidar) or it is auxiliary, what tells its sensors apart beyond the source address, and how to make the
decoder of a new sensor (none: the vendor recognises the stream but cannot decode it without its sensor
file). Decoders are used only through the :class:`~lidarpkt.core.decoder.Decoder` protocol.

A sensor is its vendor, its source address and the match's ``sensor`` key; it gets its decoder on its
first packet, up to ``max_sensors`` of them (each holds up to a frame: a capture of thousands of source
addresses must not get one each). A batch no vendor can decode, or of a sensor beyond the limit, is
unrouted: the caller counts it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

from lidarpkt.core.packet import PacketBatch
from lidarpkt.core.vendor import DecodeSetup, Match
from lidarpkt.vendors import registry

if TYPE_CHECKING:  # the router is imported by `info` too, which must not load the frame assembly
    from lidarpkt.core.decoder import Decoder
    from lidarpkt.core.streams import StreamKind

MAX_SENSORS = 64  # the default limit of sensors decoded from one source, files and live alike


def source_name(batch: PacketBatch) -> str:
    """The name of a batch's source (``"192.168.1.201:2368"``), ``"unknown source"`` when it has none."""
    return str(batch.src) if batch.src is not None else "unknown source"


@dataclass
class Route:
    """Where a batch goes: its sensor's key (vendor, source address, match's sensor key), the match, and
    the sensor's decoder (``None`` when the sensor is beyond the limit)."""

    key: tuple
    match: Match
    decoder: Decoder | None


class Router:
    """Routes batches to one decoder per sensor (see the module doc).

    Args:
        setup: the sensor files and decoding options the vendors' classifiers and decoders are given.
        max_sensors: most sensors given a decoder.
        on_limit: called once, when the first sensor beyond ``max_sensors`` is seen.

    Attributes:
        decoders: sensor key → its decoder, in order of first packet.
        packets: packets routed, by stream kind.
    """

    def __init__(self, setup: DecodeSetup, *, max_sensors: int = MAX_SENSORS,
                 on_limit: Callable[[], None] | None = None) -> None:
        self.setup = setup
        self.max_sensors = int(max_sensors)
        self.on_limit = on_limit
        self.decoders: dict[tuple, Decoder] = {}
        self.packets: dict[StreamKind, int] = {}
        self._named: set[tuple] = set()
        self._limited = False

    def classify(self, batch: PacketBatch) -> Match | None:
        """The registry's match of ``batch`` (:func:`lidarpkt.vendors.registry.classify`), or ``None``."""
        return registry.classify(batch, self.setup)

    def key(self, batch: PacketBatch, match: Match) -> tuple:
        """The sensor key of a matched batch: (vendor, source address, *match.sensor)."""
        src = batch.src.address if batch.src is not None else None
        return (match.vendor, src, *match.sensor)

    def route(self, batch: PacketBatch) -> Route | None:
        """The :class:`Route` of ``batch``, or ``None`` when no vendor can decode it. The sensor's decoder
        is made on its first batch unless the limit is reached; a lidar batch names its
        decoder after the data stream (:meth:`name_by_data`). Counts the batch in :attr:`packets` when it
        has a decoder."""
        match = self.classify(batch)
        return None if match is None or match.make is None else self.route_match(batch, match)

    def route_match(self, batch: PacketBatch, match: Match) -> Route:
        """:meth:`route` of a batch already classified (:meth:`classify`) as decodable."""
        assert match.make is not None  # a decodable match
        key = self.key(batch, match)
        decoder = self.decoders.get(key)
        if decoder is None:
            if len(self.decoders) < self.max_sensors:
                decoder = self.decoders[key] = match.make(source_name(batch))
            elif not self._limited:
                self._limited = True
                if self.on_limit is not None:
                    self.on_limit()
        if decoder is not None:
            self.packets[match.stream] = self.packets.get(match.stream, 0) + len(batch)
            if match.lidar:
                self.name_by_data(key, decoder, batch)
        return Route(key, match, decoder)

    def name_by_data(self, key: tuple, decoder: Decoder, batch: PacketBatch) -> None:
        """A sensor is named after its data stream (address:port of its first lidar packet), even when an
        auxiliary packet came first and made its decoder: so every segment of a capture, and a live
        stream whose IMU packets came first, name it alike."""
        if key in self._named:
            return
        self._named.add(key)
        name = source_name(batch)
        if decoder.source != name:
            decoder.source = name
