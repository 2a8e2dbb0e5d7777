"""The vendors lidarpkt knows (:data:`VENDORS`), and the questions the rest of lidarpkt asks of them all.

Each entry is a vendor package's :class:`~lidarpkt.core.vendor.Vendor` record. A new vendor is a folder
beside the others, exporting its record as ``VENDOR``, and its place in :data:`VENDORS`
(``docs/adding-a-vendor.md``). Nothing outside ``lidarpkt/vendors`` names a vendor: it asks here.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterable, Mapping

from lidarpkt.containers.protocol import PacketSource, open_packet_source
from lidarpkt.core.packet import PacketBatch
from lidarpkt.core.vendor import DecodeSetup, FrameFiles, Match, Vendor
from lidarpkt.errors import MetadataError
from . import hesai, ouster, robosense, velodyne

if TYPE_CHECKING:  # the ROS messages are read only where a bag or MCAP file is
    from lidarpkt.containers.rosmsgs import BagMessages

#: The vendors, in the order their classifiers are asked (Ouster first: with its metadata given, a stream
#: that fits the metadata is the sensor's, whatever its size says otherwise).
VENDORS: tuple[Vendor, ...] = (ouster.VENDOR, velodyne.VENDOR, hesai.VENDOR, robosense.VENDOR)

_BY_NAME = {v.name: v for v in VENDORS}
_SNIFF_BYTES = 64 << 10  # a sensor file is told by its first 64 KiB
_NOTHING_GIVEN = DecodeSetup()


def vendor(name: str) -> Vendor:
    """The record of the vendor called ``name`` (a :class:`~lidarpkt.core.sensor.SensorInfo`'s ``vendor``).

    Raises:
        KeyError: no vendor of that name.
    """
    return _BY_NAME[name]


def names() -> str:
    """The vendors for people: ``"Ouster, Velodyne or Hesai"``."""
    titles = [v.title for v in VENDORS]
    return ", ".join(titles[:-1]) + " or " + titles[-1] if len(titles) > 1 else titles[0]


# --------------------------------------------------------------------------- streams
def classify(batch: PacketBatch, setup: DecodeSetup | None = None) -> Match | None:
    """The one classifier: the first vendor's match that can decode ``batch``; else the first match (a stream
    recognised, not decodable: its sensor file is missing); ``None`` when no vendor recognises it."""
    setup = setup if setup is not None else _NOTHING_GIVEN
    recognised = None
    for v in VENDORS:
        match = v.classify(batch, setup)
        if match is not None:
            if match.decodable:
                return match
            recognised = recognised or match
    return recognised


def by_kind(batch: PacketBatch, match: Match) -> list[tuple[Match, PacketBatch]]:
    """``batch``, a stream of ``match``'s vendor, as the packets of each stream kind it holds with each kind's
    match: ``[(match, batch)]``, but where the vendor's :attr:`~lidarpkt.core.vendor.Vendor.split` finds
    several kinds in it (a ROS message carrying two streams), one part per kind in the order of its first
    packet (NumPy masks, no loop over packets)."""
    split = vendor(match.vendor).split
    if split is None:
        return [(match, batch)]
    parts = [(m, rows) for m, rows in split(batch, match) if rows.any()]
    if len(parts) <= 1:
        return [(parts[0][0] if parts else match, batch)]
    parts.sort(key=lambda part: int(part[1].argmax()))
    return [(m, batch.select(rows)) for m, rows in parts]


def factory_addressed(batch: PacketBatch, match: Match) -> list[PacketBatch]:
    """``batch``, which kept no addresses (a bag's), as batches from and to its vendor's factory endpoints
    (:attr:`~lidarpkt.core.vendor.Vendor.endpoints`): one per stream kind it holds (:func:`by_kind`), in the
    order of its first packet, so that each kind goes to its own port."""
    out = []
    for m, part in by_kind(batch, match):
        src, dst = vendor(m.vendor).endpoints(m)
        out.append(PacketBatch(src, dst, part.timestamp_ns, part.payload, part.index))
    return out


def undecoded_hint(path: Any, unrouted_streams: Mapping[Any, int], setup: DecodeSetup) -> str | None:
    """What to say when no stream was decoded but a vendor recognises some as its own (its sensor file is
    missing or does not fit), ``None`` when none does."""
    for v in VENDORS:
        if v.undecoded_hint is not None:
            hint = v.undecoded_hint(path, unrouted_streams, setup.files(v.name))
            if hint:
                return hint
    return None


def check_model(name: str | None) -> None:
    """``model=``: ``None``, or the name of a model some vendor takes (case, spaces and dashes ignored).

    Raises:
        UsageError: no vendor has a model of that name (the message lists them).
    """
    if name is None:
        return
    from lidarpkt.errors import UsageError

    names = [m for v in VENDORS if v.models is not None for m in v.models()]
    if _model_key(name) not in {_model_key(m) for m in names}:
        raise UsageError(f"model={name!r}: no such sensor model; give one of {', '.join(names)}")


def _model_key(name: str) -> str:
    return str(name).replace(" ", "").replace("-", "").replace("_", "").lower()


# --------------------------------------------------------------------------- sensor files
@dataclass(frozen=True)
class SensorFile:
    """A sensor file given (``metadata=``): its vendor, its name for messages, and the file as its vendor's
    decoder takes it."""

    vendor: str
    name: str
    loaded: Any

    @property
    def what(self) -> str:
        files = vendor(self.vendor).sensor_files
        return files.what if files is not None else "sensor file"

    @property
    def ports(self) -> tuple[int, ...]:
        """The UDP ports the file says its sensor sends to (``()`` when it does not say)."""
        files = vendor(self.vendor).sensor_files
        return () if files is None or files.ports is None else tuple(files.ports(self.loaded))


def load_sensor_files(items: Any) -> list[SensorFile]:
    """The sensor files of the ``metadata`` option (``None``, one, or a list: paths, JSON text, parsed or loaded
    objects), each told apart by its content and loaded by its vendor.

    Raises:
        MetadataError: a file that cannot be read or is of no kind lidarpkt knows (the message names it and
            the kinds), or what its vendor's loader raises.
        CalibrationError: what a vendor's loader raises.
    """
    if items is None:
        return []
    given = list(items) if isinstance(items, (list, tuple)) else [items]
    return [_load_one(item) for item in given]


def setup(files: Iterable[SensorFile], options: Mapping[str, Any] | None = None) -> DecodeSetup:
    """The :class:`~lidarpkt.core.vendor.DecodeSetup` of loaded sensor files and decoding options."""
    by_vendor: dict[str, tuple] = {}
    for f in files:
        by_vendor[f.vendor] = by_vendor.get(f.vendor, ()) + (f.loaded,)
    return DecodeSetup(by_vendor, dict(options or {}))


def _load_one(item: Any) -> SensorFile:
    if isinstance(item, SensorFile):
        return item
    for v in VENDORS:
        if v.sensor_files is not None and not isinstance(item, (str, os.PathLike)) and v.sensor_files.is_loaded(item):
            return SensorFile(v.name, getattr(item, "path", None) or getattr(item, "source", None) or v.sensor_files.what,
                              v.sensor_files.load(item))
    if not isinstance(item, (str, os.PathLike)):
        raise MetadataError(f"metadata={type(item).__name__}: not a sensor file lidarpkt reads; give {_kinds()} "
                            "(a path, or the loaded file)")
    text, name = _text_of(item)
    for v in VENDORS:
        if v.sensor_files is not None and v.sensor_files.recognise(text):
            return SensorFile(v.name, name, v.sensor_files.load(item))
    raise MetadataError(f"{name}: not a sensor file lidarpkt reads ({_what_it_is(text)}); give {_kinds()}")


_IN_BAND_SPAN_NS = 1_500_000_000  # a sensor sending its file in-band sends it at least this often
_IN_BAND_QUIET_NS = 100_000_000  # a capture none of whose streams of its first 0.1 s carries one has none


def sensor_files_in_packets(path: str | os.PathLike[str], setup: DecodeSetup) -> list[SensorFile]:
    """The sensor files the first packets of a capture carry (:attr:`~lidarpkt.core.vendor.Vendor.sensor_file_in_packets`),
    one per vendor and source address, looked for in its first 1.5 s (0.1 s when no stream of a vendor that
    sends one is there): what the reader of a later segment of the capture is given."""
    if not any(v.sensor_file_in_packets is not None for v in VENDORS):
        return []
    found: dict[tuple, SensorFile] = {}
    wanted: set[tuple] = set()
    start = None
    batches = open_packets(path).batches()
    try:
        for batch in batches:
            if not len(batch):
                continue
            start = int(batch.timestamp_ns[0]) if start is None else start
            elapsed = int(batch.timestamp_ns[0]) - start
            if elapsed > _IN_BAND_SPAN_NS or (not wanted and elapsed > _IN_BAND_QUIET_NS):
                break
            match = classify(batch, setup)
            v = vendor(match.vendor) if match is not None else None
            if match is None or v is None or v.sensor_file_in_packets is None:
                continue
            key = (v.name, batch.src.address if batch.src is not None else None)
            wanted.add(key)
            if key not in found:
                loaded = v.sensor_file_in_packets(batch, match)
                if loaded is not None:
                    found[key] = SensorFile(v.name, f"{os.fspath(path)} (in its packets)", loaded)
            if wanted <= set(found):
                break
    finally:
        close = getattr(batches, "close", None)
        if close is not None:
            close()
    return list(found.values())


def _kinds() -> str:
    whats = [v.sensor_files.what for v in VENDORS if v.sensor_files is not None]
    return ", ".join(whats[:-1]) + " or " + whats[-1] if len(whats) > 1 else whats[0]


def _text_of(item: str | os.PathLike[str]) -> tuple[str, str]:
    """(the first 64 KiB of a file as text, its name); JSON text given as such is its own text."""
    if isinstance(item, str) and item.lstrip().startswith("{"):
        return item, "(text)"
    path = Path(item)
    try:
        with path.open("rb") as fh:
            head = fh.read(_SNIFF_BYTES)
    except FileNotFoundError:
        raise MetadataError(f"{path}: no such file; give the sensor's file (metadata=...)") from None
    except (OSError, ValueError) as exc:  # a directory, no permission; a NUL in the path
        raise MetadataError(f"{path}: cannot read the sensor file: {getattr(exc, 'strerror', None) or exc}") from None
    return head.decode("utf-8", errors="replace"), str(path)


def _what_it_is(text: str) -> str:
    """A few words on what a file of no known kind holds."""
    start = text.lstrip()[:1]
    if not start:
        return "it is empty"
    if start in "{[":
        import json

        try:
            doc = json.loads(text)
        except (ValueError, RecursionError):
            return "it starts as JSON"
        return f"a JSON {type(doc).__name__} without the fields of any of them"
    if any(ord(c) < 9 or 13 < ord(c) < 32 or c == "\ufffd" for c in text[:64]):
        return "binary data: sensor files are text"
    first = text.lstrip().splitlines()[0]
    if "," in first:
        return f"comma-separated lines that are none of them; it starts with {first[:40]!r}"
    return f"it starts with {text.lstrip()[:40]!r}"


def open_packets(path: str | os.PathLike[str], **filters: Any) -> PacketSource:
    """The packet reader of any capture (:func:`lidarpkt.containers.open_packet_source`), a bag or MCAP file read
    for every vendor's packet messages and recorded sensor files (:func:`bag_messages`)."""
    return open_packet_source(path, messages=bag_messages, **filters)


# --------------------------------------------------------------------------- ROS messages
def bag_messages() -> BagMessages:
    """What the bag and MCAP readers read: every vendor's packet message types and their definitions, and the
    topics where a driver records its sensor file."""
    from lidarpkt.containers.rosmsgs import DEFINITIONS as GENERIC_DEFINITIONS
    from lidarpkt.containers.rosmsgs import STAMPED_PACKET, BagMessages, SensorFileTopic, stamped_packet

    definitions = dict(GENERIC_DEFINITIONS)
    packets: dict = {STAMPED_PACKET: stamped_packet}
    topics = []
    for v in VENDORS:
        definitions.update(v.ros.definitions)
        packets.update(v.ros.packets)
        if v.ros.sensor_file_topic is not None and v.ros.sensor_file_refusal is not None:
            what = v.sensor_files.what if v.sensor_files is not None else f"{v.title} sensor file"
            topics.append(SensorFileTopic(what, v.ros.sensor_file_topic, v.ros.sensor_file_refusal))
    return BagMessages(definitions, packets, tuple(topics))


def ros_definitions() -> dict[str, str]:
    """Every ``.msg`` definition lidarpkt reads or writes that rosbags' ROS 2 store lacks, by type."""
    return dict(bag_messages().definitions)


# --------------------------------------------------------------------------- frame files
def frame_files(path: str | os.PathLike[str]) -> FrameFiles | None:
    """The frame files a vendor records that ``path`` is (an OSF file...), ``None`` for any other path
    (a packet capture, or no file lidarpkt reads: opening it says so)."""
    from lidarpkt.containers.magic import FRAME_CONTAINERS, container_kind
    from lidarpkt.errors import UnsupportedContainerError

    if str(path).startswith("udp://"):
        return None
    try:
        kind = container_kind(path)
    except UnsupportedContainerError:
        return None
    if kind not in FRAME_CONTAINERS:
        return None
    return next((v.frame_files[kind] for v in VENDORS if kind in v.frame_files), None)


def geometry(sensor: Any, calibration: Mapping[str, Any] | None = None) -> Any:
    """The XYZ geometry of a sensor whose frames were read back from a file (its vendor's
    :attr:`~lidarpkt.core.vendor.Vendor.geometry`), ``None`` when it cannot be rebuilt."""
    v = _BY_NAME.get(sensor.vendor)
    return None if v is None or v.geometry is None else v.geometry(sensor, calibration)
