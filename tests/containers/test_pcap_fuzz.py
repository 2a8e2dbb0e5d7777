"""Property tests: damaged captures give packets, lidarpkt warnings or lidarpkt errors — nothing else."""

from __future__ import annotations

import itertools
import warnings

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lidarpkt.errors import LidarpktError, LidarpktWarning
from lidarpkt.core.packet import Endpoint, Packet
from lidarpkt.containers.pcap_reader import PcapReader
from lidarpkt.writers.framing import frames_for
from lidarpkt.writers.pcap import Interface, pcap_bytes, pcapng_bytes

_PACKETS = [
    Packet(1_600_000_000_000_000_000 + i * 1_327_000, Endpoint("192.168.1.201", 2368), Endpoint("255.255.255.255", 2368),
           bytes((i * 7 + j) & 0xFF for j in range(1206)))
    for i in range(4)
] + [
    Packet(1_600_000_000_010_000_000, Endpoint("10.0.0.5", 7502), Endpoint("10.0.0.1", 7502), bytes(range(256)) * 12),
    Packet(1_600_000_000_020_000_000, Endpoint("fd00::5", 7502), Endpoint("fd00::1", 7502), bytes(range(200)) * 16),
    Packet(1_600_000_000_030_000_000, Endpoint("10.0.0.5", 7503), Endpoint("10.0.0.1", 7503), bytes(48)),
]


def _records(link="ethernet", vlan=()):
    return [(p.timestamp_ns, f) for i, p in enumerate(_PACKETS) for f in frames_for(p, link=link, vlan=vlan, ident=i)]


BASES = {
    "pcap": pcap_bytes(_records()),
    "pcap-be-ns-vlan": pcap_bytes(_records(vlan=(3, 4)), nanosecond=True, big_endian=True),
    "pcap-sll2": pcap_bytes(_records("linux_sll2"), link="linux_sll2"),
    "pcapng": pcapng_bytes(
        [(i % 2, ts, f if i % 2 == 0 else f) for i, (ts, f) in enumerate(_records())],
        interfaces=[Interface("ethernet"), Interface("ethernet", tsresol=9)],
    ),
}


def _read_all(path):
    """Read every way; return the packet count. Only lidarpkt errors/warnings may escape."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            reader = PcapReader(path, batch_packets=3)
            n = sum(1 for _ in reader.packets())
            m = sum(len(b) for b in reader.batches())
            assert n == m
            assert n <= reader.stats.records
        except LidarpktError:
            n = -1
    for w in caught:
        assert issubclass(w.category, LidarpktWarning), w
    return n


@pytest.mark.parametrize("base", sorted(BASES))
def test_clean_bases_read_fully(tmp_path, base):
    path = tmp_path / "f"
    path.write_bytes(BASES[base])
    assert _read_all(path) == len(_PACKETS)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    base=st.sampled_from(sorted(BASES)),
    edits=st.lists(st.tuples(st.floats(0, 1, exclude_max=True), st.integers(0, 255)), max_size=12),
    cut=st.one_of(st.none(), st.floats(0, 1)),
)
def test_mutated_captures(tmp_path, base, edits, cut):
    data = bytearray(BASES[base])
    for where, value in edits:
        data[int(where * len(data))] = value
    if cut is not None:
        data = data[: int(cut * len(data))]
    path = tmp_path / "m"
    path.write_bytes(bytes(data))
    _read_all(path)


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    base=st.sampled_from(sorted(BASES)),
    where=st.floats(0, 1, exclude_max=True),
    junk=st.binary(min_size=1, max_size=64),
)
def test_inserted_junk(tmp_path, base, where, junk):
    data = BASES[base]
    i = int(where * len(data))
    path = tmp_path / "j"
    path.write_bytes(data[:i] + junk + data[i:])
    _read_all(path)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    header_fields=st.lists(st.integers(0, 2**32 - 1), min_size=4, max_size=4),
    base=st.sampled_from(["pcap", "pcap-be-ns-vlan"]),
    record=st.integers(0, 10),
)
def test_random_record_headers(tmp_path, header_fields, base, record):
    """Any values in one record header: the records before it are still read."""
    import struct

    data = bytearray(BASES[base])
    endian = ">" if base.startswith("pcap-be") else "<"
    off = 24
    for _ in range(record):
        off += 16 + struct.unpack_from(endian + "I", data, off + 8)[0]
    struct.pack_into(endian + "IIII", data, off, *header_fields)
    path = tmp_path / "h"
    path.write_bytes(bytes(data))
    # the packets all of whose records (fragments) precede the damaged record are read, with no error
    per_packet = [len(frames_for(p, ident=i)) for i, p in enumerate(_PACKETS)]
    whole_before = sum(1 for end in itertools.accumulate(per_packet) if end <= record)
    assert _read_all(path) >= whole_before


def _datagrams():
    """Six UDP datagrams from two senders, fragmented at MTU 1500 (9, 9, 3, 1, 9, 6 fragments);
    each sender reuses an IP ID for its first two datagrams."""
    sizes = [12608, 12608, 4000, 500, 12608, 8448]
    out = []
    for i, size in enumerate(sizes):
        src = "169.254.92.158" if i % 2 else "169.254.238.111"
        p = Packet(1_700_000_000_000_000_000 + i * 1_000_000, Endpoint(src, 50000 + i % 2), Endpoint("169.254.100.204", 7502),
                   bytes((i * 31 + j * 7) & 0xFF for j in range(size)))
        out.append((p, [(p.timestamp_ns + k, f) for k, f in enumerate(frames_for(p, ident=1000 + i // 4))]))
    return out


_ORIGINALS, _TRAINS = zip(*_datagrams())
_ORIGINALS, _TRAINS = list(_ORIGINALS), list(_TRAINS)


@pytest.mark.filterwarnings("ignore::lidarpkt.errors.SkippedPacketWarning")  # mixes are counted and skipped
@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_vector_reassembly_equals_record_by_record(tmp_path, data):
    """Whatever the order, loss and duplication of fragments, the array fast path for whole fragment
    trains gives exactly what the record-by-record reassembler gives (batch_packets=1 never lets a
    train complete inside a chunk, so everything goes through lidarpkt.containers.reassembly)."""
    from lidarpkt.writers.pcap import write_pcap_records

    records = []
    for train in _TRAINS:
        train = list(train)
        if data.draw(st.booleans(), label="perturb"):
            if len(train) > 1 and data.draw(st.booleans(), label="drop"):
                del train[data.draw(st.integers(0, len(train) - 1), label="dropped")]
            if data.draw(st.booleans(), label="dup"):
                train.insert(data.draw(st.integers(0, len(train)), label="at"), train[data.draw(st.integers(0, len(train) - 1))])
            train = data.draw(st.permutations(train), label="order") if data.draw(st.booleans(), label="shuffle") else train
        records.append(train)
    # interleave the trains a little: sometimes two at once
    flat = []
    for i in range(0, len(records), 2):
        pair = records[i : i + 2]
        if data.draw(st.booleans(), label="interleave") and len(pair) == 2:
            a, b = pair
            flat += [r for ab in zip(a, b) for r in ab] + a[len(b):] + b[len(a):]
        else:
            flat += [r for t in pair for r in t]
    path = tmp_path / "t.pcap"
    write_pcap_records(path, flat)
    chunk = data.draw(st.sampled_from([2, 5, 4096]), label="batch_packets")
    slow, fast = PcapReader(path, batch_packets=1), PcapReader(path, batch_packets=chunk)
    a, b = list(slow.packets()), list(fast.packets())
    assert a == b
    for field in ("fragments", "reassembled", "orphaned_fragments", "duplicate_fragments", "udp_packets", "malformed"):
        assert getattr(slow.stats, field) == getattr(fast.stats, field), field
    originals = {(p.src, p.payload) for p in _ORIGINALS}
    assert all((p.src, p.payload) in originals for p in b)  # never a mix of two datagrams
    # trains left whole (in order or not, no loss, no duplicate) are all delivered, unless the sender's
    # previous datagram with the same IP ID (i - 2 for i = 2, 3) is still pending, damaged
    whole = [sorted(t) == sorted(set(t)) and len(t) == len(o) for t, o in zip(records, _TRAINS)]
    expected = {o.payload for i, o in enumerate(_ORIGINALS) if whole[i] and (i not in (2, 3) or whole[i - 2])}
    assert {p.payload for p in b} >= expected


_V4 = st.tuples(st.integers(1, 223), st.integers(0, 255), st.integers(0, 255), st.integers(1, 254)).map(
    lambda t: ".".join(map(str, t)))
_V6 = st.sampled_from(["fe80::1", "fd00::5", "2001:db8::42", "ff02::1"])


@st.composite
def _packet_lists(draw):
    v6 = draw(st.booleans())
    addr = _V6 if v6 else _V4
    hosts = draw(st.lists(st.tuples(addr, st.integers(1, 65535)), min_size=1, max_size=3))
    n = draw(st.integers(0, 12))
    t0 = draw(st.integers(0, 2**31)) * 10**9
    out = []
    for i in range(n):
        src = draw(st.sampled_from(hosts))
        dst = draw(st.sampled_from(hosts))
        size = draw(st.sampled_from([0, 1, 7, 48, 512, 1206, 1473, 2961, 8448, 12608]))
        payload = bytes((i * 13 + j) & 0xFF for j in range(size))
        out.append(Packet(t0 + i * 1000 * draw(st.integers(0, 5_000)), Endpoint(*src), Endpoint(*dst), payload))
    return out


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    packets=_packet_lists(),
    container=st.sampled_from(["pcap", "pcap-ns", "pcap-be", "pcapng"]),
    link=st.sampled_from(["ethernet", "linux_sll", "linux_sll2", "raw", "null"]),
    vlan=st.sampled_from([(), (5,), (5, 6)]),
    mtu=st.sampled_from([None, 1500, 576]),
    batch_packets=st.sampled_from([1, 3, 4096]),
)
def test_write_read_round_trip(tmp_path, packets, container, link, vlan, mtu, batch_packets):
    """Any packets, written with any framing, read back exactly, in order (µs files: times are µs)."""
    from lidarpkt.writers.pcap import write_pcap, write_pcapng

    path = tmp_path / "r"
    vlan = vlan if link == "ethernet" else ()
    if container == "pcapng":
        write_pcapng(path, packets, interfaces=[Interface(link, tsresol=9)], vlan=vlan, mtu=mtu)
    else:
        write_pcap(path, packets, link=link, vlan=vlan, mtu=mtu, nanosecond=container == "pcap-ns",
                   big_endian=container == "pcap-be")
    exact_ns = container in ("pcap-ns", "pcapng")
    reader = PcapReader(path, batch_packets=batch_packets)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = list(reader.packets())
    def key(p):
        return (p.src, p.dst, p.timestamp_ns if exact_ns else p.timestamp_ns // 1000, p.payload)
    assert [key(p) for p in got] == [key(p) for p in packets]
    assert reader.stats.orphaned_fragments == 0 and reader.stats.malformed == 0
    # dpkt walks the same records
    import dpkt

    with open(path, "rb") as fh:
        ref = dpkt.pcapng.Reader(fh) if container == "pcapng" else dpkt.pcap.Reader(fh)
        assert sum(1 for _ in ref) == reader.stats.records
    # the batches say the same, grouped by stream, with ordinals 0..n-1
    batches = list(PcapReader(path, batch_packets=batch_packets).batches())
    assert sorted(int(i) for b in batches for i in b.index) == list(range(len(packets)))
