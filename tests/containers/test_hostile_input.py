"""Hostile input for every parser: cut, mutated and junk-filled captures, damaged packets among good
ones, impossible field values, random text. Only ``lidarpkt.errors`` exceptions or counted skips and
``LidarpktWarning``s may come out, every good packet around a bad one is still decoded (compared
with the decode of the clean input), and memory stays bounded.

What other files already cover (not repeated here): tests/containers/test_pcap_fuzz.py (mutated, junk-filled
pcap/pcapng captures never raise anything else; vector vs record-by-record reassembly),
tests/containers/test_reassembly.py (reassembler properties), tests/ouster/test_ouster_frames.py (damaged real Ouster
packets never crash), tests/velodyne/test_velodyne_properties.py and tests/ouster/test_ouster_decode.py (byte round
trips of any bytes).
"""

from __future__ import annotations

import struct
import tracemalloc
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import lidarpkt
from conftest import external
from lidarpkt.errors import CaptureFormatError, LidarpktError, LidarpktWarning, NMEAError, TruncatedCaptureWarning
from lidarpkt.core.packet import Endpoint, Packet, PacketBatch
from lidarpkt.containers.pcap_reader import PcapReader
from lidarpkt.writers.framing import frames_for
from lidarpkt.writers.pcap import Interface, pcap_bytes, pcapng_bytes
from reference_tools import velodyne_scan_mcap

FIXTURE_SETTINGS = dict(deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def _only_lidarpkt_warnings(caught):
    for w in caught:
        assert issubclass(w.category, LidarpktWarning), f"{w.category.__name__}: {w.message}"


# =========================================================================== pcap / pcapng reader
_SMALL = [
    Packet(1_600_000_000_000_000_000 + i * 1_000_000, Endpoint("192.168.1.201", 2368 + i % 2),
           Endpoint("192.168.1.77", 2368 + i % 2), bytes((i * 13 + j) & 0xFF for j in range(10 + 7 * i)))
    for i in range(4)
] + [
    # one datagram in 4 fragments (MTU 300), then a last small IPv6 packet
    Packet(1_600_000_000_010_000_000, Endpoint("10.0.0.5", 7502), Endpoint("10.0.0.1", 7502), bytes(range(100)) * 9),
    Packet(1_600_000_000_020_000_000, Endpoint("fd00::5", 7503), Endpoint("fd00::1", 7503), b"ipv6" * 3),
]


def _small_records():
    return [(p.timestamp_ns, f) for i, p in enumerate(_SMALL) for f in frames_for(p, ident=100 + i, mtu=300)]


def _record_ends_pcap(data: bytes) -> list[int]:
    ends, off = [], 24
    while off < len(data):
        caplen = struct.unpack_from("<I", data, off + 8)[0]
        off += 16 + caplen
        ends.append(off)
    return ends


def _record_ends_pcapng(data: bytes) -> list[tuple[int, int]]:
    """(end offset, block type) of every block."""
    out, off = [], 0
    while off < len(data):
        btype, blen = struct.unpack_from("<II", data, off)
        off += blen
        out.append((off, btype))
    return out


def _read(path, **kw):
    """(packets, error or None, warnings) — anything but a lidarpkt error propagates."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got, err = [], None
        try:
            for p in PcapReader(path, **kw).packets():
                got.append(p)
        except LidarpktError as exc:
            err = exc
    _only_lidarpkt_warnings(caught)
    return got, err, [w for w in caught]


@pytest.mark.parametrize("fmt", ["pcap", "pcapng"])
def test_every_prefix_of_a_capture_gives_a_prefix_of_its_packets_then_a_warning(tmp_path, fmt):
    """The file cut at every byte offset: the packets read are exactly the clean packets whose last
    record lies wholly before the cut, in order; a cut inside a record gives a
    TruncatedCaptureWarning (inside the file header: a CaptureFormatError), a cut between records none."""
    records = _small_records()
    if fmt == "pcap":
        data = pcap_bytes(records)
        ends = _record_ends_pcap(data)
        header = 24
    else:
        data = pcapng_bytes([(0, t, f) for t, f in records], interfaces=[Interface("ethernet")])
        blocks = _record_ends_pcapng(data)
        ends = [e for e, t in blocks if t == 6]  # enhanced packet blocks
        header = blocks[1][0]  # SHB + IDB
    # the record (index into ends) that completes each clean packet
    completes, r = [], 0
    for p in _SMALL:
        r += len(frames_for(p, mtu=300))
        completes.append(ends[r - 1])
    path = tmp_path / "cut"
    clean_key = [(p.timestamp_ns, p.src, p.dst, p.payload) for p in _SMALL]
    boundaries = set(ends) | {header}
    for cut in range(len(data) + 1):
        path.write_bytes(data[:cut])
        try:
            got, err, caught = _read(path, batch_packets=3)
        except CaptureFormatError:
            assert cut < header, cut
            continue
        if cut < header:
            # a pcapng cut after its section header but inside the interface block may read as empty
            assert not got
            continue
        expected = [k for k, end in zip(clean_key, completes) if end <= cut]
        assert [(p.timestamp_ns, p.src, p.dst, p.payload) for p in got] == expected, cut
        truncated = any(issubclass(w.category, TruncatedCaptureWarning) for w in caught)
        assert truncated == (cut not in boundaries) or err is not None, cut


@settings(max_examples=60, **FIXTURE_SETTINGS)
@given(where=st.integers(0, 8), junk=st.binary(min_size=1, max_size=80))
def test_garbage_between_records_keeps_every_packet_before_it(tmp_path, where, junk):
    records = _small_records()
    data = pcap_bytes(records)
    ends = [24] + _record_ends_pcap(data)
    at = ends[min(where, len(ends) - 1)]
    path = tmp_path / "junk.pcap"
    path.write_bytes(data[:at] + junk + data[at:])
    clean, _, _ = _read(_write(tmp_path / "clean.pcap", data[:at]))
    got, err, caught = _read(path)
    assert [p.payload for p in got[: len(clean)]] == [p.payload for p in clean]
    assert len(got) >= len(clean)


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


@pytest.mark.parametrize("caplen", [0xFFFFFFFF, 0x7FFFFFFF, 1 << 18 | 1, 10_000_000])
def test_absurd_record_length_stops_with_a_warning_without_allocating_it(tmp_path, caplen):
    data = bytearray(pcap_bytes(_small_records()))
    ends = _record_ends_pcap(bytes(data))
    struct.pack_into("<II", data, ends[2] + 8, caplen, caplen)  # header of the 4th record
    path = _write(tmp_path / "absurd.pcap", bytes(data))
    tracemalloc.start()
    try:
        got, err, caught = _read(path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert err is None
    assert [p.payload for p in got] == [p.payload for p in _SMALL[:3]]
    assert any(issubclass(w.category, TruncatedCaptureWarning) for w in caught)
    assert peak < 8 * 1024 * 1024


@settings(max_examples=60, **FIXTURE_SETTINGS)
@given(block=st.integers(2, 12), length=st.one_of(st.sampled_from([0, 4, 8, 11, 12, 13, 28, 0xFFFFFFFC, 0x7FFFFFFF]),
                                                   st.integers(0, 2**32 - 1)), trailer=st.booleans())
def test_pcapng_block_with_a_bad_length_keeps_the_packets_before_it(tmp_path, block, length, trailer):
    records = _small_records()
    data = bytearray(pcapng_bytes([(0, t, f) for t, f in records], interfaces=[Interface("ethernet")]))
    blocks = _record_ends_pcapng(bytes(data))
    block = min(block, len(blocks) - 1)
    start = blocks[block - 1][0]
    end = blocks[block][0]
    struct.pack_into("<I", data, end - 4 if trailer else start + 4, length)  # leading or trailing length
    path = _write(tmp_path / "bad.pcapng", bytes(data))
    got, err, caught = _read(path)
    clean, _, _ = _read(_write(tmp_path / "clean.pcapng", bytes(data[:start])))
    assert [p.payload for p in got[: len(clean)]] == [p.payload for p in clean]
    assert err is not None or caught or got == list(PcapReader(_write(tmp_path / "all.pcapng", pcapng_bytes(
        [(0, t, f) for t, f in records], interfaces=[Interface("ethernet")]))).packets())


def test_fragments_that_never_complete_are_counted_and_the_rest_decoded(tmp_path):
    """A datagram missing its middle fragment, another missing its last one: both counted as
    orphaned fragments; every other packet comes out whole."""
    big = [Packet(1_600_000_000_000_000_000 + i, Endpoint("10.0.0.5", 7502), Endpoint("10.0.0.1", 7502),
                  bytes([i]) * 3000) for i in range(4)]
    records = []
    for i, p in enumerate(big):
        fr = frames_for(p, ident=i, mtu=1500)
        if i == 1:
            fr = fr[:1] + fr[2:]
        if i == 2:
            fr = fr[:-1]
        records += [(p.timestamp_ns, f) for f in fr]
    path = _write(tmp_path / "holes.pcap", pcap_bytes(records))
    reader = PcapReader(path)
    got = list(reader.packets())
    assert [p.payload for p in got] == [big[0].payload, big[3].payload]
    assert reader.stats.orphaned_fragments == 2 + 2
    assert reader.stats.reassembled == 2


def test_orphan_fragment_flood_keeps_the_pending_state_capped(tmp_path):
    """30 000 orphan first fragments (distinct IP IDs from 4 senders) with a good packet after every
    1000th: every good packet comes out, and the reader's pending reassembly state never exceeds its
    bounds while reading (benchmarks/bench_orphans.py measures millions, with peak RSS)."""
    from lidarpkt.writers.framing import ip_packets, link_frame, udp_datagram

    good = []
    records = []
    t0 = 1_600_000_000_000_000_000
    for k in range(30_000):
        src = f"10.0.{k % 4}.5"
        l4 = udp_datagram(src, 7502, "10.0.0.1", 7502, b"o" * 2000)
        first = ip_packets(src, "10.0.0.1", l4, ident=k // 4 % 65536, mtu=1500)[0]
        records.append((t0 + k * 1000, link_frame(first)))
        if k % 1000 == 999:
            p = Packet(t0 + k * 1000 + 1, Endpoint("192.168.1.201", 2368), Endpoint("192.168.1.77", 2368), k.to_bytes(4, "little") * 10)
            good.append(p)
            records += [(p.timestamp_ns, f) for f in frames_for(p, ident=7)]
    path = _write(tmp_path / "flood.pcap", pcap_bytes(records))
    reader = PcapReader(path, max_pending_datagrams=64, max_pending_bytes=256 * 1024, batch_packets=512)
    got = []
    worst_datagrams = worst_bytes = 0
    for p in reader.packets():
        got.append(p)
        worst_datagrams = max(worst_datagrams, reader._reasm.pending_datagrams)
        worst_bytes = max(worst_bytes, reader._reasm.held_bytes)
    assert [p.payload for p in got] == [p.payload for p in good]
    assert worst_datagrams <= 64 and worst_bytes <= 256 * 1024
    assert reader.stats.orphaned_fragments == 30_000
    assert reader.stats.reassembled == 0


# =========================================================================== VLP-16
def _vlp16_packets(name="vlp16-strongest"):
    from lidarpkt import fixtures

    return list(lidarpkt.containers.pcap_reader.read_packets(fixtures.canned(name)))


def _frame_columns(frames):
    """Everything a frame sequence says about the data, concatenated over columns."""
    if not frames:
        return {}
    keys = ("range_mm", "reflectivity")
    out = {k: np.concatenate([getattr(f, k) for f in frames], axis=-1) for k in keys}
    for k in ("column_timestamp_ns", "column_valid", "azimuth_deg"):
        out[k] = np.concatenate([np.asarray(getattr(f, k)) for f in frames])
    return out


def _open_all(path, **kw):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        frames = list(lidarpkt.open(path, **kw))
    _only_lidarpkt_warnings(caught)
    return frames


def _damage_vlp16(payload: bytes, how: int, rnd: int) -> bytes:
    b = bytearray(payload)
    if how == 0:  # a block flag
        block = rnd % 12
        struct.pack_into("<H", b, block * 100, 0xEEFF ^ (1 + rnd % 0xFFFE))
    elif how == 1:  # an impossible azimuth
        block = rnd % 12
        struct.pack_into("<H", b, block * 100 + 2, 36001 + rnd % (65536 - 36001))
    elif how == 2:  # unknown return mode
        b[1204] = [0x00, 0x36, 0x3A, 0xFF][rnd % 4]
    elif how == 3:  # cut short
        del b[1 + rnd % 1205 :]
    else:  # too long
        b += bytes(1 + rnd % 300)
    return bytes(b)


_VLP = {}


def _vlp_base():
    if not _VLP:
        pk = _vlp16_packets()
        data_idx = [i for i, p in enumerate(pk) if len(p.payload) == 1206]
        _VLP.update(packets=pk, data_idx=data_idx)
    return _VLP


@settings(max_examples=25, **FIXTURE_SETTINGS)
@given(damage=st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 4), st.integers(0, 2**31)), min_size=1, max_size=25))
def test_vlp16_bad_packets_among_good_ones_leave_the_good_ones_decoded(tmp_path, damage):
    """Damaged data packets (bad flag, azimuth > 36000, unknown mode, wrong size) in a real-layout
    capture: the frames are exactly those of the same capture with those packets lost."""
    from lidarpkt.writers.pcap import write_pcap

    base = _vlp_base()
    pk, data_idx = base["packets"], base["data_idx"]
    hit = {data_idx[d % len(data_idx)]: (how, rnd) for d, how, rnd in damage}
    damaged = [Packet(p.timestamp_ns, p.src, p.dst, _damage_vlp16(p.payload, *hit[i])) if i in hit else p for i, p in enumerate(pk)]
    lost = [p for i, p in enumerate(pk) if i not in hit]
    write_pcap(tmp_path / "damaged.pcap", damaged)
    write_pcap(tmp_path / "lost.pcap", lost)
    a = _frame_columns(_open_all(tmp_path / "damaged.pcap"))
    b = _frame_columns(_open_all(tmp_path / "lost.pcap"))
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    # and the good packets are all in there: as many valid columns as good firings
    assert int(a["column_valid"].sum()) == 24 * (len(data_idx) - len(hit))


@settings(max_examples=200, deadline=None)
@given(st.one_of(
    st.text(max_size=120),
    st.binary(max_size=120),
    st.builds(lambda s, i, c: s[:i] + c + s[i + 1:],
              st.sampled_from(["$GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*6A",
                               "$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47",
                               "$GPRMC,220516,A,5133.82,N,00042.24,W,173.8,231.8,130694,004.2,W*70"]),
              st.integers(0, 80), st.characters()),
))
def test_nmea_parser_takes_any_text(sentence):
    from lidarpkt.core.nmea import parse_nmea

    try:
        fix = parse_nmea(sentence)
    except NMEAError:
        return
    if fix.latitude_deg is not None:
        assert -90 <= fix.latitude_deg <= 90
    if fix.longitude_deg is not None:
        assert -180 <= fix.longitude_deg <= 180


@settings(max_examples=80, deadline=None)
@given(st.lists(st.binary(min_size=512, max_size=512), min_size=1, max_size=4), st.booleans())
def test_position_packets_of_any_bytes_are_counted_never_raised(blobs, host_time):
    from lidarpkt.vendors.velodyne import VelodyneDecoder

    dec = VelodyneDecoder()
    times = [1_600_000_000_000_000_000 + i for i in range(len(blobs))] if host_time else None
    dec.push_position(PacketBatch.from_payloads(blobs, times))
    assert dec.stats.position_packets == len(blobs)


# =========================================================================== Ouster
_OUSTER_CASES = {  # real streams; the two with a single real packet get synthetic frames of their layout
    "legacy-64": ("rust-lidar-utils/ouster_example.pcap", ["rust-lidar-utils/ouster_example.json"]),
    "rng19-dual-32": ("ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.pcap", ["ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.json"]),
    "rng19-single-128": ("ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.pcap", ["ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.json"]),
    "rng15-crc-128": ("ouster-sdk/crc_test.pcap", ["ouster-sdk/crc_test.json"]),
    "fusa-dual-128": (None, ["ouster-sdk/same_ports_nonlegacy.1.json"]),
    "rng19-dual-128-crc": (None, ["ouster-sdk/empty_pcap.json"]),
}
_OUSTER = {}


def _synthetic_stream(md, frames=2, seed=0):
    """``frames`` whole frames of valid columns with random pixels, in ``md``'s layout (CRC written)."""
    from lidarpkt.vendors.ouster import empty_fields, encode_packets

    per = md.columns_per_frame // md.columns_per_packet
    n = frames * per
    f = empty_fields(md, n)
    rng = np.random.default_rng(seed)
    mid = np.arange(n * md.columns_per_packet).reshape(n, md.columns_per_packet) % md.columns_per_frame
    f.measurement_id[:] = mid
    f.timestamp_ns[:] = 10**9 + np.arange(mid.size).reshape(mid.shape) * 48_828
    f.status[:] = 1
    f.header["frame_id"][:] = np.arange(n) // per + 7
    for bf in md.profile.pixel_fields:
        if bf.name in f.pixels:
            f.pixels[bf.name][:] = (rng.integers(0, 1 << min(bf.width, 12), f.pixels[bf.name].shape) << bf.upshift)
    return PacketBatch.from_payloads(encode_packets(f, md), 10**18 + np.arange(n) * 781_000,
                                     src=Endpoint("10.0.0.9", 7502), dst=Endpoint("10.0.0.1", 7502))


def _ouster_stream(which):
    if which not in _OUSTER:
        from lidarpkt.vendors.ouster import load_metadata
        from test_ouster_cases import lidar_streams

        pcap, jsons = _OUSTER_CASES[which]
        if pcap is None:
            md = load_metadata(external(jsons[0]))
            batch = _synthetic_stream(md)
        else:
            md, batch = lidar_streams(pcap, jsons)[0]
        n = min(len(batch), 160)
        _OUSTER[which] = (md, batch.select(slice(0, n)))
    return _OUSTER[which]


def _damage_ouster(md, row: np.ndarray, how: int) -> np.ndarray | None:
    """A copy of one packet the decoder must skip, or None when this profile has no such check.
    Fields are changed through decode/encode, so that the CRC (where the firmware writes one) stays
    right and the intended fault is the only one."""
    from lidarpkt.vendors.ouster import decode_packets, encode_packets

    if how == 1:
        if md.footer_kind != "crc":
            return None
        r = row.copy()
        r[100] ^= 0x10  # a bit flipped under the CRC
        return r
    f = decode_packets(row[None, :], md, verify_crc=False)
    if how == 0:  # a measurement id beyond the frame
        f.measurement_id[0, 3] = md.columns_per_frame + 3
    elif how == 2 and not md.profile.legacy and md.init_id:  # another sensor's init_id
        f.header["init_id"][0] = (int(md.init_id) + 1) % (1 << 24)
    else:
        return None
    return encode_packets(f, md)[0]


@settings(max_examples=12, **FIXTURE_SETTINGS)
@given(which=st.sampled_from(sorted(_OUSTER_CASES)),
       damage=st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 3)), min_size=1, max_size=12),
       step=st.sampled_from([1, 7, 64]))
def test_ouster_bad_packets_among_good_ones_leave_the_good_ones_decoded(which, damage, step):
    """Every profile: packets with an impossible measurement id, a failed CRC, a foreign init_id or a
    wrong size, among real packets: the frames are exactly those of the same stream with those packets
    lost, and every packet is counted."""
    from lidarpkt.vendors.ouster import OusterDecoder

    md, batch = _ouster_stream(which)
    n = len(batch)
    bad = {}
    for pos, how in damage:
        i = pos % n
        if how == 3:
            bad[i] = "size"
        else:
            row = _damage_ouster(md, batch.payload[i], how)
            if row is not None:
                bad[i] = row

    def run(rows):  # rows: list of (index, payload row)
        dec = OusterDecoder(md)
        frames = []
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            for s in range(0, len(rows), step):
                chunk = rows[s : s + step]
                # consecutive same-size runs, as a reader would batch them
                runs = []
                for idx, r in chunk:
                    if runs and len(runs[-1][-1][1]) == len(r):
                        runs[-1].append((idx, r))
                    else:
                        runs.append([(idx, r)])
                for run_ in runs:
                    pb = PacketBatch(batch.src, batch.dst, batch.timestamp_ns[[i for i, _ in run_]],
                                     np.stack([r for _, r in run_]), np.array([i for i, _ in run_], np.int64))
                    frames += dec.push(pb)
            frames += dec.finish()
        _only_lidarpkt_warnings(caught)
        return frames, dec

    rows = []
    for i in range(n):
        if i in bad:
            rows.append((i, batch.payload[i][:-4] if isinstance(bad[i], str) else bad[i]))
        else:
            rows.append((i, batch.payload[i]))
    got, dec = run(rows)
    want, _ = run([(i, batch.payload[i]) for i in range(n) if i not in bad])
    assert dec.stats.packets == n
    assert [f.frame_id for f in got] == [f.frame_id for f in want]
    for fa, fb in zip(got, want):
        np.testing.assert_array_equal(fa.range_mm, fb.range_mm)
        np.testing.assert_array_equal(fa.column_valid, fb.column_valid)
        np.testing.assert_array_equal(fa.column_timestamp_ns, fb.column_timestamp_ns)
    assert sum(int(f.column_valid.sum()) for f in got) == md.columns_per_packet * (n - len(bad))


@settings(max_examples=100, deadline=None)
@given(data=st.data())
def test_metadata_with_any_value_in_any_field_loads_or_names_the_field(data):
    """A real metadata file with random JSON values put at its keys: either it loads and a decoder
    takes a packet of its size, or a MetadataError comes out — never another exception."""
    import copy
    import json

    from lidarpkt.errors import MetadataError
    from lidarpkt.vendors.ouster import OusterDecoder, OusterGeometry, load_metadata

    name = data.draw(st.sampled_from(["ouster-sdk/empty_pcap.json", "ouster-sdk/OS-1-64_sensor_config_reduced.json",
                                      "ouster-sdk/crc_test.json"]))
    doc = json.loads(external(name).read_text())
    doc = copy.deepcopy(doc)
    values = st.recursive(
        st.none() | st.booleans() | st.integers(-(2**70), 2**70) | st.floats(allow_nan=True) | st.text(max_size=12),
        lambda inner: st.lists(inner, max_size=6) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
        max_leaves=12,
    )
    for _ in range(data.draw(st.integers(1, 4))):
        node = doc
        while isinstance(node, dict) and node:
            key = data.draw(st.sampled_from(sorted(node)))
            if not isinstance(node[key], dict) or data.draw(st.booleans()):
                if isinstance(node[key], list) and node[key] and data.draw(st.booleans()):
                    node[key][data.draw(st.integers(0, len(node[key]) - 1))] = data.draw(values)
                else:
                    node[key] = data.draw(values)
                break
            node = node[key]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.simplefilter("ignore", LidarpktWarning)
        try:
            md = load_metadata(doc)
        except MetadataError:
            return
        OusterGeometry(md)
        dec = OusterDecoder(md)
        dec.push(PacketBatch.from_payloads(np.zeros((1, md.packet_size), np.uint8)))
        assert dec.stats.packets == 1


# =========================================================================== bags (MCAP, ROS 1, rosbag2)
_BAG = {}


def _small_mcap() -> tuple[bytes, list[bytes], list[int]]:
    if not _BAG:
        base = _vlp_base()
        pk = [p for p in base["packets"] if len(p.payload) == 1206][:30]
        data = velodyne_scan_mcap([p.payload for p in pk], [p.timestamp_ns for p in pk], chunk_size=6_000)
        _BAG.update(data=data, payloads=[p.payload for p in pk], times=[p.timestamp_ns for p in pk])
    return _BAG["data"], _BAG["payloads"], _BAG["times"]


def _bag_packets(path):
    from lidarpkt.containers.bags import BagReader
    from lidarpkt.vendors.registry import bag_messages

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got, err = [], None
        try:
            for b in BagReader(path, messages=bag_messages()).batches():
                got += [(int(t), row.tobytes()) for t, row in zip(b.timestamp_ns, b.payload)]
        except LidarpktError as exc:
            err = exc
    _only_lidarpkt_warnings(caught)
    return got, err, caught


@settings(max_examples=60, **FIXTURE_SETTINGS)
@given(cut=st.floats(0, 1))
def test_mcap_cut_anywhere_gives_a_prefix_of_its_packets(tmp_path, cut):
    data, payloads, times = _small_mcap()
    path = _write(tmp_path / "cut.mcap", data[: int(cut * len(data))])
    got, err, caught = _bag_packets(path)
    assert got == list(zip(times, payloads))[: len(got)]
    if len(got) < len(payloads):
        assert err is not None or caught  # said so


@settings(max_examples=80, **FIXTURE_SETTINGS)
@given(edits=st.lists(st.tuples(st.floats(0, 1, exclude_max=True), st.integers(0, 255)), min_size=1, max_size=10),
       suffix=st.sampled_from([".mcap", ".bag", ".db3"]), junk=st.booleans())
def test_mutated_or_random_bags_raise_only_lidarpkt_errors(tmp_path, edits, suffix, junk):
    data, payloads, _ = _small_mcap()
    if junk:
        raw = bytearray(b"#ROSBAG V2.0\n" if suffix == ".bag" else b"SQLite format 3\x00" if suffix == ".db3" else b"\x89MCAP0\r\n")
        raw += bytes(int(w * 251) for w, _ in edits) * 20
    else:
        raw = bytearray(data)
        for where, value in edits:
            raw[int(where * len(raw))] = value
    path = _write(tmp_path / f"m{suffix}", bytes(raw))
    got, err, _ = _bag_packets(path)
    for _, payload in got:
        assert len(payload) == 1206
