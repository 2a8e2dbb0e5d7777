"""The compiled kernels (``lidarpkt._native``) against their pure-NumPy twins, and on their own.

Every comparison reads the same input twice, once with ``kernels.native`` the extension and once
with it ``None`` (the NumPy/Python path callers fall back to), and asserts identical output:
batches (endpoints, time stamps, payload bytes, ordinals), ``ReadStats`` and warning messages for
pcap reading; float64 bit patterns for Ouster XYZ. The kernels are also called directly on
hand-built buffers where the expected answer is known.
"""

from __future__ import annotations

import contextlib
import os
import random
import struct
import subprocess
import sys
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lidarpkt import fixtures
import lidarpkt
import lidarpkt.containers.pcap_reader as pcap_module
from lidarpkt.containers import gathers
from conftest import external, external_root
from lidarpkt.core import kernels
from lidarpkt.errors import CaptureFormatError, SkippedPacketWarning, TruncatedCaptureWarning
from lidarpkt.core.packet import Endpoint, Packet
from lidarpkt.containers.pcap_reader import PcapReader, capture_format
from lidarpkt.containers.pcap_walk import MAX_RECORD_BYTES
from lidarpkt.writers.framing import frames_for
from lidarpkt.writers.pcap import pcap_bytes
from test_ouster_cases import CAPTURES as OUSTER_CAPTURES

NATIVE = kernels.native  # as imported: the extension, or None when not built / LIDARPKT_NATIVE=0

needs_native = pytest.mark.skipif(
    NATIVE is None,
    reason="no compiled kernels to compare (" + kernels.describe() + "); test_extension_is_built says why",
)


@contextlib.contextmanager
def _impl(native):
    """Run the block with ``kernels.native`` set to ``native`` (the extension or None), then restore it."""
    saved = kernels.native
    kernels.native = native
    try:
        yield
    finally:
        kernels.native = saved


def _read(path, native, **reader_args):
    """Everything a pass of ``PcapReader(path).batches()`` gives: batches, stats and warnings, hashable."""
    with _impl(native), warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        reader = PcapReader(path, **reader_args)
        batches = [
            (
                b.src,
                b.dst,
                b.timestamp_ns.dtype.str,
                b.timestamp_ns.tolist(),
                b.payload.dtype.str,
                b.payload.shape,
                b.payload.tobytes(),
                b.index.tolist(),
            )
            for b in reader.batches()
        ]
        stats = reader.stats.as_dict()
    messages = [(w.category.__name__, str(w.message)) for w in caught]
    return batches, stats, messages


def _assert_same(path, **reader_args):
    """Native and NumPy give identical batches, stats and warnings; returns the native result."""
    got = _read(path, NATIVE, **reader_args)
    ref = _read(path, None, **reader_args)
    where = f"{path} {reader_args}"
    assert len(got[0]) == len(ref[0]), where
    for i, (a, b) in enumerate(zip(got[0], ref[0])):
        assert a == b, f"{where}: batch {i} differs"
    assert got[1] == ref[1], where
    assert got[2] == ref[2], where
    return got


# --- synthetic captures -------------------------------------------------------------------------------
VLP = (Endpoint("192.168.1.201", 2368), Endpoint("255.255.255.255", 2368))
VLP_POS = (Endpoint("192.168.1.201", 8308), Endpoint("255.255.255.255", 8308))
OUSTER = (Endpoint("10.5.5.87", 7502), Endpoint("10.5.5.1", 7502))
OUSTER_IMU = (Endpoint("10.5.5.87", 7503), Endpoint("10.5.5.1", 7503))
V6 = (Endpoint("fd00::5", 9000), Endpoint("fd00::1", 9000))


def _payload(rng: random.Random, size: int) -> bytes:
    return rng.getrandbits(8 * size).to_bytes(size, "little") if size else b""


def _mixed_records(seed: int = 1) -> list[tuple[int, bytes]]:
    """Records of many sizes in the patterns real captures have, and some they should not.

    Runs of VLP-16 data (1248-byte frames) with a 554-byte position frame every ~12 (VeloView's
    capture), a long pure run (speculative strided walk), alternating sizes (record-by-record
    walk), Ouster lidar packets fragmented at MTU 1500 with IMU packets between, IPv6, ARP
    (non-UDP), an empty record and a 1-byte record (malformed), and odd sizes.
    """
    rng = random.Random(seed)
    t = 1_600_000_000_123_456_000
    out: list[tuple[int, bytes]] = []
    ident = 0

    def add(ends, size, **kw):
        nonlocal t, ident
        t += rng.randrange(1, 2_000_000)
        ident += 1
        for f in frames_for(Packet(t, ends[0], ends[1], _payload(rng, size)), ident=ident, **kw):
            out.append((t, f))

    for i in range(40):  # VLP-16 data with position packets interleaved
        add(VLP, 1206, udp_checksum=False)
        if i % 12 == 5:
            add(VLP_POS, 512, udp_checksum=False)
    for _ in range(70):  # a long run of one size
        add(VLP, 1206, udp_checksum=False)
    for i in range(30):  # sizes alternating record by record
        add(VLP if i % 2 else VLP_POS, 1206 if i % 2 else 512)
    for _ in range(3):  # Ouster lidar (12608 B -> 9 fragments) and IMU
        add(OUSTER, 12608)
        add(OUSTER_IMU, 48)
    for size in (0, 1, 7, 100, 1471, 1472, 1473, 2999, 3000):
        add((Endpoint("10.0.0.9", 5000), Endpoint("10.0.0.1", 5001)), size)
    add(V6, 300)
    add(V6, 2000)  # IPv6 fragments
    arp = b"\xff" * 6 + bytes.fromhex("607688000000") + b"\x08\x06" + bytes(28)
    out += [(t + 1, arp), (t + 2, b""), (t + 3, b"\x45")]
    for _ in range(20):
        add(VLP, 1206, udp_checksum=False)
    return out


def _record_starts(data: bytes, header_bytes: int = 16, endian: str = "<") -> list[int]:
    """File offsets of the records of a well-formed classic pcap, and its length (the end)."""
    starts, off = [], 24
    while off + header_bytes <= len(data):
        starts.append(off)
        off += header_bytes + struct.unpack_from(endian + "I", data, off + 8)[0]
    assert off == len(data)
    return starts + [off]


def _modified_pcap(records, endian: str = "<") -> bytes:
    """Kuznetzov's 24-byte-record pcap (magic a1b2cd34) of ready-made Ethernet frames."""
    out = bytearray(struct.pack(endian + "IHHiIII", 0xA1B2CD34, 2, 4, 0, 0, 65535, 1))
    for ts, frame in records:
        sec, ns = divmod(ts, 10**9)
        out += struct.pack(endian + "IIII", sec, ns // 1000, len(frame), len(frame))
        out += struct.pack(endian + "IHBB", 2, 0x0800, 0, 0) + frame
    return bytes(out)


@pytest.fixture(scope="module")
def mixed():
    return _mixed_records()


# --- 1. the build ---------------------------------------------------------------------------------------
def test_extension_is_built():
    """CI installs with pip: this is what proves the optional extension compiled there."""
    if os.environ.get("LIDARPKT_NATIVE") == "0":
        pytest.skip("LIDARPKT_NATIVE=0: the compiled kernels are disabled on purpose")
    assert kernels.native is not None, (
        "the optional extension lidarpkt._native was not built (no C compiler at install time?) or does not "
        f"import; kernels.describe() says: {kernels.describe()}"
    )
    assert kernels.native.__name__ == "lidarpkt._native"
    for name in ("walk_pcap", "gather_rows", "xyz_lut"):
        assert callable(getattr(kernels.native, name)), name
    text = kernels.describe()
    assert text == "compiled kernels (lidarpkt._native)"


def test_describe_names_the_numpy_twin(monkeypatch):
    monkeypatch.setattr(kernels, "native", None)
    monkeypatch.delenv("LIDARPKT_NATIVE", raising=False)
    assert kernels.describe() == "pure NumPy (extension not built)"
    monkeypatch.setenv("LIDARPKT_NATIVE", "0")
    assert kernels.describe() == "pure NumPy (disabled by LIDARPKT_NATIVE=0)"


def _python(code: str, **env) -> str:
    res = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, env={**os.environ, **env}
    )
    assert res.returncode == 0, res.stderr
    return res.stdout.strip()


def test_version_says_which_implementation_runs():
    res = subprocess.run([sys.executable, "-m", "lidarpkt", "--version"], capture_output=True, text=True, timeout=60,
                         env={**os.environ, "LIDARPKT_NATIVE": "0"})
    assert res.returncode == 0 and res.stdout.strip().endswith(", pure NumPy (disabled by LIDARPKT_NATIVE=0)"), res
    if NATIVE is not None:
        res = subprocess.run([sys.executable, "-m", "lidarpkt", "--version"], capture_output=True, text=True,
                             timeout=60, env={k: v for k, v in os.environ.items() if k != "LIDARPKT_NATIVE"})
        assert res.returncode == 0 and res.stdout.strip().endswith(", compiled kernels (lidarpkt._native)"), res


def test_environment_switch_in_a_fresh_interpreter():
    code = "from lidarpkt.core import kernels; print(kernels.native); print(kernels.describe())"
    assert _python(code, LIDARPKT_NATIVE="0").splitlines() == ["None", "pure NumPy (disabled by LIDARPKT_NATIVE=0)"]
    if NATIVE is not None:  # and any other value leaves the extension on
        out = _python(code, LIDARPKT_NATIVE="1").splitlines()
        assert out[0].startswith("<module 'lidarpkt._native'") and out[1].startswith("compiled kernels (")


# --- 2. pcap reading: real and canned captures ------------------------------------------------------
def _external_captures() -> list[str]:
    root = external_root()
    if not root.is_dir():
        return []
    return sorted(str(p.relative_to(root)) for p in root.rglob("*") if p.is_file() and capture_format(p) == "pcap")


EXTERNAL_CAPTURES = _external_captures()
REQUIRED_EXTERNAL = [
    "veloview/vlp-16-test-90deg-1-50-frames.pcap",  # interleaved 1248-B data and 554-B position records
    "rust-lidar-utils/velodyne_vlp16.pcap",
    "rust-lidar-utils/ouster_example.pcap",
    "ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.pcap",
    "ouster-sdk/duplicate_id.pcap",
    "ouster-sdk/empty_pcap.pcap",
]


def test_external_captures_are_all_found():
    for rel in REQUIRED_EXTERNAL:
        external(rel)  # skips when the external fixtures are absent
        assert rel in EXTERNAL_CAPTURES
    assert len(EXTERNAL_CAPTURES) >= 18


@needs_native
@pytest.mark.parametrize("rel", EXTERNAL_CAPTURES or ["(none)"])
@pytest.mark.parametrize("batch_packets", [1, 7, 4096])
def test_external_capture_native_equals_numpy(rel, batch_packets):
    path = external(rel)
    batches, stats, _ = _assert_same(path, batch_packets=batch_packets)
    data = path.read_bytes()
    endian = "<" if data[:4] in (b"\xd4\xc3\xb2\xa1", b"\x4d\x3c\xb2\xa1") else ">"
    offs, _, _ = _reference_walk(data, 24, len(data), 16, endian, MAX_RECORD_BYTES, 1 << 40, 1 << 62)
    assert stats["records"] == len(offs)
    if batch_packets == 1:
        assert all(len(b[7]) == 1 for b in batches)
    if rel == "veloview/vlp-16-test-90deg-1-50-frames.pcap":
        sizes = {b[5][1] for b in batches}
        assert sizes == {1206, 512} and stats["yielded"] == 1902 + 367


@needs_native
@pytest.mark.parametrize("name", fixtures.CAPTURES)
@pytest.mark.parametrize("batch_packets", [3, 4096])
def test_canned_capture_native_equals_numpy(name, batch_packets):
    batches, stats, messages = _assert_same(fixtures.canned(name), batch_packets=batch_packets)
    assert batches and stats["yielded"] > 0 and not stats["truncated"] and messages == []


# --- 2b. generated captures: mixed sizes, both byte orders, chunk limits ------------------------------
@needs_native
@pytest.mark.parametrize("big_endian", [False, True])
@pytest.mark.parametrize("nanosecond", [False, True])
@pytest.mark.parametrize("batch_packets", [1, 3, 7, 4096])
def test_generated_mixed_capture(tmp_path, mixed, big_endian, nanosecond, batch_packets):
    path = tmp_path / "mixed.pcap"
    path.write_bytes(pcap_bytes(mixed, big_endian=big_endian, nanosecond=nanosecond))
    batches, stats, messages = _assert_same(path, batch_packets=batch_packets)
    assert stats["records"] == len(mixed) and stats["big_endian"] == big_endian and not stats["truncated"]
    # 3 Ouster lidar packets, the 1473/2999/3000-byte datagrams and the 2000-byte IPv6 one
    assert stats["reassembled"] == 3 + 3 + 1 and stats["malformed"] == 2 and stats["non_udp"] == 1
    assert [m[0] for m in messages] == ["SkippedPacketWarning"]
    assert max(len(b[7]) for b in batches) <= batch_packets


@needs_native
@pytest.mark.parametrize("endian", ["<", ">"])
def test_generated_modified_pcap_24_byte_headers(tmp_path, mixed, endian):
    path = tmp_path / "kuz.pcap"
    path.write_bytes(_modified_pcap(mixed, endian))
    for batch_packets in (1, 7, 4096):
        _, stats, _ = _assert_same(path, batch_packets=batch_packets)
        assert stats["records"] == len(mixed)


@needs_native
@pytest.mark.parametrize("block", [1600, 3001, 4999, 10_007])
def test_generated_capture_small_read_blocks(tmp_path, monkeypatch, mixed, block):
    """Records straddling read blocks: the native walk stops at the block end (reasons 1 and 3 with
    more file to come), the reader refills; both twins must agree, and with the whole-file read."""
    path = tmp_path / "mixed.pcap"
    path.write_bytes(pcap_bytes(mixed, big_endian=True))
    whole = _read(path, NATIVE, batch_packets=5)
    monkeypatch.setattr(pcap_module, "READ_BLOCK_BYTES", block)
    for batch_packets in (5, 4096):
        got = _assert_same(path, batch_packets=batch_packets)
        if batch_packets == 5:
            # block ends cut chunks (and so batches) elsewhere, but the packets are the same
            assert _packets_of(got) == _packets_of(whole)
            assert got[1]["records"] == whole[1]["records"] == len(mixed)


def _packets_of(result) -> list[tuple]:
    """(ordinal, src, dst, time stamp, payload) of every packet of a ``_read`` result, by ordinal."""
    out = []
    for src, dst, _, ts, _, shape, payload, index in result[0]:
        size = shape[1]
        out += [(i, src, dst, t, payload[k * size : (k + 1) * size]) for k, (i, t) in enumerate(zip(index, ts))]
    return sorted(out)


def _uniform_capture(tmp_path, n=100, size=962):
    rng = random.Random(5)
    packets = [Packet(1000 * i, *VLP, _payload(rng, size)) for i in range(n)]
    path = tmp_path / "uniform.pcap"
    path.write_bytes(pcap_bytes([(p.timestamp_ns, f) for p in packets for f in frames_for(p)]))
    return path, 16 + 42 + size  # file, record stride


@needs_native
@pytest.mark.parametrize("limit", [10_000, 20 * 1020 + 7, 20 * 1020 - 1, 3 * 1020 + 1])
def test_byte_limit_of_chunks(tmp_path, monkeypatch, mixed, limit):
    """MAX_CHUNK_BYTES (byte_limit of walk_pcap) ends chunks at the same record both ways."""
    path, stride = _uniform_capture(tmp_path)
    assert stride == 1020
    monkeypatch.setattr(pcap_module, "MAX_CHUNK_BYTES", limit)
    batches, _, _ = _assert_same(path)
    # a chunk holds the records that start less than `limit` bytes after its first one
    assert [len(b[7]) for b in batches][:-1] == [-(-limit // stride)] * (len(batches) - 1)
    mixed_path = tmp_path / "mixed.pcap"
    mixed_path.write_bytes(pcap_bytes(mixed))
    _assert_same(mixed_path)
    _assert_same(mixed_path, batch_packets=7)


@needs_native
def test_byte_limit_exact_multiple_of_the_stride(tmp_path, monkeypatch):
    path, stride = _uniform_capture(tmp_path)
    monkeypatch.setattr(pcap_module, "MAX_CHUNK_BYTES", 20 * stride)
    batches, _, _ = _assert_same(path)
    assert [len(b[7]) for b in batches] == [20] * 5


# --- 2b. pcapng: the compiled walk over enhanced packet blocks against the record-by-record walk -----
def _pcapng_of(records, *, big_endian=False, seed=0, extra_blocks=True, raw_epb_iface=None) -> bytes:
    """One section with four interfaces (µs; ns with an offset; 2^-20 s; 10^-10 s, whose stamps pass
    2^63 and take the per-record conversion), the records spread over them, and between
    them the blocks the compiled walk must stop at and hand back: simple and obsolete packet blocks,
    a name resolution block, a custom block, an EPB naming an undeclared interface."""
    from lidarpkt.writers.pcap import Interface, _block, pcapng_bytes

    rng = random.Random(seed)
    e = ">" if big_endian else "<"
    interfaces = (Interface(), Interface(tsresol=9, tsoffset_s=-3600), Interface(tsresol=0x80 | 20),
                  Interface(tsresol=10))
    which = [rng.choice((0, 0, 0, 1, 2, 3)) for _ in records]
    body = pcapng_bytes([(w, ts, f) for w, (ts, f) in zip(which, records)], interfaces=interfaces,
                        big_endian=big_endian)
    if not extra_blocks:
        return body
    # split after the section and interface blocks, then after every block, inserting odd blocks
    off, blocks = 0, []
    while off < len(body):
        blen = struct.unpack_from(e + "I", body, off + 4)[0]
        blocks.append(body[off : off + blen])
        off += blen
    head, packets = blocks[:5], blocks[5:]
    spb = _block(e, 3, struct.pack(e + "I", 60) + bytes(range(60)))
    opb = _block(e, 2, struct.pack(e + "HHIIII", 0, 0, 1, 2, 54, 54) + bytes(54))
    nrb = _block(e, 4, struct.pack(e + "HH", 0, 0))
    custom = _block(e, 0x40000BAD, b"lidarpkt")
    stray = _block(e, 6, struct.pack(e + "IIIII", 9, 0, 0, 4, 4) + b"abcd")  # interface 9 of 4
    out = list(head)
    for i, blk in enumerate(packets):
        out.append(blk)
        if i % 17 == 3:
            out.append(rng.choice((spb, opb, nrb, custom, stray)))
    return b"".join(out)


@needs_native
@pytest.mark.parametrize("big_endian", [False, True])
@pytest.mark.parametrize("batch_packets", [1, 5, 4096])
def test_generated_pcapng_native_equals_record_by_record(tmp_path, mixed, big_endian, batch_packets):
    path = tmp_path / "m.pcapng"
    path.write_bytes(_pcapng_of(mixed, big_endian=big_endian))
    batches, stats, _ = _assert_same(path, batch_packets=batch_packets)
    assert stats["format"] == "pcapng" and stats["interfaces"] == 4
    assert stats["malformed_reasons"].get("pcapng packet for an undeclared interface", 0) > 0  # the stray blocks
    assert sum(len(b[7]) for b in batches) > 150


@needs_native
@pytest.mark.parametrize("block", [1600, 4999])
def test_generated_pcapng_small_read_blocks(tmp_path, monkeypatch, mixed, block):
    monkeypatch.setattr(pcap_module, "READ_BLOCK_BYTES", block + 12_000)  # still holds the largest block
    path = tmp_path / "m.pcapng"
    path.write_bytes(_pcapng_of(mixed, seed=2))
    _assert_same(path, batch_packets=7)


@needs_native
def test_pcapng_time_stamps_outside_int64_are_malformed_either_way(tmp_path, mixed):
    """Whole-second stamps times 10^9 that pass 2^63 take the record-by-record conversion; a time
    beyond 2^63 ns is counted malformed and dropped by both walks."""
    from lidarpkt.writers.pcap import Interface, _block, pcapng_bytes

    head = pcapng_bytes([], interfaces=(Interface(tsresol=0),))  # whole seconds
    e = "<"
    frame = mixed[0][1]
    epbs = b"".join(
        _block(e, 6, struct.pack(e + "IIIII", 0, sec >> 32, sec & 0xFFFFFFFF, len(frame), len(frame)) + frame)
        for sec in (1_700_000_000, 2**40, 9_223_372_036, 9_223_372_037, 2**63 - 1, 5)
    )
    path = tmp_path / "t.pcapng"
    path.write_bytes(head + epbs)
    batches, stats, _ = _assert_same(path)
    assert stats["malformed_reasons"]["pcapng time stamp out of range"] == 3
    assert [t for b in batches for t in b[3]] == [1_700_000_000 * 10**9, 9_223_372_036 * 10**9, 5 * 10**9]


@needs_native
def test_pcapng_cut_and_damaged_anywhere(tmp_path, mixed):
    data = _pcapng_of(mixed[:60], seed=3)
    rng = random.Random(5)
    cuts = sorted(set(range(len(data) - 40, len(data) + 1)) | {rng.randrange(28, len(data)) for _ in range(60)})
    path = tmp_path / "c.pcapng"
    inputs = [data[:cut] for cut in cuts]
    for _ in range(80):  # one byte of a block length or body changed
        raw = bytearray(data)
        raw[rng.randrange(28, len(raw))] = rng.randrange(256)
        inputs.append(bytes(raw))
    refused = 0
    for blob in inputs:
        path.write_bytes(blob)
        try:
            _assert_same(path, batch_packets=5)
        except CaptureFormatError as native_error:  # then the record-by-record walk refuses it alike
            refused += 1
            with pytest.raises(CaptureFormatError) as ref_error:
                _read(path, None, batch_packets=5)
            assert str(ref_error.value) == str(native_error)
    assert refused < len(inputs) // 2


# --- 3. truncation and corruption ---------------------------------------------------------------------
@pytest.fixture(scope="module")
def mixed_bytes(mixed):
    data = pcap_bytes(mixed)
    return data, _record_starts(data)


def _cut_offsets(data: bytes, starts: list[int]) -> list[int]:
    """Every offset from inside the last header bytes of the record before some boundaries to a
    few data bytes after them (cut headers, cut data, exact boundaries), and a sample of the rest."""
    n = len(starts) - 1
    around = [1, 41, n // 2, n - 12, n - 1, n]  # early, in a run, in fragments, near and at the end
    cuts = set(range(24, 30))
    for k in around:
        b = starts[k]
        cuts.update(range(max(24, b - 3), min(len(data), b + 19)))
    cuts.update(random.Random(7).sample(range(24, len(data)), 60))
    return sorted(cuts)


@needs_native
def test_truncated_at_many_offsets(tmp_path, mixed_bytes):
    data, starts = mixed_bytes
    path = tmp_path / "cut.pcap"
    kinds = set()
    cuts = _cut_offsets(data, starts)
    assert len(cuts) > 150
    for cut in cuts:
        path.write_bytes(data[:cut])
        batch_packets = (3, 4096)[cut % 2]
        _, stats, messages = _assert_same(path, batch_packets=batch_packets)
        kinds.update(m[0] for m in messages)
        assert stats["truncated"] == (cut not in starts)
        if cut in starts:
            assert stats["records"] == starts.index(cut)
            assert "TruncatedCaptureWarning" not in {m[0] for m in messages}
        else:
            assert messages[0][0] == "TruncatedCaptureWarning"
    assert kinds == {TruncatedCaptureWarning.__name__, SkippedPacketWarning.__name__}
    for cut in range(0, 24):  # inside the global header: not a capture, both ways
        path.write_bytes(data[:cut])
        for native in (NATIVE, None):
            with _impl(native), pytest.raises(CaptureFormatError):
                PcapReader(path)


@needs_native
@pytest.mark.parametrize("endian", ["<", ">"])
def test_corrupt_record_lengths(tmp_path, mixed, endian):
    data = pcap_bytes(mixed, big_endian=endian == ">")
    starts = _record_starts(data, endian=endian)
    path = tmp_path / "corrupt.pcap"
    n = len(starts) - 1
    messages_seen = set()
    for k in (0, 1, 9, 45, n // 2, n - 5, n - 1):
        true_len = struct.unpack_from(endian + "I", data, starts[k] + 8)[0]
        for claim in (0xFFFFFFFF, 0x80000000, 0x7FFFFFFF, MAX_RECORD_BYTES + 1, MAX_RECORD_BYTES, len(data),
                      true_len + 1, true_len - 1 if true_len else 3, 0):
            bad = bytearray(data)
            struct.pack_into(endian + "I", bad, starts[k] + 8, claim)
            path.write_bytes(bytes(bad))
            for batch_packets in (3, 4096):
                batches, stats, messages = _assert_same(path, batch_packets=batch_packets)
                messages_seen.update(m[1].split(": ", 1)[1][:30] for m in messages if m[0] == "TruncatedCaptureWarning")
                if claim > MAX_RECORD_BYTES:
                    assert stats["truncated"] and stats["records"] == k
                    assert any(f"record at offset {starts[k]} claims {claim}" in m[1] for m in messages)
    assert len(messages_seen) >= 2  # "record at offset ... claims" and "last record at offset ..." at least


# --- 4. property: random record sizes -----------------------------------------------------------------
_SIZE = st.one_of(st.sampled_from([0, 48, 512, 1206, 1472, 1473]), st.integers(0, 3000))
_RUNS = st.lists(st.tuples(_SIZE, st.integers(1, 40), st.booleans()), min_size=0, max_size=8)


@needs_native
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    runs=_RUNS,
    big_endian=st.booleans(),
    nanosecond=st.booleans(),
    fragment=st.booleans(),
    batch_packets=st.sampled_from([1, 3, 7, 64, 4096]),
    cut=st.one_of(st.none(), st.integers(0, 1 << 20)),
    seed=st.integers(0, 2**32 - 1),
)
def test_random_record_sizes(tmp_path, runs, big_endian, nanosecond, fragment, batch_packets, cut, seed):
    """Runs of records of one size (the speculative walk) and single records (the record-by-record
    walk): UDP datagrams (fragmented when `fragment` and larger than MTU 1500) or junk frames."""
    rng = random.Random(seed)
    records = []
    t = 1_500_000_000 * 10**9
    for size, count, junk in runs:
        for _ in range(count):
            t += rng.randrange(1, 10**9)
            if junk:
                records.append((t, _payload(rng, size)))
            else:
                p = Packet(t, Endpoint("10.1.2.3", 4000 + size % 7), Endpoint("10.1.2.4", 2368), _payload(rng, size))
                records += [(t, f) for f in frames_for(p, mtu=1500 if fragment else None, ident=len(records))]
    data = pcap_bytes(records, big_endian=big_endian, nanosecond=nanosecond)
    if cut is not None:
        data = data[: max(24, min(cut, len(data)))]
    path = tmp_path / "random.pcap"
    path.write_bytes(data)
    _, stats, _ = _assert_same(path, batch_packets=batch_packets)
    if cut is None:
        assert stats["records"] == len(records) and not stats["truncated"]


# --- 5. gather_rows -------------------------------------------------------------------------------------
@needs_native
@pytest.mark.parametrize("width", [1, 2, 3, 4, 8, 100])
def test_gather_rows_equals_slicing(width):
    rng = np.random.default_rng(width)
    for size in (width, width + 1, 1000, 65_537):
        buf = rng.integers(0, 256, size, dtype=np.uint8)
        for n in (0, 1, 5, 1000):
            offs = rng.integers(0, size - width + 1, n, dtype=np.int64)
            if n:
                offs[0] = size - width  # the last row that fits
            out = np.full((n, width), 0xAA, np.uint8)
            assert NATIVE.gather_rows(buf, offs, out) is None
            want = np.array([buf[o : o + width] for o in offs.tolist()], np.uint8).reshape(n, width)
            assert np.array_equal(out, want)
            with _impl(None):
                assert np.array_equal(gathers.copy_rows(buf, offs, width), want)
            with _impl(NATIVE):
                assert np.array_equal(gathers.copy_rows(buf, offs, width), want)
    # any writable bytes-like source works (the reader passes NumPy arrays, bytes would do)
    out = np.empty((2, 3), np.uint8)
    NATIVE.gather_rows(b"abcdefgh", np.array([5, 0], np.int64), out)
    assert out.tobytes() == b"fghabc"


@needs_native
@pytest.mark.parametrize("width", [1, 2, 3, 4, 8, 100])
def test_gather_rows_rejects_rows_outside_the_buffer(width):
    buf = np.arange(200, dtype=np.uint8)
    for bad in (200 - width + 1, 200, 10_000, -1, -width, -(2**62)):
        offs = np.array([0, bad, 3], np.int64)
        out = np.empty((3, width), np.uint8)
        with pytest.raises(IndexError, match="leaves the 200-byte buffer"):
            NATIVE.gather_rows(buf, offs, out)


@needs_native
def test_gather_rows_offset_near_int64_max_is_an_index_error():
    code = (
        "import numpy as np, lidarpkt._native as n\n"
        "try:\n"
        "    n.gather_rows(np.zeros(100, np.uint8), np.array([2**63 - 1], np.int64), np.empty((1, 8), np.uint8))\n"
        "except IndexError:\n"
        "    print('IndexError')\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0 and res.stdout.strip() == "IndexError", (res.returncode, res.stderr[-300:])


@needs_native
def test_gather_rows_rejects_an_out_of_the_wrong_size():
    buf = np.arange(100, dtype=np.uint8)
    offs = np.array([1, 2, 3], np.int64)
    # out must be uint8 [len(offsets), width]
    for shape in ((4, 4), (10,), (2, 5), (13,), (1, 1)):
        with pytest.raises(ValueError, match=r"out uint8 \[len\(offsets\), width\]"):
            NATIVE.gather_rows(buf, offs, np.empty(shape, np.uint8))
    with pytest.raises(ValueError, match=r"out uint8 \[len\(offsets\), width\]"):  # no offsets, yet bytes to fill
        NATIVE.gather_rows(buf, np.zeros(0, np.int64), np.empty((1, 4), np.uint8))
    with pytest.raises(ValueError, match="expected items of 8 bytes"):
        NATIVE.gather_rows(buf, offs.astype(np.int32), np.empty((3, 4), np.uint8))
    with pytest.raises(ValueError, match="offsets must be native int64"):  # 8-byte items, but not integers
        NATIVE.gather_rows(buf, offs.astype(np.float64), np.empty((3, 4), np.uint8))
    with pytest.raises(ValueError, match="expected items of 1 bytes"):
        NATIVE.gather_rows(buf, offs, np.empty((3, 4), np.uint16))
    with pytest.raises(ValueError, match="read-only"):
        NATIVE.gather_rows(buf, offs, np.frombuffer(bytes(12), np.uint8))


# --- 6. walk_pcap ---------------------------------------------------------------------------------------
def _records_buffer(caps, endian="<", header_bytes=16, lead=0):
    """``lead`` junk bytes, then records with these incl_len values (data bytes = incl_len), and their offsets."""
    buf = bytearray(b"\x99" * lead)
    offs = []
    for i, cap in enumerate(caps):
        offs.append(len(buf))
        head = struct.pack(endian + "IIII", 1000 + i, i, cap, cap) + b"\x77" * (header_bytes - 16)
        buf += head + bytes([i & 0xFF]) * cap
    return np.frombuffer(bytes(buf), np.uint8), offs


def _walk(buf, start=0, end=None, *, hdr=16, swap=False, max_cap=65535, max_records=100, byte_limit=1 << 40):
    out = np.full(max(max_records, 1), -7, np.int64)
    n, nxt, reason = NATIVE.walk_pcap(buf, start, buf.shape[0] if end is None else end, 8, hdr, swap, max_cap,
                                      max_records, byte_limit, out)
    assert np.all(out[n:] == -7)  # nothing written past the records found
    return out[:n].tolist(), nxt, reason


CAPS = [10, 20, 0, 5, 1206, 3]


@needs_native
@pytest.mark.parametrize("endian", ["<", ">"])
@pytest.mark.parametrize("hdr,lead", [(16, 0), (16, 13), (24, 5)])
def test_walk_pcap_reasons_and_offsets(endian, hdr, lead):
    swap = (endian == ">") != (sys.byteorder == "big")
    buf, offs = _records_buffer(CAPS, endian, hdr, lead)
    size = buf.shape[0]
    kw = dict(hdr=hdr, swap=swap)
    # every whole record; at the exact end the next header is "cut" with 0 bytes (reason 1, next = end)
    assert _walk(buf, lead, **kw) == (offs, size, 1)
    # a header cut: the last record's header is short by 1..hdr-1 bytes (and 'end' beyond the buffer is clamped)
    last = offs[-1]
    for e in range(last + 1, last + hdr):
        assert _walk(buf, lead, e, **kw) == (offs[:-1], last, 1)
    assert _walk(buf, lead, size + 1000, **kw) == (offs, size, 1)
    # its data cut: the header is whole, the data short
    for e in range(last + hdr, size):
        assert _walk(buf, lead, e, **kw) == (offs[:-1], last, 3)
    # a record claiming more than max_cap: stop at it; exactly max_cap is fine
    assert _walk(buf, lead, max_cap=1205, **kw) == (offs[:4], offs[4], 2)
    assert _walk(buf, lead, max_cap=1206, **kw) == (offs, size, 1)
    assert _walk(buf, lead, max_cap=0, **kw) == ([], lead, 2)
    # limits: max_records, byte_limit (a record is taken when it starts before the limit)
    ends = offs + [size]
    for k in range(len(CAPS) + 1):  # the limit is checked first: reason 0 even after the last record
        assert _walk(buf, lead, max_records=k, **kw) == (offs[:k], ends[k], 0)
    for k in range(1, len(CAPS)):
        assert _walk(buf, lead, byte_limit=offs[k], **kw) == (offs[:k], offs[k], 0)
        assert _walk(buf, lead, byte_limit=offs[k] + 1, **kw) == (offs[: k + 1], ends[k + 1], 0)
    assert _walk(buf, lead, byte_limit=lead, **kw) == ([], lead, 0)
    # from the middle
    assert _walk(buf, offs[2], **kw) == (offs[2:], size, 1)
    # start beyond the end: nothing, header cut
    assert _walk(buf, size + 5, **kw) == ([], size + 5, 1)


@needs_native
def test_walk_pcap_huge_claims_and_wrong_byte_order():
    buf, offs = _records_buffer([4, 4, 4])
    raw = bytearray(buf.tobytes())
    struct.pack_into("<I", raw, offs[1] + 8, 0xFFFFFFF0)
    buf = np.frombuffer(bytes(raw), np.uint8)
    assert _walk(buf, max_cap=2**32) == (offs[:1], offs[1], 3)  # no overflow of rel + header + cap
    assert _walk(buf, max_cap=2**18) == (offs[:1], offs[1], 2)
    # read with the wrong byte order, 10 claims 0x0a000000 bytes
    buf, offs = _records_buffer([10, 10])
    assert _walk(buf, swap=True, max_cap=2**32) == ([], 0, 3)
    assert _walk(buf, swap=True) == ([], 0, 2)


@needs_native
def test_walk_pcap_rejects_bad_arguments():
    buf, _ = _records_buffer(CAPS)
    out = np.zeros(4, np.int64)
    with pytest.raises(ValueError, match="bad arguments"):
        NATIVE.walk_pcap(buf, 0, buf.shape[0], 8, 16, False, 65535, 5, 1 << 40, out)  # more records than room
    with pytest.raises(ValueError, match="bad arguments"):
        NATIVE.walk_pcap(buf, -1, buf.shape[0], 8, 16, False, 65535, 4, 1 << 40, out)
    with pytest.raises(ValueError, match="bad arguments"):
        NATIVE.walk_pcap(buf, 0, buf.shape[0], 8, 11, False, 65535, 4, 1 << 40, out)  # header ends inside incl_len
    with pytest.raises(ValueError, match="expected items of 8 bytes"):
        NATIVE.walk_pcap(buf, 0, buf.shape[0], 8, 16, False, 65535, 4, 1 << 40, np.zeros(4, np.int32))
    with pytest.raises(BufferError, match="not writable"):  # offsets out must be writable
        NATIVE.walk_pcap(buf, 0, buf.shape[0], 8, 16, False, 65535, 4, 1 << 40, bytes(32))


def _reference_walk(data: bytes, start, end, hdr, endian, max_cap, max_records, byte_limit):
    """The documented walk, one record at a time in Python."""
    end = min(end, len(data))
    rel, offs = start, []
    while len(offs) < max_records and rel < byte_limit:
        if rel + hdr > end:
            return offs, rel, 1
        cap = struct.unpack_from(endian + "I", data, rel + 8)[0]
        if cap > max_cap:
            return offs, rel, 2
        if rel + hdr + cap > end:
            return offs, rel, 3
        offs.append(rel)
        rel += hdr + cap
    return offs, rel, 0


@needs_native
@settings(max_examples=60, deadline=None)
@given(
    caps=st.lists(st.one_of(st.integers(0, 40), st.integers(0, 2**32 - 1)), max_size=30),
    endian=st.sampled_from("<>"),
    hdr=st.sampled_from([12, 16, 24]),
    start=st.integers(0, 50),
    end_cut=st.integers(0, 200),
    max_cap=st.integers(0, 2**32),
    max_records=st.integers(0, 40),
    byte_limit=st.integers(0, 3000),
    junk=st.binary(max_size=64),
)
def test_walk_pcap_matches_a_reference_walk(caps, endian, hdr, start, end_cut, max_cap, max_records, byte_limit, junk):
    data = bytearray()
    for cap in caps:
        data += struct.pack(endian + "II", 0, 0) + struct.pack(endian + "I", cap) + b"\0" * (hdr - 12)
        data += b"\x01" * min(cap, 40)  # huge claims are cut, like damage
    data = bytes(data) + junk
    buf = np.frombuffer(data, np.uint8) if data else np.zeros(0, np.uint8)
    end = max(0, len(data) - end_cut)
    swap = (endian == ">") != (sys.byteorder == "big")
    out = np.full(max(max_records, 1), -7, np.int64)
    n, nxt, reason = NATIVE.walk_pcap(buf, start, end, 8, hdr, swap, max_cap, max_records, byte_limit, out)
    assert (out[:n].tolist(), nxt, reason) == _reference_walk(data, start, end, hdr, endian, max_cap, max_records,
                                                              byte_limit)


# --- 7. Ouster XYZ ------------------------------------------------------------------------------------
def _ouster_sources():
    """(label, capture path, metadata) of every Ouster capture with metadata: external and canned."""
    out = [(pcap, pcap, jsons) for pcap, jsons, _ in OUSTER_CAPTURES]
    out += [(f"canned/{n}", None, n) for n in fixtures.CAPTURES if fixtures.metadata_path(fixtures.canned(n))]
    return out


OUSTER_SOURCES = _ouster_sources()


def _assert_xyz_identical(frame, label):
    """The compiled and the NumPy XYZ give the same bits, in float64 and in float32; returns the float64 points."""
    for dtype, word in ((np.float64, np.uint64), (np.float32, np.uint32)):
        native = frame.xyz(dtype)
        with _impl(None):
            ref = frame.xyz(dtype)
        assert native.shape == ref.shape == frame.range_mm.shape + (3,) and native.dtype == ref.dtype == dtype
        same = native.view(word) == ref.view(word)
        assert same.all(), f"{label} {dtype.__name__}: {np.count_nonzero(~same)} coordinates differ in their bits"
        empty = frame.range_mm == 0
        assert not native.view(word)[empty].any(), f"{label}: a pixel without a return is not +0.0"
        if dtype == np.float64:
            points = native
    return points


@needs_native
@pytest.mark.parametrize("label,pcap,meta", OUSTER_SOURCES, ids=[s[0].split("/")[-1] for s in OUSTER_SOURCES])
def test_ouster_xyz_native_equals_numpy(label, pcap, meta):
    if pcap is None:
        path = fixtures.canned(meta)
        metadata = fixtures.metadata_path(path)
    else:
        path = external(pcap)
        metadata = [external(j) for j in meta]
        metadata = metadata[0] if len(metadata) == 1 else metadata
    frames = list(lidarpkt.open(path, metadata=metadata))
    if "empty_pcap" in label:
        assert frames == []
        return
    assert frames, label
    for i, frame in enumerate(frames):
        xyz = _assert_xyz_identical(frame, f"{label} frame {i}")
        assert np.count_nonzero(frame.range_mm) == 0 or np.any(xyz != 0)
    if label in ("ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.pcap", "canned/os1-64-dual"):
        assert frames[0].range_mm.shape[0] == 2  # dual-return frames were covered
        assert np.count_nonzero(frames[0].range_mm == 0) > 0  # and pixels without a return


@needs_native
def test_ouster_xyz_all_range_values():
    """Every uint32 range (incl. 1, 2^20-1, 2^32-1) and zeros, R = 1, 2 and 3: the same bits both ways."""
    frames = list(lidarpkt.open(external("ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.pcap"),
                                metadata=external("ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.json")))
    frame = frames[0]
    rng = np.random.default_rng(3)
    h, w = frame.range_mm.shape[1:]
    for r in (1, 2, 3):
        values = rng.integers(0, 2**32, (r, h, w), dtype=np.uint64).astype(np.uint32)
        values[rng.random((r, h, w)) < 0.2] = 0
        values.reshape(-1)[:6] = [1, 2**20 - 1, 2**32 - 1, 0, 2**31, 7]
        frame.range_mm = values
        _assert_xyz_identical(frame, f"random ranges, R={r}")
        # and the NumPy twin is range * direction + offset, rounded twice, zero where no return
        direction, offset = frame.sensor.geometry._planes
        want = values[..., None].astype(np.float64) * np.moveaxis(direction, 0, -1) + np.moveaxis(offset, 0, -1)
        want[values == 0] = 0.0
        assert np.array_equal(frame.xyz().view(np.uint64), want.view(np.uint64))


@needs_native
def test_xyz_lut_direct_and_its_size_checks():
    rng = np.random.default_rng(11)
    hw = 37
    direction = rng.normal(size=(3, hw))
    offset = rng.normal(size=(3, hw))
    rng_mm = rng.integers(0, 100_000, (2, hw), dtype=np.uint32)
    rng_mm[0, :5] = 0
    out = np.full((2, hw, 3), np.nan)
    assert NATIVE.xyz_lut(rng_mm, direction, offset, out) is None
    want = rng_mm[..., None].astype(np.float64) * direction.T + offset.T
    want[rng_mm == 0] = 0.0
    assert np.array_equal(out.view(np.uint64), want.view(np.uint64))
    bad = {
        "offset of another size": (rng_mm, direction, np.ascontiguousarray(offset[:, :-1]), out),
        "ranges not a whole number of frames": (rng_mm.reshape(-1)[:-1].copy(), direction, offset, np.empty((2 * hw - 1, 3))),
        "out too small": (rng_mm, direction, offset, np.empty((2, hw, 2))),
        "out too large": (rng_mm, direction, offset, np.empty((3, hw, 3))),
        "empty lookup table": (rng_mm, np.empty((3, 0)), np.empty((3, 0)), out),
    }
    for what, args in bad.items():
        with pytest.raises(ValueError, match="of agreeing sizes"):
            NATIVE.xyz_lut(*args)
            pytest.fail(what)
    with pytest.raises(ValueError, match="all float64 or all float32"):
        NATIVE.xyz_lut(rng_mm, direction.astype(np.float32), offset, out)
    with pytest.raises(ValueError, match="all float64 or all float32"):
        NATIVE.xyz_lut(rng_mm, direction.astype(np.float16), offset.astype(np.float16), out.astype(np.float16))
    # float32: products and sums in float32 (ouster-sdk's XYZLutFloat), zero where no return
    d32, o32 = direction.astype(np.float32), offset.astype(np.float32)
    out32 = np.full((2, hw, 3), np.nan, np.float32)
    assert NATIVE.xyz_lut(rng_mm, d32, o32, out32) is None
    want32 = rng_mm[..., None].astype(np.float32) * d32.T + o32.T
    want32[rng_mm == 0] = 0.0
    assert want32.dtype == np.float32 and np.array_equal(out32.view(np.uint32), want32.view(np.uint32))
    with pytest.raises(ValueError, match="expected items of 4 bytes"):
        NATIVE.xyz_lut(rng_mm.astype(np.uint16), direction, offset, out)
    with pytest.raises(ValueError, match="range must be uint32"):  # 4-byte items, but floats
        NATIVE.xyz_lut(rng_mm.astype(np.float32), direction, offset, out)
    with pytest.raises(ValueError, match="range must be uint32"):  # 8-byte items, but integers
        NATIVE.xyz_lut(rng_mm, direction.view(np.int64), offset, out)
    with pytest.raises(ValueError, match="not C-contiguous"):
        NATIVE.xyz_lut(rng_mm, np.zeros((hw, 3)).T, offset, out)
