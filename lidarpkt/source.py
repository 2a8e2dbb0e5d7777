"""From a capture file to frames: container detection, stream routing, one decoder per sensor.

``lidarpkt.open(path)`` is :func:`open_frames`. The container (pcap, pcapng, MCAP,
rosbag2, ROS 1 bag) is recognised by its first bytes, not its name. Every batch of
packets is routed by what it is (VLP-16 data or position packets; Ouster lidar or IMU
packets of a sensor whose metadata was given) and by its source, so that several
sensors in one file each get their own decoder. Streams that are none of these are
counted, not decoded.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Iterator

from .errors import UnknownSensorError, UnsupportedContainerError
from .frame import Frame
from .packet import PacketBatch

PCAP_MAGICS = {
    b"\xd4\xc3\xb2\xa1", b"\xa1\xb2\xc3\xd4",  # µs, little / big endian
    b"\x4d\x3c\xb2\xa1", b"\xa1\xb2\x3c\x4d",  # ns
    b"\x0a\x0d\x0d\x0a",  # pcapng section header block
}
MCAP_MAGIC = b"\x89MCAP0\r\n"
ROS1_MAGIC = b"#ROSBAG V2.0"
SQLITE_MAGIC = b"SQLite format 3\x00"


def container_kind(path: str | os.PathLike[str]) -> str:
    """``"pcap"``, ``"mcap"``, ``"rosbag2"`` (directory or .db3) or ``"rosbag1"``, from the file's first bytes.

    Raises :class:`UnsupportedContainerError` naming the file and what it starts with.
    """
    p = Path(path)
    if p.is_dir():
        if (p / "metadata.yaml").exists():
            return "rosbag2"
        raise UnsupportedContainerError(f"{p} is a directory without a rosbag2 metadata.yaml")
    try:
        with p.open("rb") as fh:
            head = fh.read(16)
    except FileNotFoundError:
        raise UnsupportedContainerError(f"{p}: no such file") from None
    except OSError as exc:
        raise UnsupportedContainerError(f"{p}: cannot read ({exc.strerror})") from None
    if head[:4] in PCAP_MAGICS:
        return "pcap"
    if head.startswith(MCAP_MAGIC):
        return "mcap"
    if head.startswith(ROS1_MAGIC):
        return "rosbag1"
    if head.startswith(SQLITE_MAGIC):
        return "rosbag2"
    shown = head.hex(" ") if head else "nothing (empty file)"
    raise UnsupportedContainerError(
        f"{p} is not a capture lidarpkt reads (pcap, pcapng, MCAP, rosbag2, ROS 1 bag): it starts with {shown}"
    )


def read_batches(path: str | os.PathLike[str], **filters: Any) -> Iterator[PacketBatch]:
    """Packet batches of any supported container, in capture order (see :class:`lidarpkt.pcap.PcapReader`)."""
    return _open_packet_source(path, **filters).batches()


def _open_packet_source(path: str | os.PathLike[str], **filters: Any):
    kind = container_kind(path)
    if kind == "pcap":
        from .pcap import PcapReader

        return PcapReader(path, **filters)
    from .bags import BagReader

    return BagReader(path, **filters)


@dataclass
class SourceStats:
    """What :func:`open_frames` saw: packets routed to each kind of decoder and streams it could not use."""

    batches: int = 0
    packets: int = 0
    velodyne_data_packets: int = 0
    velodyne_position_packets: int = 0
    ouster_lidar_packets: int = 0
    ouster_imu_packets: int = 0
    unrouted_packets: int = 0
    unrouted_streams: dict[str, int] = field(default_factory=dict)  # "src → dst (size B)" → packets
    frames: int = 0


class FrameReader:
    """Iterator of :class:`Frame` over one capture; ``stats``, ``decoders`` and ``reader`` show what happened.

    Made by :func:`open_frames` (``lidarpkt.open``). Frames come out when their last packet has
    been read, so memory stays bounded whatever the length of the capture.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        metadata: str | os.PathLike[str] | dict | Iterable[str | os.PathLike[str] | dict] | None = None,
        calibration: Any = None,
        cut_angle_deg: float | None = None,
        cut_on_block: bool = False,
        source: str | None = None,
        include_partial: bool = True,
        verify_crc: bool = True,
        soft_id_check: bool = False,
        **filters: Any,
    ) -> None:
        self.path = Path(path)
        self.reader = _open_packet_source(path, **filters)
        self.stats = SourceStats()
        self.decoders: dict[tuple, Any] = {}
        self._velodyne_options = {"calibration": calibration, "cut_angle_deg": cut_angle_deg,
                                  "cut_on_block": cut_on_block}
        self._ouster_options = {"verify_crc": verify_crc, "soft_id_check": soft_id_check}
        self._source_filter = source
        self._include_partial = include_partial
        self._ouster_metadata = _load_ouster_metadata(metadata)
        self._iter = self._frames()

    def __iter__(self) -> "FrameReader":
        return self

    def __next__(self) -> Frame:
        return next(self._iter)

    # ------------------------------------------------------------------ routing
    def _frames(self) -> Iterator[Frame]:
        from . import ouster, velodyne

        embedded = getattr(self.reader, "ouster_metadata", None)
        for batch in self.reader.batches():
            if embedded and not self._ouster_metadata:
                # Metadata recorded inside the file (MCAP /ouster/metadata) serves when none was given.
                self._ouster_metadata = _load_ouster_metadata(embedded())
            self.stats.batches += 1
            self.stats.packets += len(batch)
            src = batch.src.address if batch.src is not None else None
            if self._source_filter is not None and src != self._source_filter:
                continue
            yield from self._emit(self._route(batch, src, ouster, velodyne))
        for decoder in list(self.decoders.values()):
            yield from self._emit(decoder.finish())
        if self.stats.packets and not self.decoders:
            raise UnknownSensorError(self._no_sensor_message())

    def _route(self, batch: PacketBatch, src: str | None, ouster, velodyne) -> list[Frame]:
        if self._ouster_metadata:
            match = ouster.classify(batch, self._ouster_metadata)
            if match is not None:
                kind, md = match
                decoder = self._decoder(("ouster", src, id(md)), lambda: ouster.OusterDecoder(
                    md, source=_source_name(batch), **self._ouster_options))
                if kind == "lidar":
                    self.stats.ouster_lidar_packets += len(batch)
                    return decoder.push(batch)
                self.stats.ouster_imu_packets += len(batch)
                decoder.push_imu(batch)
                return []
        kind = velodyne.classify(batch)
        if kind is not None:
            decoder = self._decoder(("velodyne", src), lambda: velodyne.VelodyneDecoder(
                source=_source_name(batch), **self._velodyne_options))
            if kind == "data":
                self.stats.velodyne_data_packets += len(batch)
                return decoder.push(batch)
            self.stats.velodyne_position_packets += len(batch)
            decoder.push_position(batch)
            return []
        key = f"{_source_name(batch)} → {batch.dst if batch.dst is not None else '?'} ({batch.payload_size} B)"
        self.stats.unrouted_packets += len(batch)
        self.stats.unrouted_streams[key] = self.stats.unrouted_streams.get(key, 0) + len(batch)
        return []

    def _decoder(self, key: tuple, make):
        decoder = self.decoders.get(key)
        if decoder is None:
            decoder = self.decoders[key] = make()
        return decoder

    def _emit(self, frames: list[Frame]) -> Iterator[Frame]:
        for frame in frames:
            if frame.partial and not self._include_partial:
                continue
            self.stats.frames += 1
            yield frame

    def _no_sensor_message(self) -> str:
        streams = "; ".join(f"{k}: {n} packets" for k, n in list(self.stats.unrouted_streams.items())[:8])
        hint = "" if self._ouster_metadata else " For an Ouster sensor pass its metadata JSON (metadata=... / --metadata)."
        return f"{self.path}: no VLP-16 or Ouster stream found among {streams}.{hint}"


def open_frames(
    path: str | os.PathLike[str],
    *,
    metadata: str | os.PathLike[str] | dict | Iterable[str | os.PathLike[str] | dict] | None = None,
    **options: Any,
) -> FrameReader:
    """Frames from a capture; this is ``lidarpkt.open``.

    Args:
        path: pcap/pcapng file, MCAP file, rosbag2 directory or ``.db3``, or ROS 1 ``.bag``.
        metadata: Ouster metadata JSON (path or parsed dict), or a list of them for several sensors.
            MCAP files we record carry it and need none.
        calibration: VLP-16 calibration (path to a ROS YAML / VeloView XML, or a loaded one);
            the stock VLP-16 calibration by default.
        cut_angle_deg: VLP-16: cut frames at this azimuth instead of at the wrap through 0°.
        cut_on_block: VLP-16: cut at the block that wraps (VeloView's frames) rather than at the
            firing sequence that wraps.
        source: decode only packets from this source IP address.
        include_partial: yield the partial frames at the ends of the capture (default True).
        verify_crc: Ouster: check the CRC-64 of packets whose firmware writes one (default True).
        soft_id_check: Ouster: accept packets whose init_id differs from the metadata's (a
            changed init_id still ends the frame).
        **filters: passed to the packet reader (``ports``, ``src_addresses``, ``payload_sizes``).

    Raises:
        UnsupportedContainerError: the file is no container lidarpkt reads.
        UnknownSensorError: the file holds packets, but none of a supported sensor (message lists the streams).
        MetadataError, SensorMismatchError, CaptureFormatError: see their docstrings.
    """
    return FrameReader(path, metadata=metadata, **options)


def _load_ouster_metadata(metadata) -> list:
    if metadata is None:
        return []
    from .ouster import load_metadata

    items = metadata if isinstance(metadata, (list, tuple)) else [metadata]
    return [m if hasattr(m, "sensor_info") else load_metadata(m) for m in items]


def _source_name(batch: PacketBatch) -> str:
    return str(batch.src) if batch.src is not None else "unknown source"
