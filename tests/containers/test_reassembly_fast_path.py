"""The vectorised IPv4 fragment path of PcapReader is the one taken for clean fragment trains.

Its output equals the general reassembler's, so a broken fast path (a fragment offset read in
bytes instead of 8-byte units, say) falls back record by record with identical packets: only
the count of datagrams it rebuilt shows it: ``ReadStats.reassembled_vectorised``.
"""

from __future__ import annotations

import pytest

from lidarpkt.containers.pcap_reader import PcapReader
from lidarpkt.writers.pcap import write_pcap


@pytest.mark.parametrize("pcap,fragments", [
    ("ouster-sdk/same_ports_legacy.pcap", 26),  # two LEGACY lidar packets, fragmented at MTU 1500
    ("ouster-sdk/same_ports_nonlegacy.pcap", 24),
])
def test_clean_fragment_trains_take_the_vectorised_path(ext, pcap, fragments):
    reader = PcapReader(ext(pcap))
    for _ in reader.batches():
        pass
    assert reader.stats.fragments == fragments and reader.stats.reassembled == 2
    assert reader.stats.reassembled_vectorised == 2  # both: none fell back to the general path


def test_a_reused_ip_id_goes_through_the_general_path(ext):
    """duplicate_id.pcap: a stale fragment shares the IP ID, so the train is not clean."""
    reader = PcapReader(ext("ouster-sdk/duplicate_id.pcap"))
    assert sum(len(b) for b in reader.batches()) == 1
    assert reader.stats.reassembled == 1 and reader.stats.reassembled_vectorised == 0


def test_written_fragments_take_the_vectorised_path(ext, tmp_path):
    """Our own writer's fragments (MTU 1500 → 1480-byte pieces, offsets in 8-byte units)."""
    from lidarpkt.containers.pcap_reader import read_packets

    packets = [p for p in read_packets(ext("ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.pcap")) if len(p.payload) == 8448]
    path = tmp_path / "f.pcap"
    write_pcap(path, packets, mtu=1500)
    reader = PcapReader(path)
    got = [bytes(row) for b in reader.batches() for row in b.payload]
    assert got == [p.payload for p in packets]
    assert reader.stats.reassembled == len(packets) == reader.stats.reassembled_vectorised
