"""From packet batches to one decoder per sensor: the one router of files (``lidarpkt.open``) and live
sources (``record --points``, ``view``), driven by :class:`lidarpkt.pipeline.reader.Driver`.

Each batch is recognised by the vendors' registry (:data:`VENDORS`): an entry per vendor, in order,
whose classifier looks at the batch (its payload, size and ports, and the Ouster metadata given) and
answers with a :class:`Match`: the vendor's name of the stream, whether frames are made of it (lidar)
or it is auxiliary (Velodyne position, Ouster IMU), what tells its sensors apart beyond the source
address, and how to make the decoder of a new sensor. A new vendor is one entry. Decoders are used
only through the :class:`~lidarpkt.core.decoder.Decoder` protocol.

A sensor is its vendor, its source address and the match's ``sensor`` key; it gets its decoder on its
first packet, up to ``max_sensors`` of them (each holds up to a frame: a capture of thousands of source
addresses must not get one each). A batch no entry recognises, or of a sensor beyond the limit, is
unrouted: the caller counts it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Sequence

from lidarpkt.core.packet import PacketBatch

if TYPE_CHECKING:  # the router is imported by `info` too, which must not load the frame assembly
    from lidarpkt.core.decoder import Decoder

MAX_SENSORS = 64  # the default limit of sensors decoded from one source, files and live alike


@dataclass(frozen=True)
class Match:
    """What a vendor's classifier says of a batch it recognises.

    Attributes:
        vendor: the registry entry's name (``"velodyne"``, ``"ouster"``).
        kind: the vendor's name of the stream (``"data"``, ``"position"``, ``"lidar"``, ``"imu"``).
        lidar: True when frames are made of it (:meth:`Decoder.push`), False for auxiliary packets
            (:meth:`Decoder.push_auxiliary`).
        sensor: what tells this vendor's sensors apart beyond their source address (the Ouster
            metadata the packets fit), ``()`` when the address says it all.
        make: the decoder of a new sensor, given the sensor's source name.
    """

    vendor: str
    kind: str
    lidar: bool
    sensor: tuple
    make: Callable[[str], Decoder]


@dataclass(frozen=True)
class RouteOptions:
    """What the classifiers and decoder factories are given.

    Attributes:
        ouster_metadata: loaded Ouster metadata, one per sensor (Ouster packets are recognised by it).
        decoder_options: keyword options of each vendor's decoder, by vendor name.
    """

    ouster_metadata: Sequence[Any] = ()
    decoder_options: dict[str, dict[str, Any]] = field(default_factory=dict)

    def of(self, vendor: str) -> dict[str, Any]:
        return self.decoder_options.get(vendor, {})


@dataclass(frozen=True)
class Vendor:
    """A registry entry: a vendor's name and its classifier (``None``: not this vendor's batch)."""

    name: str
    classify: Callable[[PacketBatch, RouteOptions], Match | None]


def _ouster(batch: PacketBatch, options: RouteOptions) -> Match | None:
    if not options.ouster_metadata:
        return None
    from lidarpkt.vendors import ouster

    found = ouster.classify(batch, options.ouster_metadata)
    if found is None:
        return None
    kind, md = found
    return Match("ouster", kind, kind == "lidar", (id(md),),
                 lambda source: ouster.OusterDecoder(md, source=source, **options.of("ouster")))


def _velodyne(batch: PacketBatch, options: RouteOptions) -> Match | None:
    from lidarpkt.vendors import velodyne

    kind = velodyne.classify(batch)
    if kind is None:
        return None
    return Match("velodyne", kind, kind == "data", (),
                 lambda source: velodyne.VelodyneDecoder(source=source, **options.of("velodyne")))


def _hesai(batch: PacketBatch, options: RouteOptions) -> Match | None:
    from lidarpkt.vendors import hesai

    model = hesai.classify(batch)  # sizes only Pandars send, then their header or block start bytes
    if model is None:
        return None
    return Match("hesai", "data", True, (model.name,),
                 lambda source: hesai.HesaiDecoder(model=model, source=source, **options.of("hesai")))


#: The vendors, in the order their classifiers are asked (Ouster first: its packets are recognised only
#: with the metadata given, and then they are the metadata's, whatever their size says otherwise).
VENDORS: tuple[Vendor, ...] = (Vendor("ouster", _ouster), Vendor("velodyne", _velodyne), Vendor("hesai", _hesai))


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
        options: the :class:`RouteOptions`.
        max_sensors: most sensors given a decoder.
        on_limit: called once, when the first sensor beyond ``max_sensors`` is seen.
        vendors: the registry (default :data:`VENDORS`).

    Attributes:
        decoders: sensor key → its decoder, in order of first packet.
        packets: packets routed, by (vendor, stream kind).
    """

    def __init__(self, options: RouteOptions, *, max_sensors: int = MAX_SENSORS,
                 on_limit: Callable[[], None] | None = None, vendors: Sequence[Vendor] = VENDORS) -> None:
        self.options = options
        self.max_sensors = int(max_sensors)
        self.on_limit = on_limit
        self.vendors = tuple(vendors)
        self.decoders: dict[tuple, Decoder] = {}
        self.packets: dict[tuple[str, str], int] = {}
        self._named: set[tuple] = set()
        self._limited = False

    def classify(self, batch: PacketBatch) -> Match | None:
        """The first registry entry's match of ``batch``, or ``None``."""
        for vendor in self.vendors:
            match = vendor.classify(batch, self.options)
            if match is not None:
                return match
        return None

    def key(self, batch: PacketBatch, match: Match) -> tuple:
        """The sensor key of a matched batch: (vendor, source address, *match.sensor)."""
        src = batch.src.address if batch.src is not None else None
        return (match.vendor, src, *match.sensor)

    def route(self, batch: PacketBatch) -> Route | None:
        """The :class:`Route` of ``batch``, or ``None`` when no vendor recognises it. The sensor's decoder
        is made on its first batch unless the limit is reached; a lidar batch names its
        decoder after the data stream (:meth:`name_by_data`). Counts the batch in :attr:`packets` when it
        has a decoder."""
        match = self.classify(batch)
        return None if match is None else self.route_match(batch, match)

    def route_match(self, batch: PacketBatch, match: Match) -> Route:
        """:meth:`route` of a batch already classified (:meth:`classify`)."""
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
            self.packets[match.vendor, match.kind] = self.packets.get((match.vendor, match.kind), 0) + len(batch)
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
            metadata = getattr(decoder, "metadata", None)
            if metadata is not None:  # Ouster: the SensorInfo carries the name
                decoder.sensor = metadata.sensor_info(name)  # type: ignore[attr-defined]
