"""One way to open any capture as a stream of packets: the :class:`PacketSource` protocol and
:func:`open_packet_source`, used by ``lidarpkt.open``, ``lidarpkt info``, ``decode`` and ``replay``."""

from __future__ import annotations

import os
from typing import Any, Iterator, Protocol, runtime_checkable

from lidarpkt.core.packet import Packet, PacketBatch
from .filters import BAG_OPTIONS, PCAP_OPTIONS, check_filters
from .magic import container_kind

__all__ = ["PacketSource", "open_packet_source", "PCAP_OPTIONS", "BAG_OPTIONS"]

@runtime_checkable
class PacketSource(Protocol):
    """What every packet reader offers (:class:`~lidarpkt.containers.pcap_reader.PcapReader`,
    :class:`~lidarpkt.containers.bags.BagReader`).

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
        path: pcap/pcapng file, MCAP file, rosbag2 directory or ``.db3``, ROS 1 ``.bag``; or
            ``udp://[ADDRESS]:PORT[,PORT...]`` to receive live (:class:`~lidarpkt.containers.udp.UdpSource`,
            whose options are then ``multicast``, ``interface``, ``rcvbuf_bytes``, ``queue_bytes``).
        **options: filters and reader options: pcap/pcapng take ``ports`` (destination ports),
            ``src_addresses``, ``payload_sizes``, ``batch_packets``, the reassembly bounds and
            ``segment``; bags and MCAP take ``topics`` and ``payload_sizes``.

    Raises:
        UnsupportedContainerError: the file is no capture lidarpkt reads, or an OSF file (frames, not packets).
        UnsupportedFilterError: an option this container's reader does not know or cannot apply
            (bags record no ports or addresses); ``None`` values are accepted everywhere.
        CaptureFormatError: the file's header is unusable.
    """
    if str(path).startswith("udp://"):
        from .udp import UdpSource, parse_udp_url

        bind, ports = parse_udp_url(str(path))
        return UdpSource(ports, bind=bind, **options)
    kind = container_kind(path)
    if kind == "osf":
        from ..errors import UnsupportedContainerError

        raise UnsupportedContainerError(f"{path} is an OSF file: it holds decoded frames, not packets; read its frames "
                                        "with lidarpkt.open")
    check_filters(path, kind, options)
    options = {k: v for k, v in options.items() if v is not None}
    if kind == "pcap":
        from .pcap_reader import PcapReader

        return PcapReader(path, **options)
    from .bags import BagReader

    return BagReader(path, **options)


def embedded_ouster_metadata(path: str | os.PathLike[str], look_ahead: int = 64) -> str | None:
    """The Ouster metadata JSON text recorded in an MCAP file or bag (``/ouster/metadata``), looked for
    among its first ``look_ahead`` batches; ``None`` for pcaps and files without it."""
    if container_kind(path) == "pcap":
        return None
    reader = open_packet_source(path)
    for k, _ in enumerate(reader.batches()):
        if reader.ouster_metadata() or k >= look_ahead:
            break
    return reader.ouster_metadata()
