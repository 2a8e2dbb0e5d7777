"""Back to pcap: the raw packets of any capture that holds them, written as a classic pcap
(``lidarpkt export --format pcap``), for VeloView, ouster-cli, velodyne_decoder, Wireshark.

Every packet the capture's packet reader yields (:func:`lidarpkt.containers.open_packet_source`:
pcap, pcapng, MCAP, ROS bags), lidar and IMU/position packets alike, goes out in capture order
with its capture time (nanoseconds) and its UDP payload byte for byte, framed by
:class:`lidarpkt.writers.pcap.PcapBatchWriter` (Ethernet, IPv4 fragmented at MTU 1500, valid
checksums). A pcap keeps its packets' addresses and ports. A ROS bag or an MCAP records neither,
so each stream gets its vendor's factory defaults (:func:`addressed`: the registry record's
:attr:`~lidarpkt.core.vendor.Vendor.endpoints`, from its sensor file's ports where one is given):
a VLP-16's data from 192.168.1.201:2368 to broadcast, an Ouster's lidar packets from 169.254.0.2 to
169.254.0.1 on the metadata's ``udp_port_lidar``...; a stream of no vendor from 192.168.1.201:2368 to
broadcast, the common lidar default. A message that carries packets of two stream kinds (a RoboSense
scan holds its DIFOP among the MSOP) is parted by kind (:func:`lidarpkt.vendors.registry.by_kind`),
each kind on its own port (MSOP 6699, DIFOP 7788), as the sensor's driver listens for them.

A bag's or an MCAP's file order need not be its capture order (a writer may store each topic's
messages apart, as ``decode`` does with a chunk's IMU packets): their packets go out in the order
of their capture times (stable: equal times keep the file's order), sorted within a window of
:data:`REORDER_WINDOW_NS` of capture time, which bounds the memory; a packet that comes later
than that in the file keeps its file place. A pcap's record order is its capture order.

A file of decoded frames (an OSF file) holds no packets: :func:`write_packets_pcap` refuses it
with one line saying so.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterable, Iterator

import numpy as np

from lidarpkt.errors import CaptureFormatError, OutputError, UnsupportedContainerError
from lidarpkt.core.packet import Endpoint, PacketBatch

if TYPE_CHECKING:
    from lidarpkt.core.vendor import Match

__all__ = ["PacketExport", "addressed", "time_ordered", "write_packets_pcap"]

# the common lidar default (the factory address and port of most sensors), to broadcast
DEFAULT_SOURCE = Endpoint("192.168.1.201", 2368)
DEFAULT_DESTINATION = Endpoint("255.255.255.255", 2368)
REORDER_WINDOW_NS = 2_000_000_000  # a bag's packets are put in time order within this much capture time


@dataclass
class PacketExport:
    """What :func:`write_packets_pcap` wrote: ``packets``; ``defaulted``: for a bag or MCAP, the
    endpoints given to each payload size (``{1206: "192.168.1.201:2368 → 255.255.255.255:2368"}``; those of
    each stream kind, joined by ``"; "``, where packets of one size are of two kinds)."""

    packets: int = 0
    defaulted: dict[int, str] = field(default_factory=dict)


def addressed(batch: PacketBatch, match: Match | None) -> list[PacketBatch]:
    """A batch that kept no addresses (of the stream ``match``, ``None``: of no vendor) from and to its
    factory endpoints: one batch per stream kind it holds, in the order of its first packet
    (:func:`lidarpkt.vendors.registry.factory_addressed`); the common lidar default for a stream of no vendor."""
    from lidarpkt.vendors import registry

    if match is None:
        return [PacketBatch(DEFAULT_SOURCE, DEFAULT_DESTINATION, batch.timestamp_ns, batch.payload, batch.index)]
    return registry.factory_addressed(batch, match)


def time_ordered(batches: Iterable[PacketBatch], window_ns: int = REORDER_WINDOW_NS) -> Iterator[PacketBatch]:
    """The packets of ``batches`` in capture-time order (stable), re-indexed in that order, as one batch
    per stream and release, in the order of their first packet (as
    :class:`~lidarpkt.writers.pcap.PcapBatchWriter` takes them). Packets are held until the latest
    time seen is ``window_ns`` past them (released two windows at a time), so memory holds at most
    about twice that much capture time."""
    pending: list[PacketBatch] = []
    oldest = latest = None
    next_index = 0
    for batch in batches:
        if len(batch) == 0:
            continue
        pending.append(batch)
        low, high = int(batch.timestamp_ns.min()), int(batch.timestamp_ns.max())
        oldest = low if oldest is None else min(oldest, low)
        latest = high if latest is None else max(latest, high)
        if oldest <= latest - 2 * window_ns:
            out, pending = _release(pending, latest - window_ns, next_index)
            next_index += sum(len(b) for b in out)
            oldest = min((int(b.timestamp_ns.min()) for b in pending), default=None)
            yield from out
    if pending:
        yield from _release(pending, None, next_index)[0]


def _release(pending: list[PacketBatch], until_ns: int | None,
             first: int) -> tuple[list[PacketBatch], list[PacketBatch]]:
    """(the held packets with a time <= ``until_ns`` (all: None) in time order, indexed from ``first``,
    one batch per stream; the rest, one batch per stream, still held)."""
    groups: dict[tuple, list[PacketBatch]] = {}
    for b in pending:
        groups.setdefault((b.src, b.dst, b.payload_size), []).append(b)
    merged = [PacketBatch(g[0].src, g[0].dst, np.concatenate([b.timestamp_ns for b in g]),
                          np.concatenate([b.payload for b in g]), np.concatenate([b.index for b in g]))
              if len(g) > 1 else g[0] for g in groups.values()]
    times = np.concatenate([b.timestamp_ns for b in merged])
    order_in = np.concatenate([b.index for b in merged])
    take = np.ones(times.size, bool) if until_ns is None else times <= until_ns
    sel = np.flatnonzero(take)
    sel = sel[np.lexsort((order_in[sel], times[sel]))]  # by time, then the file's order
    new_index = np.empty(times.size, np.int64)
    new_index[sel] = first + np.arange(sel.size)
    out, keep, at = [], [], 0
    for b in merged:
        mine = slice(at, at + len(b))
        at += len(b)
        taken = np.flatnonzero(take[mine])
        if taken.size:
            rows = taken[np.argsort(new_index[mine][taken], kind="stable")]
            out.append(PacketBatch(b.src, b.dst, b.timestamp_ns[rows], b.payload[rows], new_index[mine][rows]))
        rest = np.flatnonzero(~take[mine])
        if rest.size:
            keep.append(PacketBatch(b.src, b.dst, b.timestamp_ns[rest], b.payload[rest], b.index[rest]))
    out.sort(key=lambda b: int(b.index[0]))
    return out, keep


def write_packets_pcap(path: str | os.PathLike[str], out: str | os.PathLike[str], *,
                       metadata: Any = ()) -> PacketExport:
    """Write every UDP packet of the capture ``path`` to the pcap ``out``, in capture order.

    Args:
        path: pcap/pcapng, MCAP, rosbag2 (folder or .db3) or ROS 1 bag.
        out: the pcap to write (overwritten).
        metadata: the sensor files (as ``lidarpkt.open`` takes them) whose ports a bag's streams get; a file
            the capture records serves when none of its vendor's is given.

    Returns:
        a :class:`PacketExport`.

    Raises:
        UnsupportedContainerError: a file of decoded frames (OSF), or no capture lidarpkt reads.
        CaptureFormatError: a bag or MCAP without raw packet topics, or a damaged capture (what
            was read before the damage is in ``out``).
    """
    from lidarpkt.containers.magic import container_kind
    from lidarpkt.vendors import registry
    from lidarpkt.writers.pcap import PcapBatchWriter

    src_path = Path(path)
    frame_files = registry.frame_files(src_path) if src_path.is_file() else None
    if frame_files is not None:
        raise UnsupportedContainerError(
            f"{src_path} is an {frame_files.what}: it holds decoded frames, not the sensor's UDP packets, so there "
            "are no packets to write as a pcap; export --format pcap takes a pcap, pcapng, MCAP or ROS bag "
            "that holds the packets")
    kind = container_kind(src_path)
    source = registry.open_packets(src_path)
    given = registry.load_sensor_files(list(metadata) if isinstance(metadata, (list, tuple)) else metadata)
    result = PacketExport()
    matched: dict[int, Match | None] = {}  # a bag's stream by payload size (its first batch's)
    batches = source.batches() if kind == "pcap" else time_ordered(source.batches())
    writer = _writing(out, lambda: PcapBatchWriter(out))
    try:
        for batch in batches:
            parts = [batch]
            if batch.src is None or batch.dst is None:
                size = batch.payload_size
                if size not in matched:
                    files = list(given)
                    recorded = source.recorded_sensor_file()  # an MCAP's own, once read past
                    if recorded:
                        f = registry.load_sensor_files([recorded])[0]
                        if not any(g.vendor == f.vendor for g in files):
                            files.append(f)
                    matched[size] = registry.classify(batch, registry.setup(files))
                parts = addressed(batch, matched[size])
                for part in parts:
                    given_to = f"{part.src} → {part.dst}"
                    before = result.defaulted.get(size)
                    if before is None or given_to not in before.split("; "):
                        result.defaulted[size] = given_to if before is None else f"{before}; {given_to}"
            for part in parts:
                _writing(out, writer.write, part)
    finally:
        _writing(out, writer.close)  # what was read before an error is in ``out``
    result.packets = writer.packets_written
    if result.packets == 0 and kind != "pcap":
        from lidarpkt.vendors import registry

        packages = sorted({t.split("/")[0] for t in registry.bag_messages().packets})
        raise CaptureFormatError(f"{src_path}: holds no topic of raw sensor packets ({', '.join(packages)}); there "
                                 "are no packets to write as a pcap")
    return result


def _writing(out: str | os.PathLike[str], action: Any, *args: Any) -> Any:
    """``action(*args)``, its OS error (a full disk) said as the output's, not taken for the input's."""
    from lidarpkt.writers.base import failure_text

    try:
        return action(*args)
    except OSError as exc:
        raise OutputError(f"{out}: writing failed: {failure_text(exc)}") from None

