"""One way to open any capture as a stream of packets: the :class:`PacketSource` protocol and
:func:`open_packet_source`, used by ``lidarpkt.open``, ``lidarpkt info``, ``decode`` and ``replay``."""

from __future__ import annotations

import os
from typing import Any, Iterator, Protocol, runtime_checkable

from ..errors import UnsupportedFilterError
from ..packet import Packet, PacketBatch
from .magic import container_kind

__all__ = ["PacketSource", "open_packet_source", "PCAP_OPTIONS", "BAG_OPTIONS"]

# keyword options each reader takes (filters first); None always means "no filter"
PCAP_OPTIONS = frozenset({"ports", "src_addresses", "payload_sizes", "batch_packets", "reassembly_timeout_ns",
                          "max_pending_datagrams", "max_pending_bytes", "segment"})
BAG_OPTIONS = frozenset({"topics", "payload_sizes"})


@runtime_checkable
class PacketSource(Protocol):
    """What every packet reader offers (:class:`~lidarpkt.sources.pcap_reader.PcapReader`,
    :class:`~lidarpkt.sources.bags.BagReader`).

    ``batches()``: same-stream :class:`PacketBatch` es in capture order, ``index`` the ordinal of each
    packet in the pass; ``packets()``: the same datagrams one by one; ``stats``: what the last pass
    found (the reader's own counters); ``ouster_metadata()``: Ouster metadata JSON recorded in the
    file (MCAP ``/ouster/metadata``), ``None`` when there is none (always, for pcap).
    """

    path: Any
    stats: Any

    def batches(self) -> Iterator[PacketBatch]: ...

    def packets(self) -> Iterator[Packet]: ...

    def ouster_metadata(self) -> str | None: ...


def open_packet_source(path: str | os.PathLike[str], **options: Any) -> PacketSource:
    """The packet reader of a capture, chosen by its first bytes (never its name).

    Args:
        path: pcap/pcapng file, MCAP file, rosbag2 directory or ``.db3``, ROS 1 ``.bag``.
        **options: filters and reader options: pcap/pcapng take ``ports`` (destination ports),
            ``src_addresses``, ``payload_sizes``, ``batch_packets``, the reassembly bounds and
            ``segment``; bags and MCAP take ``topics`` and ``payload_sizes``.

    Raises:
        UnsupportedContainerError: the file is no capture lidarpkt reads.
        UnsupportedFilterError: an option this container's reader does not know or cannot apply
            (bags record no ports or addresses); ``None`` values are accepted everywhere.
        CaptureFormatError: the file's header is unusable.
    """
    kind = container_kind(path)
    given = {k for k, v in options.items() if v is not None}
    allowed = PCAP_OPTIONS if kind == "pcap" else BAG_OPTIONS
    unknown = sorted(given - allowed)
    if unknown:
        raise UnsupportedFilterError(_filter_message(path, kind, unknown, allowed))
    options = {k: v for k, v in options.items() if v is not None}
    if kind == "pcap":
        from .pcap_reader import PcapReader

        return PcapReader(path, **options)
    from .bags import BagReader

    return BagReader(path, **options)


def _filter_message(path, kind: str, unknown: list[str], allowed: frozenset[str]) -> str:
    names = ", ".join(f"{n}=" for n in unknown)
    if kind != "pcap" and set(unknown) <= {"ports", "src_addresses"}:
        return (f"{path}: {names} cannot filter a {kind} file: it records no UDP ports or addresses; "
                "choose packets by topics=... or payload_sizes=...")
    return f"{path}: unknown packet filter {names}; a {kind} reader takes {', '.join(sorted(allowed))}"
