"""Inputs that the fuzzers (benchmarks/fuzz.py) and the hostile-input tests found, kept as regressions.

Each test names the input and what went wrong before the fix.
"""

from __future__ import annotations

import copy
import json
import subprocess
import sys
import tracemalloc
import warnings
from pathlib import Path

import numpy as np
import pytest

from conftest import external
from lidarpkt.errors import MetadataError
from lidarpkt.vendors.ouster import OusterDecoder, OusterGeometry, load_metadata
from lidarpkt.core.packet import PacketBatch
from lidarpkt.containers.reassembly import FRAGMENT_OVERHEAD, Reassembler
import lidarpkt.containers.pcap_reader  # noqa: F401 - used as lidarpkt.containers.pcap_reader below
from reference_tools import velodyne_scan_mcap

DATA = Path(__file__).resolve().parents[1] / "data" / "fuzz"


# --------------------------------------------------------------------------- Ouster metadata
def test_fuzz_metadata_pixel_shift_overflow_is_a_metadata_error():
    """fuzz input: a pixel_shift_by_row entry of ~1e30 (integral as a float) was cast to int64 with a
    RuntimeWarning and a garbage stagger; now a MetadataError naming the field."""
    doc = json.loads((DATA / "metadata-pixel-shift-overflow.json").read_bytes())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(MetadataError, match="pixel_shift_by_row"):
            load_metadata(doc)


def _edit(path, *keys_value):
    def apply(doc):
        *keys, value = keys_value
        node = doc
        for k in keys[:-1]:
            node = node[k]
        node[keys[-1]] = value

    return apply


@pytest.mark.parametrize(
    "edit, field",
    [
        (_edit(None, "lidar_data_format", "pixel_shift_by_row", 0, 1e30), "pixel_shift_by_row"),
        (_edit(None, "lidar_data_format", "pixel_shift_by_row", 0, 512), "pixel_shift_by_row"),
        # 16e8 columns: OusterDecoder allocated 11.9 GiB (MemoryError)
        (_edit(None, "lidar_data_format", "columns_per_frame", 16 * 10**8), "measurement_id"),
        # a 2 GB "packet" (columns_per_packet = columns_per_frame = 2**16)
        (_edit(None, "lidar_data_format", "columns_per_packet", 1 << 16), "UDP datagram"),
        # np.uint64(-5) / int too large raised OverflowError in OusterDecoder.push and detect
        (_edit(None, "sensor_info", "prod_sn", "-5"), "prod_sn"),
        (_edit(None, "sensor_info", "prod_sn", "99999999999999999999999"), "prod_sn"),
        (_edit(None, "sensor_info", "prod_sn", "1" * 5000), "prod_sn"),
        (_edit(None, "sensor_info", "initialization_id", 10**30), "initialization_id"),
        (_edit(None, "config_params", "udp_port_lidar", 70000), "udp_port_lidar"),
    ],
)
def test_impossible_metadata_values_are_named(edit, field):
    doc = json.loads(external("ouster-sdk/empty_pcap.json").read_text())
    doc = copy.deepcopy(doc)
    if field == "UDP datagram":
        doc["lidar_data_format"]["columns_per_frame"] = 1 << 16
        doc["lidar_data_format"]["column_window"] = [0, 5]
    if field == "measurement_id":
        doc["lidar_data_format"]["column_window"] = [0, 5]
    edit(doc)
    with pytest.raises(MetadataError, match=field):
        load_metadata(doc)


def test_real_serials_and_ids_still_load_and_decode():
    """The new bounds leave every real metadata file as it was: a decoder builds and takes a packet."""
    for rel in ("ouster-sdk/empty_pcap.json", "ouster-sdk/crc_test.json", "ouster-sdk/same_ports_nonlegacy.2.json",
                "ouster-sdk/OS-1-64_sensor_config_reduced.json"):
        md = load_metadata(external(rel))
        OusterGeometry(md)
        dec = OusterDecoder(md)
        dec.push(PacketBatch.from_payloads(np.zeros((1, md.packet_size), np.uint8)))
        assert dec.stats.packets == 1


# --------------------------------------------------------------------------- fragment reassembly
def test_tiny_orphan_fragments_are_charged_their_memory():
    """Orphan 1-byte fragments at every 8-byte offset of 1024 datagrams: before, held_bytes counted only
    the data (8 MB of 64 MB allowed) while Python held ~70 bytes per fragment (~580 MB). Now each
    fragment is charged FRAGMENT_OVERHEAD too, and the traced memory stays near max_bytes."""
    budget = 4 * 1024 * 1024
    r = Reassembler(max_bytes=budget)
    tracemalloc.start()
    try:
        n = 0
        for k in range(12):
            for off in range(0, 8192 * 8, 8):
                r.add(k, off, True, b"x", n)
                n += 1
        current, _peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert r.held_bytes <= budget
    held = sum(len(p) + FRAGMENT_OVERHEAD for e in r._pending.values() for p in e.pieces.values())
    assert held == r.held_bytes
    assert r.stats.evicted_datagrams > 0 and r.stats.orphaned_fragments > 0
    assert current < 2 * budget, f"{current} bytes traced for a {budget}-byte budget"


# --------------------------------------------------------------------------- bags
def test_bag_whose_first_line_is_not_text_closes_its_file(tmp_path):
    """Input: the first 3 bytes of an MCAP file (b'\\x89MC'), too short to be recognised as MCAP, so read as
    a ROS 1 bag: rosbags' reader failed on the non-UTF-8 line and left the file open (ResourceWarning
    in test_hostile_input's MCAP cut test). Now a CaptureFormatError and the file is closed."""
    import gc

    from lidarpkt.containers.bags import BagReader

    from lidarpkt.vendors.registry import bag_messages
    from lidarpkt.errors import CaptureFormatError

    path = tmp_path / "cut.mcap"
    path.write_bytes(b"\x89MC")
    with warnings.catch_warnings():  # other tests' garbage is collected here, not counted against this file
        warnings.simplefilter("ignore")
        gc.collect()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(CaptureFormatError, match="cannot open as a ROS bag"):
            list(BagReader(path, messages=bag_messages()).batches())
        gc.collect()
    # only this file's: an unclosed file's ResourceWarning names it (other objects may still be collected here)
    assert not [w for w in caught if issubclass(w.category, ResourceWarning) and path.name in str(w.message)]


def test_mcap_with_a_corrupt_compressed_chunk_warns_instead_of_raising_zstd_error(tmp_path):
    """Input (test_hostile_input's mutated-bag test): the 30-packet VelodyneScan MCAP with the byte at
    45.7 % of the file set to 0, inside a zstd chunk: zstandard's ZstdError ('Data corruption
    detected') came out raw. Now the messages before the chunk, then a TruncatedCaptureWarning."""
    from lidarpkt import fixtures
    from lidarpkt.containers.bags import BagReader
    from lidarpkt.vendors.registry import bag_messages
    from lidarpkt.errors import TruncatedCaptureWarning
    from lidarpkt.containers.pcap_reader import read_packets

    pk = [p for p in read_packets(fixtures.canned("vlp16-strongest")) if len(p.payload) == 1206][:30]
    payloads = [p.payload for p in pk]
    raw = bytearray(velodyne_scan_mcap(payloads, [p.timestamp_ns for p in pk], chunk_size=6_000))
    raw[int(0.45687118274246324 * len(raw))] = 0
    path = tmp_path / "corrupt.mcap"
    path.write_bytes(bytes(raw))
    with pytest.warns(TruncatedCaptureWarning, match="damaged"):
        got = [row.tobytes() for b in BagReader(path, messages=bag_messages()).batches() for row in b.payload]
    assert got == payloads[: len(got)] and len(got) < len(payloads)


def test_a_datagram_of_8189_fragments_with_a_hole_is_joined_once_not_per_fragment(monkeypatch):
    """Input: the last fragment of a 65 528-byte datagram, then 8189 fragments of 8 bytes at every
    offset but the last. The reassembler sorted and joined every held piece on each fragment once the
    end was known (quadratic: 3.2 s for this one datagram, hours for a capture of them); now it keeps
    the contiguous prefix held and tries the join only when that prefix reaches the end."""
    calls = []
    real = Reassembler._try_complete

    def counted(self, key, entry):
        calls.append(len(entry.pieces))
        return real(self, key, entry)

    monkeypatch.setattr(Reassembler, "_try_complete", counted)
    r = Reassembler()
    assert r.add("k", 65520, False, b"z" * 8, 0) is None
    for off in range(0, 65512, 8):
        assert r.add("k", off, True, bytes([off // 8 % 251]) * 8, 0) is None
    out = r.add("k", 65512, True, b"y" * 8, 0)
    assert calls == [8191]  # one join, on the fragment that closed the hole
    assert out == b"".join(bytes([o // 8 % 251]) * 8 for o in range(0, 65512, 8)) + b"y" * 8 + b"z" * 8
    # overlapping fragments: the prefix grows from whichever piece reaches furthest
    r = Reassembler()
    r.add("o", 3000, False, b"e" * 100, 0)
    for off in range(8, 2001, 8):  # the last one ends at 3000, where the end fragment starts
        r.add("o", off, True, b"x" * 1000, 0)
    assert r.pending_datagrams == 1 and r.add("o", 0, True, b"x" * 8, 0) is not None


# --------------------------------------------------------------------------- VLP-16: many sources
def test_a_capture_from_hundreds_of_source_addresses_does_not_multiply_the_geometry_tables(tmp_path):
    """Input: 300 source addresses sending one real VLP-16 data packet each (a 0.4 MB capture). Each
    source gets its decoder, and each decoder built its own 0.6 MB cos/sin tables (9 MB with per-row
    corrections): 2000 sources took 1.2 GB. The read-only tables are now shared."""
    from lidarpkt import fixtures
    import lidarpkt
    from lidarpkt.core.packet import Endpoint, Packet
    from lidarpkt.writers.pcap import write_pcap
    from lidarpkt.vendors.velodyne import VelodyneDecoder

    good = next(p for p in lidarpkt.containers.pcap_reader.read_packets(fixtures.canned("vlp16-strongest")) if len(p.payload) == 1206)
    pk = [Packet(1_600_000_000_000_000_000 + i * 1000, Endpoint(f"10.0.{i >> 8}.{i & 255}", 2368),
                 Endpoint("10.0.0.1", 2368), good.payload) for i in range(300)]
    write_pcap(tmp_path / "many.pcap", pk)
    tracemalloc.start()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            frames = list(lidarpkt.open(tmp_path / "many.pcap", max_sensors=300))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert len(frames) == 300 and all(int(f.column_valid.sum()) == 24 for f in frames)
    assert peak < 60e6, f"{peak / 1e6:.0f} MB traced for 300 one-packet sources"
    a, b = VelodyneDecoder(), VelodyneDecoder()
    assert a.geometry._cos is b.geometry._cos and not a.geometry._cos.flags.writeable


def test_a_capture_from_thousands_of_sources_decodes_at_most_max_sensors(tmp_path):
    """Input: one real OS-2-128 lidar packet from each of 100 source addresses (2.5 MB), then 1500
    junk streams. Each Ouster decoder holds up to a frame (~1.6 MB here): 400 sources took 660 MB
    and 4000 would take 6 GB. Now the first 64 sensors are decoded, the rest counted as unrouted with
    one SkippedPacketWarning, and the list of unrouted streams stays short."""
    import lidarpkt
    from lidarpkt.errors import SkippedPacketWarning
    from lidarpkt.core.packet import Endpoint, Packet
    from lidarpkt.writers.pcap import write_pcap

    meta = external("ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.json")
    src = next(p for p in lidarpkt.containers.pcap_reader.read_packets(external("ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.pcap"))
               if len(p.payload) == 24832)
    pk = [Packet(1_600_000_000_000_000_000 + i * 1000, Endpoint(f"10.0.{i >> 8}.{i & 255}", 7502),
                 Endpoint("10.0.0.1", 7502), src.payload) for i in range(100)]
    pk += [Packet(1_600_000_000_100_000_000 + i, Endpoint(f"10.1.{i >> 8}.{i & 255}", 9000 + i % 7),
                  Endpoint("10.0.0.1", 9999), bytes([i & 255]) * (20 + i % 50)) for i in range(1500)]
    write_pcap(tmp_path / "many.pcap", pk, mtu=None)
    reader = lidarpkt.open(tmp_path / "many.pcap", metadata=meta)
    with pytest.warns(SkippedPacketWarning, match="more than 64 sensors"):
        frames = list(reader)
    assert len(reader.decoders) == 64 and len(frames) == 64
    assert reader.stats.unrouted_packets == 36 + 1500
    assert len(reader.stats.unrouted_streams) <= 1001
    assert sum(reader.stats.unrouted_streams.values()) == 36 + 1500


def _chunk_records_length_at(mcap_bytes: bytes, near: int) -> int:
    """Offset of the ``records`` length field (u64) of the MCAP Chunk record holding byte ``near``
    (the first Chunk after it if ``near`` is in no Chunk)."""
    pos = 8  # after the magic
    while pos + 9 <= len(mcap_bytes):
        opcode, length = mcap_bytes[pos], int.from_bytes(mcap_bytes[pos + 1 : pos + 9], "little")
        if opcode == 0x06 and pos + 9 + length > near:
            field = pos + 9 + 8 + 8 + 8 + 4  # message start, end, uncompressed size, uncompressed CRC
            return field + 4 + int.from_bytes(mcap_bytes[field : field + 4], "little")
        pos += 9 + length
    raise AssertionError("no Chunk record in the MCAP")


def test_mcap_with_a_huge_record_length_warns_instead_of_raising_memory_error(tmp_path):
    """Input (test_hostile_input's mutated-bag test, 2026-11-21): the 30-packet VelodyneScan MCAP with
    the byte at 16.8 % of the file set to 1. It lands in a chunk's data-length field, and the mcap
    reader's ``read(length)`` asked for exabytes up front (MemoryError). The same with the top byte
    of each length field set: every one must end in a warning after a prefix of the packets."""
    from lidarpkt import fixtures
    from lidarpkt.containers.bags import BagReader
    from lidarpkt.vendors.registry import bag_messages
    from lidarpkt.errors import TruncatedCaptureWarning
    from lidarpkt.containers.pcap_reader import read_packets

    pk = [p for p in read_packets(fixtures.canned("vlp16-strongest")) if len(p.payload) == 1206][:30]
    payloads = [p.payload for p in pk]
    clean = velodyne_scan_mcap(payloads, [p.timestamp_ns for p in pk], chunk_size=6_000)
    # The found input set a byte at 16.8 % of the file; with the fixture's bytes then, that was inside
    # the records-length field of the chunk there. Fixture bytes change (compression moves records),
    # so find that field rather than the fraction: the chunk holding the 16.8 % mark, its records
    # length (after start/end time, uncompressed size, CRC and the compression string), top byte 1.
    edits = [(_chunk_records_length_at(clean, int(0.16771957051606856 * len(clean))) + 7, 1)]
    # every record's 8-byte length (after its 1-byte opcode, from the 8-byte magic on): top byte 0x7f
    pos = 8
    while pos + 9 <= len(clean) - 8:
        length = int.from_bytes(clean[pos + 1 : pos + 9], "little")
        edits.append((pos + 8, 0x7F))
        pos += 9 + length
    assert len(edits) > 5
    for where, value in edits:
        raw = bytearray(clean)
        raw[where] = value
        path = tmp_path / "huge.mcap"
        path.write_bytes(bytes(raw))
        with pytest.warns(TruncatedCaptureWarning):
            got = [row.tobytes() for b in BagReader(path, messages=bag_messages()).batches() for row in b.payload]
        assert got == payloads[: len(got)], where  # (damage in the summary section comes after all 30)


# --------------------------------------------------------------------------- bags (fuzzer `bags`)
def _open_files_under(folder) -> list[str]:
    """The files under ``folder`` this process holds open (from /proc/self/fd)."""
    import os

    if not os.path.isdir("/proc/self/fd"):
        pytest.skip("needs /proc/self/fd")
    out = []
    for fd in os.listdir("/proc/self/fd"):
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if target.startswith(str(folder)):
            out.append(target)
    return out


def _velodyne_packet_rosbag2(folder, n: int = 12) -> Path:
    """A rosbag2 sqlite3 bag of ``n`` VelodynePacket messages (rosbags' writer); returns its .db3."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from lidarpkt.vendors.registry import ros_definitions

    store = get_typestore(Stores.ROS2_HUMBLE)
    typ = "velodyne_msgs/msg/VelodynePacket"
    store.register(get_types_from_msg(ros_definitions()[typ], typ))
    msg, stamp = store.types[typ], store.types["builtin_interfaces/msg/Time"]
    w = Writer(folder)
    w.open()
    conn = w.add_connection("/velodyne_packet", typ, typestore=store)
    for i in range(n):
        data = np.full(1206, i, np.uint8)
        w.write(conn, 1_000 + i, store.serialize_cdr(msg(stamp=stamp(sec=1, nanosec=i), data=data), typ))
    w.close()
    return Path(folder) / f"{Path(folder).name}.db3"


def test_rosbag2_whose_second_db3_is_damaged_closes_it_while_the_error_is_kept(tmp_path):
    """Fuzzer `bags` (a rosbag2 sqlite3 bag with a page of its .db3 overwritten): the query for the
    messages failed in sqlite ('database disk image is malformed') and the CaptureFormatError kept
    rosbags' cursor alive through its context, so the .db3 stayed open for as long as the caller kept
    the error. Here a bag split in two files whose second has its timestamp index damaged: the 12
    messages of the first come out, then the error, and no file of the bag is open any more."""
    import shutil
    import sqlite3

    from lidarpkt.containers.bags import BagReader

    from lidarpkt.vendors.registry import bag_messages
    from lidarpkt.errors import CaptureFormatError

    db = _velodyne_packet_rosbag2(tmp_path / "bag")
    second = db.with_name("bag_1.db3")
    shutil.copy(db, second)
    con = sqlite3.connect(second)
    root = con.execute("SELECT rootpage FROM sqlite_master WHERE name = 'timestamp_idx'").fetchone()[0]
    page = con.execute("PRAGMA page_size").fetchone()[0]
    con.close()
    raw = bytearray(second.read_bytes())
    raw[(root - 1) * page] = 0  # not a b-tree page type
    second.write_bytes(bytes(raw))
    meta = db.parent / "metadata.yaml"
    meta.write_text(meta.read_text().replace("  - bag.db3", "  - bag.db3\n  - bag_1.db3"))

    got = []
    with pytest.raises(CaptureFormatError, match="damaged after the messages already read") as caught:
        for b in BagReader(db.parent, messages=bag_messages()).batches():
            got += [int(row[0]) for row in b.payload]
    assert got == list(range(12))
    assert caught.value is not None and _open_files_under(tmp_path) == []


def _mcap_storage_rosbag2(folder, mcap: bytes) -> Path:
    """A rosbag2 folder whose storage is the MCAP file ``mcap`` (metadata.yaml written out by hand)."""
    folder.mkdir()
    (folder / "b_0.mcap").write_bytes(mcap)
    (folder / "metadata.yaml").write_text(
        "rosbag2_bagfile_information:\n  version: 8\n  storage_identifier: mcap\n  duration:\n    nanoseconds: 0\n"
        "  starting_time:\n    nanoseconds_since_epoch: 0\n  message_count: 3\n  topics_with_message_count:\n"
        "    - topic_metadata:\n        name: /velodyne_packets\n        type: velodyne_msgs/msg/VelodyneScan\n"
        "        serialization_format: cdr\n        offered_qos_profiles: ''\n      message_count: 3\n"
        "  compression_format: ''\n  compression_mode: ''\n  relative_file_paths:\n    - b_0.mcap\n")
    return folder


@pytest.mark.parametrize("damage", ["mcap storage: summary offset at the end magic", "mcap storage: not an MCAP file",
                                    "sqlite3 storage: no messages table"])
def test_rosbag2_that_fails_to_open_leaves_no_file_open(tmp_path, damage):
    """Fuzzer `bags` (a rosbag2 folder with MCAP storage whose footer was damaged): rosbags' open() failed
    reading the summary ('ord() expected a character', a TypeError) and left the MCAP file open; it
    stayed open while the CaptureFormatError was kept and was then closed by the garbage collector
    (ResourceWarning). Here the footer's summary offset points at the end magic (a struct.error, the
    same leak); the same for a storage file that is no MCAP at all, and (found while fixing these) for
    a .db3 without the messages table, whose sqlite3 connection rosbags never closes. Now a
    CaptureFormatError, and the file is closed before it is raised."""
    import gc

    from lidarpkt.containers.bags import BagReader

    from lidarpkt.vendors.registry import bag_messages
    from lidarpkt.errors import CaptureFormatError
    from lidarpkt.containers.pcap_reader import read_packets

    from lidarpkt import fixtures

    if damage.startswith("sqlite3"):
        import sqlite3

        db = _velodyne_packet_rosbag2(tmp_path / "bag")
        con = sqlite3.connect(db)
        con.execute("DROP TABLE messages")
        con.commit()
        con.close()
        folder = db.parent
    else:
        pk = [p for p in read_packets(fixtures.canned("vlp16-strongest")) if len(p.payload) == 1206][:3]
        mcap = bytearray(velodyne_scan_mcap([p.payload for p in pk], [p.timestamp_ns for p in pk]))
        if "summary" in damage:  # the footer's summary_start (8 bytes after its opcode and length)
            mcap[-37 + 9 : -37 + 17] = (len(mcap) - 8).to_bytes(8, "little")
        else:
            mcap[:8] = b"NOTMCAP!"
        folder = _mcap_storage_rosbag2(tmp_path / "bag", bytes(mcap))
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        with pytest.raises(CaptureFormatError, match="cannot open as a ROS bag") as caught:
            list(BagReader(folder, messages=bag_messages()).batches())
        assert caught.value is not None and _open_files_under(tmp_path) == []
        del caught
        gc.collect()
    assert not [w for w in seen if issubclass(w.category, ResourceWarning)]


def test_mcap_chunk_record_length_of_2_63_or_more_warns_instead_of_overflow_error(tmp_path):
    """Fuzzer `bags` (an uncompressed-chunk MCAP with a length field inside a chunk damaged): a record
    length of 2**63 or more inside a chunk made the mcap reader's BytesIO.read raise a raw OverflowError
    ('cannot fit int into an index-sized integer'). Now the messages of the chunks before, then a
    TruncatedCaptureWarning."""
    import io

    from mcap.writer import CompressionType
    from mcap_ros2.writer import Writer

    from lidarpkt import fixtures
    from lidarpkt.containers.bags import BagReader
    from lidarpkt.vendors.registry import bag_messages
    from lidarpkt.errors import TruncatedCaptureWarning
    from lidarpkt.containers.pcap_reader import read_packets
    from reference_tools import VELODYNE_SCAN_SCHEMA

    pk = [p for p in read_packets(fixtures.canned("vlp16-strongest")) if len(p.payload) == 1206][:6]
    fh = io.BytesIO()
    w = Writer(fh, chunk_size=1_000, compression=CompressionType.NONE)  # one message a chunk
    schema = w.register_msgdef("velodyne_msgs/msg/VelodyneScan", VELODYNE_SCAN_SCHEMA)
    for p in pk:
        t = {"sec": p.timestamp_ns // 10**9, "nanosec": p.timestamp_ns % 10**9}
        w.write_message("/velodyne_packets", schema, {"header": {"stamp": t, "frame_id": "v"},
                        "packets": [{"stamp": t, "data": p.payload}]}, log_time=p.timestamp_ns)
    w.finish()
    clean = fh.getvalue()
    chunks, pos = [], 8  # (offset of the records inside each chunk) from the top-level records
    while pos + 9 <= len(clean) - 8:
        op, length = clean[pos], int.from_bytes(clean[pos + 1 : pos + 9], "little")
        if op == 0x06:  # chunk: start, end, uncompressed size (8 each), crc (4), compression (4 + n), records length (8)
            n = int.from_bytes(clean[pos + 9 + 28 : pos + 9 + 32], "little")
            chunks.append(pos + 9 + 32 + n + 8)
        pos += 9 + length
    assert len(chunks) >= 4
    raw = bytearray(clean)
    third = chunks[2]
    while raw[third] != 0x05:  # to the message record of the third chunk (after its schema / channel)
        third += 9 + int.from_bytes(raw[third + 1 : third + 9], "little")
    raw[third + 8] = 0x80  # its length's top byte: >= 2**63
    path = tmp_path / "long.mcap"
    path.write_bytes(bytes(raw))
    with pytest.warns(TruncatedCaptureWarning, match="cut short or damaged after 2 messages"):
        got = [row.tobytes() for b in BagReader(path, messages=bag_messages()).batches() for row in b.payload]
    assert got == [p.payload for p in pk[:2]]


def _scan_and_string_mcap(payloads, times, metadata_text: str) -> bytes:
    """An MCAP (mcap_ros2 writer) of VelodyneScan messages and an /ouster/metadata String."""
    import io

    from mcap_ros2.writer import Writer

    from reference_tools import VELODYNE_SCAN_SCHEMA

    fh = io.BytesIO()
    w = Writer(fh)
    text = w.register_msgdef("std_msgs/msg/String", "string data\n")
    w.write_message("/ouster/metadata", text, {"data": metadata_text}, log_time=int(times[0]))
    scan = w.register_msgdef("velodyne_msgs/msg/VelodyneScan", VELODYNE_SCAN_SCHEMA)
    for p, t in zip(payloads, times):
        stamp = {"sec": int(t) // 10**9, "nanosec": int(t) % 10**9}
        w.write_message("/velodyne_packets", scan, {"header": {"stamp": stamp, "frame_id": "v"},
                        "packets": [{"stamp": stamp, "data": p}]}, log_time=int(t))
    w.finish()
    return fh.getvalue()


@pytest.mark.parametrize("text, was", [
    ("os1\x00.json", "ValueError: embedded null byte"),
    ("METADATA_FILE", "the file at that path read as the sensor's metadata"),
    ('{"a": ' + "[" * 5000 + "]" * 5000 + "}", "RecursionError in json.loads"),
    ('{"a": 1' + "0" * 5000 + "}", "ValueError: integer string conversion limit"),
    ("[1, 2]", "MetadataError (kept: fine, now a warning like the others)"),
])
def test_bag_ouster_metadata_message_that_is_no_json_object_is_skipped_with_a_warning(tmp_path, text, was):
    """Fuzzer `bags` (an MCAP whose /ouster/metadata String was mutated to start with a 0 byte):
    ``lidarpkt.open`` handed the bag's text to ``load_metadata``, which reads any text not starting
    with '{' as the path of a file: a raw ValueError (embedded null byte), and a bag could make lidarpkt
    read (or hang on, /dev/zero) any local file. A JSON object nested too deep or with a 5000-digit
    int gave a raw RecursionError / ValueError. Now ``BagReader.recorded_sensor_file()`` is only ever a JSON
    object's text; any other message there is skipped with a SkippedPacketWarning, and the VLP-16
    packets of the same bag are decoded."""
    import lidarpkt
    from lidarpkt import fixtures
    from lidarpkt.containers.bags import BagReader
    from lidarpkt.vendors.registry import bag_messages
    from lidarpkt.errors import SkippedPacketWarning
    from lidarpkt.containers.pcap_reader import read_packets

    if text == "METADATA_FILE":
        text = str(external("ouster-sdk/OS-1-32-G_v2.1.1_1024x10.json"))
    pk = [p for p in read_packets(fixtures.canned("vlp16-strongest")) if len(p.payload) == 1206][:80]
    path = tmp_path / "b.mcap"
    path.write_bytes(_scan_and_string_mcap([p.payload for p in pk], [p.timestamp_ns for p in pk], text))
    reader = BagReader(path, messages=bag_messages())
    with pytest.warns(SkippedPacketWarning, match="/ouster/metadata is not Ouster metadata"):
        assert sum(len(b) for b in reader.batches()) == 80
    assert reader.recorded_sensor_file() is None
    with pytest.warns(SkippedPacketWarning, match="not Ouster metadata"):
        frames = list(lidarpkt.open(path))
    assert frames and all(f.range_mm.shape[1] == 16 for f in frames), was


@pytest.mark.parametrize("container", ["MCAP file", "rosbag2 with MCAP storage"])
def test_bag_time_beyond_int64_is_a_capture_format_error(tmp_path, container):
    """Fuzzer `bags` (an MCAP whose VelodynePacket message had a log time with the top bit set): MCAP log
    times are uint64, packet times int64 ns, and the packet's bag time raised a raw OverflowError in NumPy
    (and the MCAP file stayed open while that error was kept). Now the packets before, then a
    CaptureFormatError naming the topic and the time, and no file of the bag left open."""
    from lidarpkt.containers.bags import BagReader
    from lidarpkt.vendors.registry import bag_messages
    from lidarpkt.errors import CaptureFormatError
    from lidarpkt.containers.pcap_reader import read_packets

    from lidarpkt import fixtures

    import io

    from mcap_ros2.writer import Writer

    from reference_tools import VELODYNE_SCAN_SCHEMA

    pk = [p for p in read_packets(fixtures.canned("vlp16-strongest")) if len(p.payload) == 1206][:3]
    fh = io.BytesIO()
    w = Writer(fh)
    schema = w.register_msgdef("velodyne_msgs/msg/VelodyneScan", VELODYNE_SCAN_SCHEMA)
    for p, log_time in zip(pk, [pk[0].timestamp_ns, pk[1].timestamp_ns, 2**64 - 1]):
        t = {"sec": p.timestamp_ns // 10**9, "nanosec": p.timestamp_ns % 10**9}
        w.write_message("/velodyne_packets", schema, {"header": {"stamp": t, "frame_id": "v"},
                        "packets": [{"stamp": t, "data": p.payload}]}, log_time=log_time, publish_time=log_time)
    w.finish()
    mcap = fh.getvalue()
    if container == "MCAP file":
        path = tmp_path / "b.mcap"
        path.write_bytes(mcap)
    else:
        path = _mcap_storage_rosbag2(tmp_path / "bag", mcap)
    got = []
    with pytest.raises(CaptureFormatError, match=r"/velodyne_packets has the bag time 18446744073709551615 ns") as caught:
        for b in BagReader(path, messages=bag_messages()).batches():
            got += [row.tobytes() for row in b.payload]
    assert got == [p.payload for p in pk[:2]]
    assert caught.value is not None and _open_files_under(tmp_path) == []


@pytest.mark.parametrize("container", ["rosbag2", "ROS 1"])
def test_bag_without_packet_topics_gives_no_batches_not_key_error(tmp_path, container):
    """Found while writing the fuzzer's `bags` target (reading `_rosbags_messages`): a rosbag2 or ROS 1
    bag with no topic of a packet type (a bag of other topics) made rosbags read every connection
    (it takes an empty connection list as "all"), and the first message of another type raised a raw
    KeyError in ``batches()``. Now no batches, the topics listed in ``stats['skipped_topics']``, and
    ``lidarpkt.open`` yields no frame."""
    import lidarpkt
    from rosbags.typesys import Stores, get_typestore

    from lidarpkt.containers.bags import BagReader

    from lidarpkt.vendors.registry import bag_messages

    if container == "rosbag2":
        from rosbags.rosbag2 import Writer

        store, path = get_typestore(Stores.ROS2_HUMBLE), tmp_path / "bag"
    else:
        from rosbags.rosbag1 import Writer

        store, path = get_typestore(Stores.ROS1_NOETIC), tmp_path / "b.bag"
    w = Writer(path)
    w.open()
    conn = w.add_connection("/chatter", "std_msgs/msg/Int32", typestore=store)
    for i in range(3):
        msg = store.types["std_msgs/msg/Int32"](data=i)
        raw = store.serialize_cdr(msg, msg.__msgtype__) if container == "rosbag2" else store.serialize_ros1(msg, msg.__msgtype__)
        w.write(conn, 1_000 + i, raw)
    w.close()
    reader = BagReader(path, messages=bag_messages())
    assert list(reader.batches()) == []
    assert reader.stats["skipped_topics"] == {"/chatter": "std_msgs/msg/Int32"}
    assert list(lidarpkt.open(path)) == []


@pytest.mark.parametrize("renamed", [(b"time stamp\nuint8[] data", b"time stsmp\nuint8[] data"),
                                     (b"VelodynePacket[] packets", b"VelodynePacket[] packetz")])
def test_ros1_bag_whose_own_definition_renames_a_field_is_a_capture_format_error(tmp_path, renamed):
    """Fuzzer `bags` (a ROS 1 bag whose connection header spelled NebulaPacket's ``stamp`` as ``stsmp``): a
    ROS 1 bag carries its own message definitions, rosbags decodes with them, and the packet extractor
    met a message without the field it reads: a raw AttributeError. The same for a VelodyneScan whose
    ``packets`` is renamed. Now the batches before, then a CaptureFormatError naming the topic and type."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from lidarpkt.containers.bags import BagReader

    from lidarpkt.vendors.registry import ros_definitions

    from lidarpkt.vendors.registry import bag_messages
    from lidarpkt.errors import CaptureFormatError

    store = get_typestore(Stores.ROS1_NOETIC)
    for name, text in ros_definitions().items():
        store.register(get_types_from_msg(text, name))
    T = store.types
    time = T["builtin_interfaces/msg/Time"](sec=1, nanosec=5)
    u8 = np.arange(1206, dtype=np.uint16).astype(np.uint8)
    msgs = [("/first", "velodyne_msgs/msg/VelodynePacket", T["velodyne_msgs/msg/VelodynePacket"](stamp=time, data=u8)),
            ("/velodyne_packets", "velodyne_msgs/msg/VelodyneScan", T["velodyne_msgs/msg/VelodyneScan"](
                header=T["std_msgs/msg/Header"](seq=0, stamp=time, frame_id="v"),
                packets=[T["velodyne_msgs/msg/VelodynePacket"](stamp=time, data=u8)])),
            ("/position", "nebula_msgs/msg/NebulaPacket", T["nebula_msgs/msg/NebulaPacket"](stamp=time, data=u8[:512]))]
    path = tmp_path / "b.bag"
    w = Writer(path)
    w.open()
    for i, (topic, typ, msg) in enumerate(msgs):
        w.write(w.add_connection(topic, typ, typestore=store), 1_000 + i, store.serialize_ros1(msg, typ))
    w.close()
    raw = path.read_bytes()
    assert raw.count(renamed[0]) >= 1
    path.write_bytes(raw.replace(*renamed))
    got = []
    with pytest.raises(CaptureFormatError, match="has not the fields lidarpkt reads") as caught:
        for b in BagReader(path, messages=bag_messages()).batches():
            got += [row.tobytes() for row in b.payload]
    assert got[0] == u8.tobytes()  # the packet before the damage
    assert caught.value is not None and _open_files_under(tmp_path) == []


def test_metadata_that_breaks_the_json_parser_is_a_metadata_error(tmp_path):
    """Found by the bags fuzzer's review (2026-11-21): deep nesting gave a raw RecursionError, a
    5000-digit number a raw ValueError, a NUL in a path a raw ValueError from the file system."""
    deep = "[" * 100_000 + "]" * 100_000  # nesting deeper than the parser's recursion limit
    huge = '{"lidar_mode": ' + "9" * 5000 + "}"  # an integer beyond Python's digit limit for str -> int
    for i, text in enumerate((deep, huge)):
        path = tmp_path / f"m{i}.json"
        path.write_text(text, encoding="utf-8")
        with pytest.raises(MetadataError, match="is not valid JSON"):
            load_metadata(path)
    with pytest.raises(MetadataError, match="is not valid JSON"):
        load_metadata(huge)  # JSON text rather than a path
    with pytest.raises(MetadataError, match="cannot read Ouster metadata file"):
        load_metadata("\x00metadata.json")  # not JSON text, so a path, with a NUL in it



def _mcap_with_second_chunk_replaced(path, compression: str, body: bytes, declared: int) -> list[bytes]:
    """Write to ``path`` the 30-packet VelodyneScan MCAP (zstd chunks of ~6 KB) with its second chunk
    record replaced by one holding ``body`` (compressed as ``compression``) that declares ``declared``
    uncompressed bytes; return the 30 payloads."""
    from lidarpkt import fixtures
    from lidarpkt.containers.pcap_reader import read_packets

    pk = [p for p in read_packets(fixtures.canned("vlp16-strongest")) if len(p.payload) == 1206][:30]
    raw = velodyne_scan_mcap([p.payload for p in pk], [p.timestamp_ns for p in pk], chunk_size=6_000)
    pos, chunks = 8, []
    while pos + 9 <= len(raw) - 8:  # records: opcode, u64 length, body
        length = int.from_bytes(raw[pos + 1 : pos + 9], "little")
        if raw[pos] == 0x06:
            chunks.append((pos, 9 + length))
        pos += 9 + length
    assert len(chunks) >= 3
    at, length = chunks[1]
    name = compression.encode()
    fields = (raw[at + 9 : at + 25] + declared.to_bytes(8, "little") + bytes(4) + len(name).to_bytes(4, "little")
              + name + len(body).to_bytes(8, "little") + body)  # start/end times kept, crc 0
    path.write_bytes(raw[:at] + bytes([0x06]) + len(fields).to_bytes(8, "little") + fields + raw[at + length :])
    return [p.payload for p in pk]


def _zero_bomb(compression: str, size: int) -> bytes:
    """``size`` zero bytes compressed (a few KB), the zstd frame header naming ``size``."""
    block = bytes(1 << 20)
    if compression == "zstd":
        import zstandard

        obj = zstandard.ZstdCompressor(write_content_size=True).compressobj(size=size)
        return b"".join(obj.compress(block) for _ in range(size >> 20)) + obj.flush()
    import lz4.frame

    comp = lz4.frame.LZ4FrameCompressor()
    return comp.begin(source_size=size) + b"".join(comp.compress(block) for _ in range(size >> 20)) + comp.flush()


_READ_AND_REPORT_PEAK = r"""
import sys, warnings
from lidarpkt.containers.bags import BagReader
from lidarpkt.vendors.registry import bag_messages
from lidarpkt.errors import LidarpktError
n, outcome = 0, "ok"
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    try:
        for b in BagReader(sys.argv[1], messages=bag_messages()).batches():
            n += len(b)
    except LidarpktError as exc:
        outcome = type(exc).__name__
outcome = outcome if outcome != "ok" or not caught else type(caught[-1].message).__name__
hwm = next(l.split()[1] for l in open('/proc/self/status') if l.startswith('VmHWM'))
print(n, outcome, int(hwm) // 1024)
"""


@pytest.mark.parametrize("compression", ["zstd", "lz4"])
def test_mcap_chunk_that_inflates_past_its_declared_size_is_not_inflated(tmp_path, compression):
    """Found reading the bags fuzzer's report (2026-11-21): the mcap library inflates a zstd chunk into
    the size its zstd frame header names and an lz4 chunk without any limit, so a 512 MB zero "bomb"
    of a few KB in a chunk declaring 1000 bytes took over 512 MB. Now a chunk inflates into at most
    what it declares: the packets of the first chunk, a TruncatedCaptureWarning, and a small peak."""
    bomb = _zero_bomb(compression, 512 << 20)
    assert len(bomb) < 4 << 20
    path = tmp_path / "bomb.mcap"
    _mcap_with_second_chunk_replaced(path, compression, bomb, declared=1000)
    res = subprocess.run([sys.executable, "-c", _READ_AND_REPORT_PEAK, str(path)], capture_output=True, text=True,
                         timeout=120, cwd=Path(__file__).resolve().parents[2])
    assert res.returncode == 0, res.stderr[-2000:]
    n, outcome, peak_mb = res.stdout.split()
    assert 0 < int(n) < 30 and outcome == "TruncatedCaptureWarning"
    assert int(peak_mb) < 300, f"peak RSS {peak_mb} MB while reading a chunk that declares 1000 bytes"


def test_mcap_chunk_declaring_more_than_the_limit_is_a_capture_format_error(tmp_path):
    from lidarpkt.containers.bags import BagReader
    from lidarpkt.vendors.registry import bag_messages
    from lidarpkt.containers.mcap_records import MAX_MCAP_CHUNK_BYTES
    from lidarpkt.errors import CaptureFormatError

    path = tmp_path / "big.mcap"
    payloads = _mcap_with_second_chunk_replaced(path, "zstd", b"\x28\xb5\x2f\xfd", declared=MAX_MCAP_CHUNK_BYTES + 1)
    got = []
    with pytest.raises(CaptureFormatError, match="MiB"):
        for b in BagReader(path, messages=bag_messages()).batches():
            got += [row.tobytes() for row in b.payload]
    assert 0 < len(got) < len(payloads) and got == payloads[: len(got)]
