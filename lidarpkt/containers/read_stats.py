"""What a pass of the pcap/pcapng reader found: the counts that its walk, datagram checks and batching
add to as they go, and that :class:`~lidarpkt.containers.pcap_reader.PcapReader` hands out as ``stats``."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

__all__ = ["ReadStats"]


@dataclass
class ReadStats:
    """What a :class:`PcapReader` found. Counts are of records unless the name says otherwise."""

    path: str = ""
    format: str = ""  # "pcap" or "pcapng"
    records: int = 0  # packet records read (pcap records, pcapng EPB/SPB/OPB)
    bytes_read: int = 0  # file bytes walked (headers included)
    udp_packets: int = 0  # UDP datagrams found (after reassembly, before filters)
    yielded: int = 0  # datagrams handed out (after filters)
    filtered: int = 0  # datagrams dropped by the port/address/size filters
    non_udp: int = 0  # records that are not UDP (ARP, TCP, ICMP, other ethertypes...)
    fragments: int = 0  # IP fragments seen
    reassembled: int = 0  # datagrams rebuilt from fragments
    reassembled_vectorised: int = 0  # of which rebuilt by the array fast path (whole in-order trains in one chunk)
    orphaned_fragments: int = 0  # fragments whose datagram never completed (timed out, evicted, end of file)
    duplicate_fragments: int = 0
    malformed: int = 0  # records skipped as damaged (see malformed_reasons)
    malformed_reasons: Counter = field(default_factory=Counter)
    truncated: bool = False  # reading stopped at damage before the end of the file
    truncated_reason: str = ""
    link_types: Counter = field(default_factory=Counter)  # link type name -> records
    interfaces: int = 0  # pcapng interfaces (1 for classic pcap)
    snaplen: int = 0
    nanosecond: bool = False  # classic pcap with ns time stamps
    big_endian: bool = False

    def as_dict(self) -> dict:
        """A JSON-ready copy."""
        out = {k: getattr(self, k) for k in self.__dataclass_fields__}
        out["malformed_reasons"] = dict(self.malformed_reasons)
        out["link_types"] = dict(self.link_types)
        return out
