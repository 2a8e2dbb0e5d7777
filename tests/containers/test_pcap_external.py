"""The pcap reader on every real third-party capture in fixtures/external.

Expected numbers come from fixtures/external/SOURCES.md (written by whoever collected
the files, from the files themselves and the upstream tests), and from two readers we
did not write: dpkt (record by record, for unfragmented files) and ouster-sdk's libtins
based pcap reader (which reassembles fragments).
"""

from __future__ import annotations

import struct
import warnings
from collections import Counter

import numpy as np
import pytest

from lidarpkt.errors import CaptureFormatError
from lidarpkt.core.packet import Endpoint
from lidarpkt.containers.pcap_reader import PcapReader, is_capture, read_batches, read_packets
from conftest import external
from reference_tools import ouster_sdk_pcap_packets

LO = "127.0.0.1"

# file -> {(src, dst, payload size): packets}, from SOURCES.md's tables
EXPECTED_STREAMS = {
    "rust-lidar-utils/velodyne_vlp16.pcap": {
        (("192.168.1.200", 2368), ("255.255.255.255", 2368), 1206): 84,
        (("192.168.1.200", 8308), ("255.255.255.255", 8308), 512): 16,
    },
    "rust-lidar-utils/velodyne_example.pcap": {(None, 2368, 1206): 84},
    "rust-lidar-utils/velodyne_vlp32.pcap": {(None, 2368, 1206): 91, (None, 8308, 512): 9},
    "veloview/vlp-16-test-90deg-1-50-frames.pcap": {(None, 2368, 1206): 1902, (None, 8308, 512): 367},
    "ouster-sdk/OS-1-64_1024x10_fw20.pcap": {
        ((LO, 7502), (LO, 7502), 12608): 64,
        ((LO, 7503), (LO, 7503), 48): 11,
    },
    "ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.pcap": {((LO, 7502), (LO, 7502), 8448): 64, ((LO, 7503), (LO, 7503), 48): 10},
    "ouster-sdk/OS-0-32-U1_v2.2.0_1024x10-single-packet.pcap": {((LO, 7502), (LO, 7502), 8448): 1},
    "ouster-sdk/OS-1-32-G_v2.1.1_1024x10.pcap": {((LO, 7502), (LO, 7502), 6464): 64},
    "ouster-sdk/OS-2-32-U0_v2.0.0_1024x10.pcap": {((LO, 7502), (LO, 7502), 6464): 64},
    "ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.pcap": {
        ((LO, 7502), (LO, 7502), 24832): 64,
        ((LO, 7503), (LO, 7503), 48): 10,
    },
    "ouster-sdk/OS-0-128-U1_v2.3.0_1024x10.pcap": {((LO, 7502), (LO, 7502), 8448): 64, ((LO, 7503), (LO, 7503), 48): 10},
    "ouster-sdk/VLI-16-one-packet.pcap": {(("192.168.1.200", 2369), ("192.168.1.102", 2368), 1212): 1},
    "ouster-sdk/crc_test.pcap": {((LO, 7502), (LO, 7502), 8448): 34, ((LO, 7503), (LO, 7503), 48): 10},
    "ouster-sdk/duplicate_id.pcap": {(("10.5.6.101", None), ("10.5.6.1", 34636), 8448): 1},
    "ouster-sdk/empty_pcap.pcap": {},
    "ouster-sdk/same_ports_legacy.pcap": {
        (("169.254.92.158", None), (None, 7502), 24896): 1,
        (("169.254.238.111", None), (None, 7502), 12608): 1,
    },
    "ouster-sdk/same_ports_nonlegacy.pcap": {
        (("169.254.238.111", None), (None, 7502), 16640): 1,
        (("169.254.92.158", None), (None, 7502), 16640): 1,
        (("169.254.238.111", None), (None, 7502), 48): 1,
        (("169.254.92.158", None), (None, 7502), 48): 1,
    },
    "rust-lidar-utils/ouster_example.pcap": {(("192.168.0.200", 35117), ("255.255.255.255", 7502), 12608): 100},
}

# fragments per datagram (SOURCES.md oddity 5): size -> fragments at MTU 1500
FRAGMENTS_AT_1500 = {8448: 6, 12608: 9, 16640: 12, 24896: 17}


def _matches(spec, endpoint: Endpoint) -> bool:
    if spec is None:
        return True
    address, port = spec
    return (address is None or endpoint.address == address) and (port is None or endpoint.port == port)


def _count_streams(path) -> tuple[Counter, PcapReader]:
    reader = PcapReader(path)
    seen = Counter()
    for batch in reader.batches():
        seen[(batch.src, batch.dst, batch.payload_size)] += len(batch)
    return seen, reader


@pytest.mark.parametrize("relpath", sorted(EXPECTED_STREAMS))
def test_streams_match_sources_md(relpath):
    path = external(relpath)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a clean real capture gives no warning
        seen, reader = _count_streams(path)
    expected = EXPECTED_STREAMS[relpath]
    assert sum(seen.values()) == sum(expected.values())
    for (src_spec, dst_spec, size), count in expected.items():
        if isinstance(dst_spec, int):
            dst_spec = (None, dst_spec)
        got = sum(
            n for (src, dst, sz), n in seen.items() if sz == size and _matches(src_spec, src) and _matches(dst_spec, dst)
        )
        assert got == count, (relpath, src_spec, dst_spec, size)
    st = reader.stats
    assert not st.truncated and st.malformed == 0 and st.non_udp == 0
    assert st.link_types.keys() <= {"ethernet"}
    assert st.bytes_read == path.stat().st_size


def test_records_and_fragments_match_sources_md():
    for relpath, sizes in {
        "ouster-sdk/same_ports_legacy.pcap": [24896, 12608],
        "ouster-sdk/same_ports_nonlegacy.pcap": [16640, 16640],
    }.items():
        reader = PcapReader(external(relpath))
        packets = list(reader.packets())
        frags = sum(FRAGMENTS_AT_1500[s] for s in sizes)
        imu = len(packets) - len(sizes)
        assert reader.stats.records == frags + imu
        assert reader.stats.fragments == frags
        assert reader.stats.reassembled == len(sizes)
        assert reader.stats.orphaned_fragments == 0


def test_duplicate_id_orphan_is_not_merged():
    """SOURCES.md: 7 fragments = an orphan first fragment + one 6-fragment datagram with the same IP ID 21723,
    88.5 s later; the SDK expects exactly one packet, of frame 1778."""
    path = external("ouster-sdk/duplicate_id.pcap")
    reader = PcapReader(path)
    packets = list(reader.packets())
    assert len(packets) == 1
    (p,) = packets
    assert len(p.payload) == 8448
    assert struct.unpack_from("<H", p.payload, 2)[0] == 1778  # non-legacy packet header frame_id
    st = reader.stats
    assert (st.records, st.fragments, st.reassembled, st.orphaned_fragments) == (7, 7, 1, 1)
    # the packet carries the time of the later datagram, not of the orphan (t = 1697084000.02)
    assert p.timestamp_ns > 1697084000_020000000 + 88 * 10**9
    # the reassembled bytes are the later datagram's: cut them from the file independently
    raw = path.read_bytes()
    off, frags = 24, []
    while off < len(raw):
        ts_s, ts_us, cap, _ = struct.unpack_from("<IIII", raw, off)
        frame = raw[off + 16 : off + 16 + cap]
        ident, flags = struct.unpack_from(">HH", frame, 14 + 4)
        total = struct.unpack_from(">H", frame, 14 + 2)[0]
        frags.append((ts_s, ident, (flags & 0x1FFF) * 8, frame[34 : 14 + total]))
        off += 16 + cap
    assert {f[1] for f in frags} == {21723}
    later = sorted((f for f in frags if f[0] > frags[0][0] + 80), key=lambda f: f[2])
    assert len(later) == 6
    assert p.payload == b"".join(f[3] for f in later)[8:]


def test_position_packets_with_wrong_ip_total_length():
    """SOURCES.md oddity 1: early VLP-16 position packets say IPv4 total length 1234 for a 540-byte datagram."""
    for relpath, n_pos in (("rust-lidar-utils/velodyne_vlp16.pcap", 16), ("veloview/vlp-16-test-90deg-1-50-frames.pcap", 367)):
        path = external(relpath)
        raw = path.read_bytes()
        off, bad_len_frames = 24, []
        while off < len(raw):
            cap = struct.unpack_from("<I", raw, off + 8)[0]
            frame = raw[off + 16 : off + 16 + cap]
            if struct.unpack_from(">H", frame, 36)[0] == 8308:
                assert struct.unpack_from(">H", frame, 16)[0] == 1234  # the IPv4 total length lies
                assert struct.unpack_from(">H", frame, 38)[0] == 520  # the UDP length does not
                bad_len_frames.append(frame)
            off += 16 + cap
        assert len(bad_len_frames) == n_pos
        positions = [p for p in read_packets(path, ports=[8308])]
        assert len(positions) == n_pos
        assert [p.payload for p in positions] == [f[42:554] for f in bad_len_frames]


def test_wrong_ip_checksums_are_tolerated():
    """SOURCES.md oddity 6: every record of ouster_example.pcap has a wrong IPv4 header checksum."""
    path = external("rust-lidar-utils/ouster_example.pcap")
    raw = path.read_bytes()
    header = raw[24 + 16 + 14 : 24 + 16 + 34]
    words = struct.unpack(">10H", header)
    total = sum(words)
    total = (total & 0xFFFF) + (total >> 16)
    assert total != 0xFFFF  # the checksum really is wrong
    assert len(list(read_packets(path))) == 100


def test_empty_capture_gives_nothing_and_no_warning():
    path = external("ouster-sdk/empty_pcap.pcap")
    assert is_capture(path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert list(read_packets(path)) == []
        assert list(read_batches(path)) == []


def test_non_captures_are_rejected_with_their_first_bytes():
    for relpath in ("einride-vlp16-go/packet.bin", "veloview/vlp-16.test", "ouster-sdk/crc_test.json"):
        path = external(relpath)
        assert not is_capture(path)
        with pytest.raises(CaptureFormatError) as err:
            PcapReader(path)
        assert str(path) in str(err.value)
        assert path.read_bytes()[:4].hex(" ") in str(err.value)


@pytest.mark.parametrize("batch_packets", [1, 7, 100, 4096])
def test_batches_preserve_capture_order(batch_packets):
    path = external("veloview/vlp-16-test-90deg-1-50-frames.pcap")
    batches = list(PcapReader(path, batch_packets=batch_packets).batches())
    index = np.concatenate([b.index for b in batches])
    assert sorted(index.tolist()) == list(range(2269))
    assert all(len(b) <= batch_packets for b in batches)
    firsts = [int(b.index[0]) for b in batches]
    assert firsts == sorted(firsts)
    last_of_stream: dict = {}
    for b in batches:
        key = (b.src, b.dst, b.payload_size)
        assert (np.diff(b.index) > 0).all()
        assert int(b.index[0]) > last_of_stream.get(key, -1)
        last_of_stream[key] = int(b.index[-1])
    # batches merged by index give exactly packets()
    packets = list(read_packets(path))
    rows = {}
    for b in batches:
        for i, t, row in zip(b.index.tolist(), b.timestamp_ns.tolist(), b.payload):
            rows[i] = (t, b.src, b.dst, row.tobytes())
    assert [(p.timestamp_ns, p.src, p.dst, p.payload) for p in packets] == [rows[i] for i in range(len(packets))]


def test_filters():
    path = external("rust-lidar-utils/velodyne_vlp16.pcap")
    assert len(list(read_packets(path, ports=[8308]))) == 16
    assert len(list(read_packets(path, payload_sizes=[1206]))) == 84
    assert len(list(read_packets(path, src_addresses=["192.168.1.200"]))) == 100
    assert list(read_packets(path, src_addresses=["192.168.1.201"])) == []
    reader = PcapReader(path, ports={2368}, payload_sizes=[1206])
    batches = list(reader.batches())
    assert [len(b) for b in batches] == [84]
    assert batches[0].index.tolist() == list(range(84))  # ordinals count yielded packets only
    assert reader.stats.filtered == 16 and reader.stats.yielded == 84
    legacy = external("ouster-sdk/same_ports_legacy.pcap")
    (p,) = read_packets(legacy, src_addresses=["169.254.92.158"])
    assert len(p.payload) == 24896


def _dpkt_udp(path):
    """(ts_us, src, sport, dst, dport, payload) of each unfragmented UDP/IPv4 record, via dpkt."""
    dpkt = pytest.importorskip("dpkt")
    import socket

    out = []
    with open(path, "rb") as fh:
        for ts, frame in dpkt.pcap.Reader(fh):
            eth = dpkt.ethernet.Ethernet(frame)
            ip = eth.data
            udp = ip.data
            if not isinstance(udp, dpkt.udp.UDP):
                continue
            out.append(
                (
                    round(ts * 1e6),
                    socket.inet_ntoa(ip.src),
                    udp.sport,
                    socket.inet_ntoa(ip.dst),
                    udp.dport,
                    bytes(udp)[8 : udp.ulen],
                )
            )
    return out


UNFRAGMENTED = [k for k in EXPECTED_STREAMS if "same_ports" not in k and "duplicate_id" not in k]


@pytest.mark.parametrize("relpath", UNFRAGMENTED)
def test_matches_dpkt_record_by_record(relpath):
    path = external(relpath)
    ours = [
        (round(p.timestamp_ns / 1000), p.src.address, p.src.port, p.dst.address, p.dst.port, p.payload)
        for p in read_packets(path)
    ]
    assert ours == _dpkt_udp(path)


@pytest.mark.crosscheck
@pytest.mark.parametrize("relpath", sorted(k for k in EXPECTED_STREAMS))
def test_matches_ouster_sdk_reader(relpath):
    path = external(relpath)
    ref = ouster_sdk_pcap_packets(path)
    ours = list(read_packets(path))
    assert len(ours) == len(ref)
    for p, (src, dst, t, payload) in zip(ours, ref):
        assert (p.src, p.dst) == (src, dst)
        assert p.payload == payload
        assert abs(p.timestamp_ns - t * 1e9) < 2000  # the SDK gives float seconds (µs in the file)


@pytest.mark.parametrize("relpath", sorted(EXPECTED_STREAMS))
def test_timestamps_exact_from_record_headers(relpath):
    """Each packet's time is its record's ts_sec·10⁹ + ts_usec·10³ exactly (all files here are µs);
    a reassembled datagram takes the time of the fragment that completed it (the last in the file)."""
    path = external(relpath)
    raw = path.read_bytes()
    off, times_by_ip_id, plain = 24, {}, []
    while off < len(raw):
        sec, usec, cap, _ = struct.unpack_from("<IIII", raw, off)
        frame = raw[off + 16 : off + 16 + cap]
        t = sec * 10**9 + usec * 1000
        flags = struct.unpack_from(">H", frame, 20)[0]
        if flags & 0x3FFF:
            times_by_ip_id.setdefault((frame[26:34], frame[18:20]), []).append(t)
        else:
            plain.append(t)
        off += 16 + cap
    packets = list(read_packets(path))
    frag_times = sorted(ts[-1] for ts in times_by_ip_id.values())
    if relpath.endswith("duplicate_id.pcap"):
        frag_times = frag_times[-1:]  # one key: the orphan and the later datagram share it
    assert sorted(p.timestamp_ns for p in packets) == sorted(plain + frag_times)


@pytest.mark.parametrize("relpath", ["ouster-sdk/same_ports_legacy.pcap", "ouster-sdk/same_ports_nonlegacy.pcap"])
def test_reassembled_bytes_match_the_fragments_in_the_file(relpath):
    """Each reassembled datagram is its fragments' data put at their offsets (cut by hand from the file)."""
    path = external(relpath)
    raw = path.read_bytes()
    off, datagrams = 24, {}
    while off < len(raw):
        cap = struct.unpack_from("<I", raw, off + 8)[0]
        frame = raw[off + 16 : off + 16 + cap]
        total, ident, flags = struct.unpack_from(">HHH", frame, 16)
        if flags & 0x3FFF:
            datagrams.setdefault((frame[26:30], ident), {})[(flags & 0x1FFF) * 8] = frame[34 : 14 + total]
        off += 16 + cap
    expected = {}
    for (src, _), pieces in datagrams.items():
        data = b"".join(pieces[k] for k in sorted(pieces))
        assert sorted(pieces) == [sum(len(pieces[j]) for j in sorted(pieces) if j < k) for k in sorted(pieces)]
        expected[(".".join(map(str, src)), struct.unpack_from(">H", data, 0)[0])] = data[8:]
    got = {(p.src.address, p.src.port): p.payload for p in read_packets(path) if len(p.payload) > 48}
    assert got == expected
