"""Generated captures for the cases no real capture covers (SOURCES.md oddity 12).

Each file is written with lidarpkt.writers.pcap from real payloads, read back with
lidarpkt.containers.pcap_reader, and also read by readers we did not write: dpkt (container and
headers) and ouster-sdk's libpcap/libtins reader (container, link layers, VLAN,
IPv6 and fragment reassembly).
"""

from __future__ import annotations

import random
import socket
import struct
import warnings

import numpy as np
import pytest

from lidarpkt.errors import CaptureFormatError, SkippedPacketWarning, TruncatedCaptureWarning
from lidarpkt.core.packet import Endpoint, Packet
from lidarpkt.containers.pcap_reader import PcapReader, read_batches, read_packets
from lidarpkt.writers.framing import frames_for
from lidarpkt.writers.pcap import Interface, pcap_bytes, pcapng_bytes, write_pcap, write_pcap_records, write_pcapng
from conftest import external
from reference_tools import ouster_sdk_pcap_packets

LINKS = ["ethernet", "linux_sll", "linux_sll2", "raw", "null"]


@pytest.fixture(scope="module")
def real_packets() -> list[Packet]:
    """VLP-16 data + position and Ouster legacy lidar + IMU packets, real payloads, mixed in time order."""
    vlp = list(read_packets(external("rust-lidar-utils/velodyne_vlp16.pcap")))[:12]
    ost = list(read_packets(external("ouster-sdk/OS-1-64_1024x10_fw20.pcap")))[:5]
    # give the Ouster packets distinct addresses and times inside the VLP-16 span
    t0 = vlp[0].timestamp_ns
    ost = [
        Packet(t0 + 1000 * (137 * i + 1), Endpoint("10.5.5.87", 7502 if len(p.payload) > 48 else 7503), Endpoint("10.5.5.1", p.dst.port), p.payload)
        for i, p in enumerate(ost)
    ]
    return sorted(vlp + ost, key=lambda p: p.timestamp_ns)


def _v6(packets):
    return [
        Packet(p.timestamp_ns, Endpoint("fe80::2e0:4cff:fe68:1", p.src.port), Endpoint("ff02::1", p.dst.port), p.payload)
        for p in packets
    ]


def _sdk_read(path):
    """ouster-sdk's view of a capture, times rounded to µs (the resolution it reports)."""
    return [(src, dst, round(t * 1e6), payload) for src, dst, t, payload in ouster_sdk_pcap_packets(path)]


def _as_tuples(packets, us=False):
    return [(p.src, p.dst, round(p.timestamp_ns / 1000) if us else p.timestamp_ns, p.payload) for p in packets]


@pytest.mark.parametrize("link", LINKS)
@pytest.mark.parametrize("ipv6", [False, True])
@pytest.mark.parametrize("nanosecond,big_endian", [(False, False), (True, False), (False, True), (True, True)])
def test_pcap_round_trip(tmp_path, real_packets, link, ipv6, nanosecond, big_endian):
    packets = _v6(real_packets) if ipv6 else real_packets
    path = tmp_path / "t.pcap"
    write_pcap(path, packets, link=link, nanosecond=nanosecond, big_endian=big_endian)
    reader = PcapReader(path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = list(reader.packets())
    assert _as_tuples(got) == _as_tuples(packets)
    st = reader.stats
    assert st.nanosecond == nanosecond and st.big_endian == big_endian
    assert st.reassembled == 5 - 1 and st.orphaned_fragments == 0  # 4 Ouster lidar packets are fragmented
    assert st.fragments == 4 * 9  # 12608 B -> 9 fragments at MTU 1500 (SOURCES.md oddity 5)


@pytest.mark.parametrize("link", ["ethernet", "linux_sll", "raw", "null"])
@pytest.mark.parametrize("ipv6", [False, True])
def test_pcap_matches_dpkt(tmp_path, real_packets, link, ipv6):
    """dpkt reads the container and parses the link/IP/UDP headers of what the writer made (unfragmented)."""
    dpkt = pytest.importorskip("dpkt")
    packets = _v6(real_packets) if ipv6 else real_packets
    path = tmp_path / "t.pcap"
    write_pcap(path, packets, link=link, mtu=None, nanosecond=True, big_endian=True)
    ref = []
    with open(path, "rb") as fh:
        reader = dpkt.pcap.Reader(fh)
        assert reader.datalink() == {"ethernet": 1, "linux_sll": 113, "raw": 101, "null": 0}[link]
        for ts, frame in reader:
            if link == "ethernet":
                ip = dpkt.ethernet.Ethernet(frame).data
            elif link == "linux_sll":
                ip = dpkt.sll.SLL(frame).data
            elif link == "null":
                ip = (dpkt.ip6.IP6 if ipv6 else dpkt.ip.IP)(frame[4:])
            else:
                ip = (dpkt.ip6.IP6 if ipv6 else dpkt.ip.IP)(frame)
            udp = ip.data
            fam = socket.AF_INET6 if ipv6 else socket.AF_INET
            ref.append((Endpoint(socket.inet_ntop(fam, ip.src), udp.sport), Endpoint(socket.inet_ntop(fam, ip.dst), udp.dport),
                        round(float(ts) * 1e6), bytes(udp.data)))
    assert _as_tuples(read_packets(path), us=True) == ref


@pytest.mark.crosscheck
@pytest.mark.parametrize(
    "options",
    [
        {},
        {"link": "linux_sll"},
        pytest.param({"link": "linux_sll2"}, marks=pytest.mark.xfail(
            raises=RuntimeError, strict=True, reason="ouster-sdk's reader (libtins) knows no SLL2")),
        {"link": "raw"},
        {"link": "null"},
        {"vlan": (100,)},
        {"vlan": (10, 20)},
        {"nanosecond": True, "big_endian": True},
        {"ipv6": True},
        {"ipv6": True, "vlan": (7,)},
    ],
)
def test_pcap_matches_ouster_sdk_reader(tmp_path, real_packets, options):
    options = dict(options)
    packets = real_packets
    if options.pop("ipv6", False):
        packets = _v6(real_packets)
        options["mtu"] = None  # the SDK does not reassemble IPv6 fragments (checked against ours elsewhere)
    path = tmp_path / "t.pcap"
    write_pcap(path, packets, **options)
    ref = _sdk_read(path)
    assert _as_tuples(read_packets(path), us=True) == [(s, d, t, p) for s, d, t, p in ref]


def test_vlan_stacks_and_tpids(tmp_path, real_packets):
    for vlan in [(1,), (4094,), (1, 2), (1, 2, 3)]:
        path = tmp_path / "v.pcap"
        write_pcap(path, real_packets, vlan=vlan)
        raw = path.read_bytes()
        # the first record's frame carries the tags right after the MAC addresses
        tpids = [struct.unpack_from(">H", raw, 24 + 16 + 12 + 4 * i)[0] for i in range(len(vlan))]
        assert tpids == [0x88A8] * (len(vlan) - 1) + [0x8100]
        assert _as_tuples(read_packets(path)) == _as_tuples(real_packets)


@pytest.mark.parametrize("big_endian", [False, True])
def test_pcapng_interfaces_link_types_and_resolutions(tmp_path, real_packets, big_endian):
    interfaces = [
        Interface("ethernet"),  # µs by default
        Interface("linux_sll2", tsresol=9),
        Interface("raw", tsresol=3, tsoffset_s=1_000_000_000),  # ms, with an offset
        Interface("null", tsresol=0x80 | 30),  # 2^-30 s
    ]
    which = {id(p): i % 4 for i, p in enumerate(real_packets)}
    path = tmp_path / "t.pcapng"
    write_pcapng(path, real_packets, interfaces=interfaces, interface_of=lambda p: which[id(p)], big_endian=big_endian)
    reader = PcapReader(path)
    got = list(reader.packets())
    assert [(p.src, p.dst, p.payload) for p in got] == [(p.src, p.dst, p.payload) for p in real_packets]
    step = {0: 1000, 1: 1, 2: 1_000_000, 3: 1}  # resolution of each interface in ns
    for g, p in zip(got, real_packets):
        i = which[id(p)]
        assert 0 <= p.timestamp_ns - g.timestamp_ns < step[i] or (i == 3 and abs(p.timestamp_ns - g.timestamp_ns) <= 1)
    assert reader.stats.format == "pcapng" and reader.stats.interfaces == 4
    assert set(reader.stats.link_types) == {"ethernet", "linux_sll2", "raw", "null"}
    # dpkt reads the blocks we wrote (it does not do multi-link sections, so check the record count)
    dpkt = pytest.importorskip("dpkt")
    with open(path, "rb") as fh:
        assert sum(1 for _ in dpkt.pcapng.Reader(fh)) == reader.stats.records


def test_pcapng_matches_dpkt(tmp_path, real_packets):
    dpkt = pytest.importorskip("dpkt")
    path = tmp_path / "t.pcapng"
    write_pcapng(path, real_packets, interfaces=[Interface(tsresol=9)], mtu=None)
    ref = []
    with open(path, "rb") as fh:
        for ts, frame in dpkt.pcapng.Reader(fh):
            ip = dpkt.ethernet.Ethernet(frame).data
            ref.append((Endpoint(socket.inet_ntoa(ip.src), ip.data.sport), Endpoint(socket.inet_ntoa(ip.dst), ip.data.dport),
                        round(float(ts) * 1e6), bytes(ip.data.data)))
    assert _as_tuples(read_packets(path), us=True) == ref


def test_pcapng_several_sections_and_simple_blocks(tmp_path, real_packets):
    a, b = real_packets[:8], real_packets[8:]
    first = pcapng_bytes([(0, p.timestamp_ns, f) for p in a for f in frames_for(p)], big_endian=True)
    second = pcapng_bytes([(0, 0, f) for p in b for f in frames_for(p, link="raw")],
                          interfaces=[Interface("raw")], block="spb")
    path = tmp_path / "two.pcapng"
    path.write_bytes(first + second)
    got = list(read_packets(path))
    assert _as_tuples(got[:8]) == _as_tuples(a)
    assert [(p.src, p.dst, p.payload) for p in got[8:]] == [(p.src, p.dst, p.payload) for p in b]
    assert all(p.timestamp_ns == 0 for p in got[8:])  # simple packet blocks carry no time


def test_pcapng_bad_block_lengths(tmp_path, real_packets):
    good = pcapng_bytes([(0, p.timestamp_ns, f) for p in real_packets[:4] for f in frames_for(p)])
    shb_len = struct.unpack_from("<I", good, 4)[0]
    idb_len = struct.unpack_from("<I", good, shb_len + 4)[0]
    first_epb = shb_len + idb_len
    epb_len = struct.unpack_from("<I", good, first_epb + 4)[0]
    second_epb = first_epb + epb_len
    path = tmp_path / "bad.pcapng"
    for bad_len in (0, 13, 0xFFFFFFF0, 1 << 30):
        data = bytearray(good)
        struct.pack_into("<I", data, second_epb + 4, bad_len)
        path.write_bytes(bytes(data))
        reader = PcapReader(path)
        with pytest.warns(TruncatedCaptureWarning, match="offset"):
            got = list(reader.packets())
        assert _as_tuples(got) == _as_tuples(real_packets[:1])
        assert reader.stats.truncated
    # trailing length differs from the leading one
    data = bytearray(good)
    second_len = struct.unpack_from("<I", good, second_epb + 4)[0]
    struct.pack_into("<I", data, second_epb + second_len - 4, second_len + 4)
    path.write_bytes(bytes(data))
    with pytest.warns(TruncatedCaptureWarning, match="differ"):
        assert len(list(read_packets(path))) == 1
    # the section header itself is broken: not a capture we can read
    data = bytearray(good)
    struct.pack_into("<I", data, 4, 7)
    path.write_bytes(bytes(data))
    with pytest.raises(CaptureFormatError, match="impossible length"):
        list(read_packets(path))


def test_truncated_last_record_every_cut(tmp_path, real_packets):
    packets = [p for p in real_packets if len(p.payload) < 1400]  # unfragmented: one record per packet
    data = pcap_bytes([(p.timestamp_ns, f) for p in packets for f in frames_for(p)])
    last_start = len(data) - (16 + 42 + len(packets[-1].payload))
    path = tmp_path / "cut.pcap"
    for cut in list(range(last_start + 1, last_start + 20)) + [len(data) - 1]:
        path.write_bytes(data[:cut])
        reader = PcapReader(path)
        with pytest.warns(TruncatedCaptureWarning, match=f"after {len(packets) - 1} complete records"):
            got = list(reader.packets())
        assert _as_tuples(got) == _as_tuples(packets[:-1])
        assert reader.stats.truncated and reader.stats.records == len(packets) - 1
    path.write_bytes(data[:last_start])  # cut exactly at a record boundary: nothing lost, no warning
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert len(list(read_packets(path))) == len(packets) - 1


def test_absurd_record_length_stops_without_allocating(tmp_path, real_packets):
    import tracemalloc

    packets = [p for p in real_packets if len(p.payload) < 1400]
    data = bytearray(pcap_bytes([(p.timestamp_ns, f) for p in packets for f in frames_for(p)]))
    off = 24
    for _ in range(3):
        off += 16 + struct.unpack_from("<I", data, off + 8)[0]
    for claim in (0x7FFFFFFF, 0xFFFFFFFF, len(data)):
        struct.pack_into("<I", data, off + 8, claim)
        path = tmp_path / "absurd.pcap"
        path.write_bytes(bytes(data))
        tracemalloc.start()
        with pytest.warns(TruncatedCaptureWarning, match=f"offset {off}"):
            got = list(read_packets(path))
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert _as_tuples(got) == _as_tuples(packets[:3])
        assert peak < 16 << 20


def test_not_a_capture(tmp_path):
    for content, shown in ((b"GARBAGE!" * 10, "47 41 52 42"), (b"\x00" * 3, "00 00 00")):
        path = tmp_path / "x.pcap"
        path.write_bytes(content)
        with pytest.raises(CaptureFormatError, match=shown) as err:
            PcapReader(path)
        assert str(path) in str(err.value)
    path = tmp_path / "empty.pcap"
    path.write_bytes(b"")
    with pytest.raises(CaptureFormatError, match="empty"):
        PcapReader(path)
    with pytest.raises(CaptureFormatError, match="no such file"):
        PcapReader(tmp_path / "missing.pcap")
    with pytest.raises(CaptureFormatError, match="directory"):
        PcapReader(tmp_path)
    path.write_bytes(struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, 147))  # a user link type
    with pytest.raises(CaptureFormatError, match="link type 147"):
        PcapReader(path)


def test_snapped_and_non_udp_records_are_counted(tmp_path, real_packets):
    vlp = [p for p in real_packets if len(p.payload) == 1206][:3]
    frames = [f for p in vlp for f in frames_for(p)]
    tcp = bytearray(frames[0])
    tcp[14 + 9] = 6  # protocol TCP (checksum left stale: never verified)
    arp = frames[0][:12] + b"\x08\x06" + bytes(28)
    records = [(1, frames[0]), (2, bytes(tcp)), (3, arp), (4, frames[1]), (5, frames[2])]
    path = tmp_path / "mixed.pcap"
    write_pcap_records(path, records, snaplen=200)  # the UDP datagrams are cut by the snap length
    reader = PcapReader(path)
    with pytest.warns(SkippedPacketWarning, match="3 malformed"):
        assert list(reader.packets()) == []
    assert reader.stats.non_udp == 2 and reader.stats.malformed == 3
    write_pcap_records(path, records)
    reader = PcapReader(path)
    assert [p.payload for p in reader.packets()] == [p.payload for p in vlp]
    assert reader.stats.non_udp == 2 and reader.stats.malformed == 0


def _fragment_records(packets, ident0=100):
    return [[(p.timestamp_ns, f) for f in frames_for(p, ident=ident0 + i)] for i, p in enumerate(packets)]


def test_fragments_out_of_order_and_duplicated(tmp_path, real_packets):
    ouster = [p for p in real_packets if len(p.payload) == 12608]
    groups = _fragment_records(ouster)
    rng = random.Random(7)
    records = []
    for g in groups:
        g = g[:]
        rng.shuffle(g)
        records += g[:-1] + [g[0], g[3]] + g[-1:]  # two duplicates before the datagram completes
    path = tmp_path / "frags.pcap"
    write_pcap_records(path, records)
    reader = PcapReader(path)
    got = list(reader.packets())
    assert [p.payload for p in got] == [p.payload for p in ouster]
    st = reader.stats
    assert (st.reassembled, st.duplicate_fragments, st.orphaned_fragments) == (len(ouster), 2 * len(ouster), 0)
    # a duplicate arriving after its datagram completed starts a datagram that never completes
    write_pcap_records(path, groups[0] + [groups[0][1]])
    reader = PcapReader(path)
    assert [p.payload for p in reader.packets()] == [ouster[0].payload]
    assert reader.stats.orphaned_fragments == 1
    # interleave the fragments of all datagrams (different IP IDs): still reassembled, ordered by completion
    inter = [r for rs in zip(*groups) for r in rs]
    write_pcap_records(path, inter)
    assert sorted(p.payload for p in read_packets(path)) == sorted(p.payload for p in ouster)
    ref = _sdk_read(path) if pytest.importorskip("ouster.sdk") else None
    assert sorted(r[3] for r in ref) == sorted(p.payload for p in ouster)


def test_lost_fragment_and_reused_ip_id(tmp_path, real_packets):
    """Like duplicate_id.pcap: a datagram loses a fragment; a later one reuses the IP ID."""
    a, b = [p for p in real_packets if len(p.payload) == 12608][:2]
    fa = [(a.timestamp_ns, f) for f in frames_for(a, ident=4242)]
    late = Packet(a.timestamp_ns + 60 * 10**9, b.src, b.dst, b.payload)
    fb = [(late.timestamp_ns, f) for f in frames_for(late, ident=4242)]
    path = tmp_path / "reuse.pcap"
    write_pcap_records(path, fa[:4] + fa[5:] + fb)  # fragment 4 of the first datagram was lost
    reader = PcapReader(path)
    (got,) = list(reader.packets())
    assert got.payload == b.payload and got.timestamp_ns == late.timestamp_ns
    assert reader.stats.orphaned_fragments == len(fa) - 1
    # the same with a reuse 1 s later (inside the timeout): the stale pieces must not leak into it either.
    late2 = Packet(a.timestamp_ns + 10**9, b.src, b.dst, b.payload)
    fb2 = [(late2.timestamp_ns, f) for f in frames_for(late2, ident=4242)]
    write_pcap_records(path, fa[:4] + fa[5:] + fb2)
    reader = PcapReader(path)
    assert [p.payload for p in reader.packets()] == [b.payload]
    assert reader.stats.orphaned_fragments == len(fa) - 1
    # a short timeout drops the stale datagram
    reader = PcapReader(path, reassembly_timeout_ns=500_000_000)
    assert [p.payload for p in reader.packets()] == [b.payload]


def test_pending_reassembly_is_bounded(tmp_path, real_packets):
    ouster = [p for p in real_packets if len(p.payload) == 12608]
    records = []
    for i in range(300):  # 300 datagrams whose last fragment never comes
        p = ouster[i % len(ouster)]
        records += [(p.timestamp_ns + i, f) for f in frames_for(p, ident=i)[:-1]]
    records += [(ouster[0].timestamp_ns + 1000, f) for f in frames_for(ouster[0], ident=9999)]
    path = tmp_path / "lossy.pcap"
    write_pcap_records(path, records)
    reader = PcapReader(path, max_pending_datagrams=16, max_pending_bytes=200_000)
    assert [p.payload for p in reader.packets()] == [ouster[0].payload]
    assert reader.stats.orphaned_fragments == 300 * 8
    assert reader._reasm.stats.evicted_datagrams >= 300 - 16


def test_batches_mix_fast_and_reassembled_packets(tmp_path, real_packets):
    """One stream whose packets come unfragmented, as in-order fragment trains (array path) and as
    reordered fragments (record-by-record path) stays one ordered stream."""
    ouster = [p for p in real_packets if len(p.payload) == 12608]
    records = []
    for i, p in enumerate(ouster):
        frames = frames_for(p, ident=i, mtu=None if i % 2 else 1500)
        if i == 2:  # out of order: this one goes through the record-by-record reassembler
            frames = frames[::-1]
        records += [(p.timestamp_ns, f) for f in frames]
    path = tmp_path / "mix.pcap"
    write_pcap_records(path, records)
    (batch,) = list(read_batches(path))
    assert batch.index.tolist() == list(range(len(ouster)))
    assert [r.tobytes() for r in batch.payload] == [p.payload for p in ouster]
    assert batch.timestamp_ns.tolist() == [p.timestamp_ns for p in ouster]


def test_udp_length_bounds_payload_not_ip_length(tmp_path, real_packets):
    vlp = [p for p in real_packets if len(p.payload) == 1206][0]
    (frame,) = frames_for(vlp)
    for ip_total in (1234, 20 + 8, 9000):  # wrong IPv4 total lengths, both ways
        bad = bytearray(frame)
        struct.pack_into(">H", bad, 16, ip_total)
        path = tmp_path / "len.pcap"
        write_pcap_records(path, [(1, bytes(bad) + b"\0" * 6)])  # plus Ethernet padding bytes
        assert [p.payload for p in read_packets(path)] == [vlp.payload]
    bad = bytearray(frame)
    struct.pack_into(">H", bad, 14 + 20 + 4, 1300)  # the UDP length claims more than was captured
    write_pcap_records(path, [(1, bytes(bad))])
    reader = PcapReader(path)
    with pytest.warns(SkippedPacketWarning):
        assert list(reader.packets()) == []
    assert reader.stats.malformed == 1


def test_filters_on_the_general_path(tmp_path, real_packets):
    """Filters apply the same to reassembled/IPv6 packets (general path) as to plain IPv4 records."""
    packets = _v6(real_packets[:8]) + real_packets[8:]
    path = tmp_path / "f.pcap"
    write_pcap(path, packets, vlan=(9,))
    v6_src = "FE80:0:0:0:2E0:4CFF:FE68:1"  # another spelling of the writer's address
    got = list(read_packets(path, src_addresses=[v6_src]))
    assert [p.payload for p in got] == [p.payload for p in packets[:8]]
    got = list(read_packets(path, ports=[7502], payload_sizes=[12608]))
    assert [p.payload for p in got] == [p.payload for p in packets if p.dst.port == 7502 and len(p.payload) == 12608]
    reader = PcapReader(path, ports=[8308])
    assert all(p.dst.port == 8308 for p in reader.packets())
    assert reader.stats.yielded + reader.stats.filtered == reader.stats.udp_packets == len(packets)


def test_modified_pcap_with_24_byte_records(tmp_path, real_packets):
    """Kuznetzov's patched libpcap (magic a1b2cd34): each record header has 8 more bytes
    (ifindex u32, protocol u16, packet type u8, pad u8) after the usual 16."""
    packets = [p for p in real_packets if len(p.payload) < 1400]
    out = bytearray(struct.pack("<IHHiIII", 0xA1B2CD34, 2, 4, 0, 0, 65535, 1))
    for p in packets:
        (frame,) = frames_for(p)
        sec, ns = divmod(p.timestamp_ns, 10**9)
        out += struct.pack("<IIII", sec, ns // 1000, len(frame), len(frame)) + struct.pack("<IHBB", 2, 0x0800, 0, 0) + frame
    path = tmp_path / "kuz.pcap"
    path.write_bytes(bytes(out))
    assert _as_tuples(read_packets(path)) == _as_tuples(packets)


@pytest.mark.parametrize("linktype,link,big_endian", [(108, "null", True), (228, "raw", False), (229, "raw", False),
                                                      (12, "raw", False), (14, "raw", False)])
def test_other_link_type_numbers(tmp_path, real_packets, linktype, link, big_endian):
    """LINKTYPE_LOOP (108, family in network order), LINKTYPE_IPV4/IPV6 (228/229), BSD DLT_RAW (12/14)."""
    packets = _v6(real_packets) if linktype == 229 else real_packets
    records = [(p.timestamp_ns, f) for i, p in enumerate(packets) for f in frames_for(p, link=link, ident=i, big_endian=big_endian)]
    path = tmp_path / "l.pcap"
    write_pcap_records(path, records, link=linktype)
    assert _as_tuples(read_packets(path)) == _as_tuples(packets)


def _ipv4_with_options(src, dst, ident, payload_l4, *, more=False, offset=0):
    """An IPv4 header with 8 bytes of options (two NOPs, a 4-byte experimental option, end), IHL 7."""
    from lidarpkt.containers.layouts import internet_checksum

    options = b"\x01\x01" + b"\x9e\x04\x00\x00" + b"\x00\x00"
    flags = (0x2000 if more else 0) | (offset // 8)
    head = struct.pack(">BBHHHBBH4s4s", 0x47, 0, 28 + len(payload_l4), ident, flags, 64, 17, 0,
                       socket.inet_aton(src), socket.inet_aton(dst)) + options
    head = head[:10] + struct.pack(">H", internet_checksum(head)) + head[12:]
    return head + payload_l4


def test_ipv4_options_fast_and_fragment_paths(tmp_path, real_packets):
    from lidarpkt.writers.framing import link_frame, udp_datagram

    vlp = [p for p in real_packets if len(p.payload) == 1206][:3]
    ost = [p for p in real_packets if len(p.payload) == 12608][0]
    records = []
    for i, p in enumerate(vlp):
        l4 = udp_datagram(p.src.address, p.src.port, p.dst.address, p.dst.port, p.payload)
        records.append((p.timestamp_ns, link_frame(_ipv4_with_options(p.src.address, p.dst.address, i, l4))))
    l4 = udp_datagram(ost.src.address, ost.src.port, ost.dst.address, ost.dst.port, ost.payload)
    room = 1472  # 1500 - 28-byte header, a multiple of 8
    for off in range(0, len(l4), room):
        part = l4[off : off + room]
        ip = _ipv4_with_options(ost.src.address, ost.dst.address, 99, part, more=off + room < len(l4), offset=off)
        records.append((ost.timestamp_ns, link_frame(ip)))
    path = tmp_path / "opt.pcap"
    write_pcap_records(path, records)
    for batch_packets in (4096, 1):  # array paths, then record by record
        reader = PcapReader(path, batch_packets=batch_packets)
        got = list(reader.packets())
        assert _as_tuples(got) == _as_tuples(vlp + [ost])
        assert reader.stats.reassembled == 1
    # and dpkt agrees on the unfragmented ones
    dpkt = pytest.importorskip("dpkt")
    with open(path, "rb") as fh:
        ref = [bytes(dpkt.ethernet.Ethernet(f).data.data.data) for _, f in list(dpkt.pcap.Reader(fh))[:3]]
    assert ref == [p.payload for p in vlp]


def test_chunks_are_bounded_in_bytes(tmp_path, monkeypatch, real_packets):
    import lidarpkt.containers.pcap_reader as pcap_module

    vlp = [p for p in real_packets if len(p.payload) == 1206]
    path = tmp_path / "c.pcap"
    write_pcap(path, vlp * 20)
    monkeypatch.setattr(pcap_module, "MAX_CHUNK_BYTES", 10_000)
    batches = list(PcapReader(path).batches())
    assert max(len(b) for b in batches) <= 10_000 // 1248 + 1
    assert sum(len(b) for b in batches) == len(vlp) * 20
    np.testing.assert_array_equal(np.concatenate([b.index for b in batches]), np.arange(len(vlp) * 20))
    write_pcapng(tmp_path / "c.pcapng", vlp * 20)
    batches = list(PcapReader(tmp_path / "c.pcapng").batches())
    assert max(len(b) for b in batches) <= 10_000 // 1248 + 2
    assert sum(len(b) for b in batches) == len(vlp) * 20


@pytest.mark.parametrize("batch_packets", [4096, 1])
def test_mixed_fragments_of_two_datagrams_are_rejected(tmp_path, real_packets, batch_packets):
    """Two same-size datagrams with one IP ID, both damaged, can complete each other: the lengths agree,
    only the UDP checksum (present in every real Ouster capture here) tells. Both reassembly paths check it."""
    a, b = [p for p in real_packets if len(p.payload) == 12608][:2]
    fa = [(a.timestamp_ns, f) for f in frames_for(a, ident=7)]
    fb = [(a.timestamp_ns + 5_000_000, f) for f in frames_for(Packet(b.timestamp_ns, a.src, a.dst, b.payload), ident=7)]
    cases = {
        "hole filled by the next datagram": fa[:3] + fa[4:] + [fb[3]] + fb[:3] + fb[4:],
        "head of one, tail of the other, in order": fa[:2] + fb[2:],
    }
    path = tmp_path / "mix.pcap"
    for name, records in cases.items():
        write_pcap_records(path, records)
        reader = PcapReader(path, batch_packets=batch_packets)
        with pytest.warns(SkippedPacketWarning, match="checksum"):
            got = list(reader.packets())
        assert all(p.payload in (a.payload, b.payload) for p in got), name
        assert reader.stats.malformed_reasons and "checksum" in next(iter(reader.stats.malformed_reasons)), name


def test_pcapng_interface_with_unsupported_link_type(tmp_path, real_packets):
    vlp = [p for p in real_packets if len(p.payload) == 1206][:4]
    records = []
    for i, p in enumerate(vlp):
        (frame,) = frames_for(p)
        records += [(0, p.timestamp_ns, frame), (1, p.timestamp_ns + 1000, b"\x01\x02" + frame)]  # 147: a user DLT
    path = tmp_path / "u.pcapng"
    from lidarpkt.writers.pcap import write_pcapng_records

    write_pcapng_records(path, records, interfaces=[Interface("ethernet"), Interface(147)])
    reader = PcapReader(path)
    with pytest.warns(SkippedPacketWarning, match="link type 147") as caught:
        got = list(reader.packets())
    assert sum("link type 147" in str(w.message) for w in caught) == 1  # said once, not per record
    assert _as_tuples(got) == _as_tuples(vlp)
    assert reader.stats.non_udp == 4 and reader.stats.link_types["linktype 147"] == 4


def test_writer_rejects_unframeable_packets(tmp_path):
    from lidarpkt.errors import PacketFormatError

    good = Endpoint("10.0.0.1", 1)
    for bad in (
        Packet(0, None, good, b"x"),
        Packet(0, Endpoint("10.0.0.300", 1), good, b"x"),
        Packet(0, Endpoint("fe80::1", 1), good, b"x"),
        Packet(0, good, good, bytes(70000)),
    ):
        with pytest.raises(PacketFormatError):
            write_pcap(tmp_path / "w.pcap", [bad])
    with pytest.raises(ValueError, match="unknown link type"):
        write_pcap(tmp_path / "w.pcap", [Packet(0, good, good, b"x")], link="token-ring")


def test_pipes_are_refused_clearly(tmp_path):
    import os

    fifo = tmp_path / "capture.pcap"
    os.mkfifo(fifo)
    with pytest.raises(CaptureFormatError, match="not a regular file"):
        PcapReader(fifo)


def test_small_read_blocks_give_the_same_packets(tmp_path, monkeypatch, real_packets):
    """Records and pcapng blocks that straddle the read blocks (incl. a big-endian section header), and a
    first read (cut at FIRST_BLOCK_BYTES) that the first record or pcapng block does not fit, which the walk
    reads again in full from there: exactly what one whole-file read gives, nothing truncated."""
    import lidarpkt.containers.pcap_reader as pcap_module
    from lidarpkt.containers import pcap_walk

    mixed = real_packets + _v6(real_packets[:6])
    files = {"a.pcap": None, "b.pcapng": None}
    write_pcap(tmp_path / "a.pcap", mixed, vlan=(3,), nanosecond=True)
    first = pcapng_bytes([(0, p.timestamp_ns, f) for p in real_packets[:9] for f in frames_for(p)])
    second = pcapng_bytes([(0, p.timestamp_ns, f) for p in real_packets[9:] for f in frames_for(p, link="raw")],
                          interfaces=[Interface("raw", tsresol=9)], big_endian=True)
    (tmp_path / "b.pcapng").write_bytes(first + second)
    for name in files:
        files[name] = (list(read_packets(tmp_path / name)), PcapReader(tmp_path / name))
        list(files[name][1].packets())
    settings = [(pcap_module, "READ_BLOCK_BYTES", block) for block in (1600, 1601, 2048, 3001, 4999, 10_007)]
    settings += [(pcap_walk, "FIRST_BLOCK_BYTES", first_read) for first_read in (8, 24, 100, 1000, 1601, 5000)]
    for module, setting, value in settings:
        with monkeypatch.context() as patched:
            patched.setattr(module, setting, value)
            for name, (expected, ref_reader) in files.items():
                reader = PcapReader(tmp_path / name, batch_packets=5)
                with warnings.catch_warnings():
                    warnings.simplefilter("error")
                    got = list(reader.packets())
                assert _as_tuples(got) == _as_tuples(expected), (name, setting, value)
                st, ref = reader.stats, ref_reader.stats
                assert (st.records, st.reassembled, st.bytes_read, st.truncated) == (
                    ref.records, ref.reassembled, ref.bytes_read, False), (name, setting, value)


def test_file_shrinking_while_read(tmp_path, monkeypatch, real_packets):
    """A capture truncated by another process while it is read: no crash (no mmap SIGBUS), the records
    read so far, then a TruncatedCaptureWarning."""
    import lidarpkt.containers.pcap_reader as pcap_module

    vlp = [p for p in real_packets if len(p.payload) < 1400]
    path = tmp_path / "s.pcap"
    write_pcap(path, vlp * 10)
    size = path.stat().st_size
    monkeypatch.setattr(pcap_module, "READ_BLOCK_BYTES", 8000)
    reader = PcapReader(path, batch_packets=4)
    got = []
    with pytest.warns(TruncatedCaptureWarning):
        for i, p in enumerate(reader.packets()):
            got.append(p)
            if i == 3:
                with open(path, "r+b") as fh:
                    fh.truncate(size // 2 + 7)
    assert 4 <= len(got) < len(vlp) * 10
    assert _as_tuples(got) == _as_tuples((vlp * 10)[: len(got)])


def test_huge_snaplen_does_not_allow_huge_records(tmp_path, real_packets):
    """A header declaring snaplen 0xFFFFFFFF and a record claiming 100 MB inside a 200 MB file:
    the reader stops there with a warning instead of taking 100 MB as one record."""
    vlp = [p for p in real_packets if len(p.payload) == 1206][:3]
    data = bytearray(pcap_bytes([(p.timestamp_ns, f) for p in vlp for f in frames_for(p)], snaplen=65535))
    struct.pack_into("<I", data, 16, 0xFFFFFFFF)  # snaplen
    off = 24 + 16 + struct.unpack_from("<I", data, 24 + 8)[0]
    struct.pack_into("<I", data, off + 8, 100_000_000)
    path = tmp_path / "big.pcap"
    with open(path, "wb") as fh:
        fh.write(data)
        fh.truncate(200_000_000)  # sparse: the claimed bytes exist
    with pytest.warns(TruncatedCaptureWarning, match="corrupt"):
        got = list(read_packets(path))
    assert [p.payload for p in got] == [vlp[0].payload]
