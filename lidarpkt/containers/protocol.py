"""One way to open any capture as a stream of packets: the :class:`PacketSource` protocol and
:func:`open_packet_source`, used by ``lidarpkt.open``, ``lidarpkt info``, ``decode`` and ``replay``."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any, Callable, Iterator, Protocol, runtime_checkable

from lidarpkt.core.packet import Packet, PacketBatch
from .filters import BAG_OPTIONS, PCAP_OPTIONS, check_filters
from .magic import FRAME_CONTAINERS, container_kind

if TYPE_CHECKING:
    from .rosmsgs import BagMessages

__all__ = ["PacketSource", "open_packet_source", "PCAP_OPTIONS", "BAG_OPTIONS"]

@runtime_checkable
class PacketSource(Protocol):
    """What every packet reader offers (:class:`~lidarpkt.containers.pcap_reader.PcapReader`,
    :class:`~lidarpkt.containers.bags.BagReader`).

    ``batches()``: same-stream :class:`PacketBatch` es in capture order, ``index`` the ordinal of each
    packet in the pass; ``packets()``: the same datagrams one by one; ``stats``: what the last pass
    found (the reader's own counters); ``recorded_sensor_file()``: the text of a sensor file a driver
    recorded in the file (a bag's or MCAP's), ``None`` when there is none (always, for pcap).
    """

    path: Any
    stats: Any

    def batches(self) -> Iterator[PacketBatch]: ...

    def packets(self) -> Iterator[Packet]: ...

    def recorded_sensor_file(self) -> str | None: ...


def open_packet_source(path: str | os.PathLike[str], *,
                       messages: BagMessages | Callable[[], BagMessages] | None = None,
                       **options: Any) -> PacketSource:
    """The packet reader of a capture, chosen by its first bytes (never its name).

    Args:
        path: pcap/pcapng file, MCAP file, rosbag2 directory or ``.db3``, ROS 1 ``.bag``; or
            ``udp://[ADDRESS]:PORT[,PORT...]`` to receive live (:class:`~lidarpkt.containers.udp.UdpSource`,
            whose options are then ``multicast``, ``interface``, ``rcvbuf_bytes``, ``queue_bytes``).
        messages: what a bag or MCAP file is read for (:class:`~lidarpkt.containers.rosmsgs.BagMessages`:
            the vendor registry's, :func:`lidarpkt.vendors.registry.bag_messages`), or the function giving
            them (called for a bag or MCAP file only); by default only the packet type no vendor owns.
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
    if kind in FRAME_CONTAINERS:
        from ..errors import UnsupportedContainerError

        raise UnsupportedContainerError(f"{path} is an {kind.upper()} file: it holds decoded frames, not packets; read "
                                        "its frames with lidarpkt.open")
    check_filters(path, kind, options)
    options = {k: v for k, v in options.items() if v is not None}
    if kind == "pcap":
        from .pcap_reader import PcapReader

        return PcapReader(path, **options)
    from .bags import BagReader

    return BagReader(path, messages=messages() if callable(messages) else messages, **options)


def recorded_sensor_file(path: str | os.PathLike[str], messages: BagMessages, look_ahead: int = 64) -> str | None:
    """The text of the sensor file a driver recorded in an MCAP file or bag (on a topic of ``messages``),
    looked for among its first ``look_ahead`` batches; ``None`` for pcaps and files without one."""
    if container_kind(path) == "pcap":
        return None
    reader = open_packet_source(path, messages=messages)
    for k, _ in enumerate(reader.batches()):
        if reader.recorded_sensor_file() or k >= look_ahead:
            break
    return reader.recorded_sensor_file()
