"""ROS bag input: the real nebula rosbag2 (sqlite3), and MCAP / ROS 1 bags written by other libraries."""

from __future__ import annotations

import sqlite3

import numpy as np
import pytest

import lidarpkt
from lidarpkt.containers.bags import BagReader
from lidarpkt.vendors.registry import bag_messages
from lidarpkt.errors import CaptureFormatError, LidarpktError, LidarpktWarning
from lidarpkt.core.packet import PacketBatch
from lidarpkt.vendors.velodyne import VelodyneDecoder, decode_packets, encode_data_packets
from reference_tools import velodyne_scan_mcap

NEBULA = "nebula/vlp16/1673400471837873222"


def _payloads_from_sqlite(db) -> list[tuple[int, list[tuple[int, bytes]]]]:
    """The packets of each message, located with the layout SOURCES.md documents (no CDR library)."""
    out = []
    with sqlite3.connect(db) as con:
        for (data,) in con.execute("SELECT data FROM messages ORDER BY timestamp"):
            assert data[:4] == b"\x00\x01\x00\x00"
            body = data[4:]
            pos = 8
            n = int.from_bytes(body[pos:pos + 4], "little")
            pos += 4 + n
            pos += -pos % 4
            count = int.from_bytes(body[pos:pos + 4], "little")
            pos += 4
            packets = []
            for _ in range(count):
                pos += -pos % 4
                sec = int.from_bytes(body[pos:pos + 4], "little", signed=True)
                nsec = int.from_bytes(body[pos + 4:pos + 8], "little")
                packets.append((sec * 10**9 + nsec, bytes(body[pos + 8:pos + 8 + 1206])))
                pos += 8 + 1206
            out.append((count, packets))
    return out


def test_nebula_bag_packets_are_the_stored_bytes(ext):
    expected = _payloads_from_sqlite(ext(NEBULA + "/1673400471837873222_0.db3"))
    assert [c for c, _ in expected] == [151, 151, 151, 150]
    reader = BagReader(ext(NEBULA), messages=bag_messages())
    batches = list(reader.batches())
    assert [len(b) for b in batches] == [151, 151, 151, 150]
    for batch, (_, packets) in zip(batches, expected):
        assert batch.src is None and batch.dst is None and batch.payload_size == 1206
        assert batch.timestamp_ns.tolist() == [t for t, _ in packets]
        assert [row.tobytes() for row in batch.payload] == [p for _, p in packets]
    assert np.concatenate([b.index for b in batches]).tolist() == list(range(603))
    assert reader.stats["packets"] == 603


def test_nebula_bag_opens_by_directory_or_db3_and_decodes_dual(ext):
    by_dir = list(lidarpkt.open(ext(NEBULA)))
    by_db3 = list(lidarpkt.open(ext(NEBULA + "/1673400471837873222_0.db3")))
    assert len(by_dir) == len(by_db3) == 5  # 4 messages ≈ 4 rotations, cut at the wrap
    for a, b in zip(by_dir, by_db3):
        np.testing.assert_array_equal(a.range_mm, b.range_mm)
    f = by_dir[2]
    assert not f.partial and f.return_labels == ("last", "strongest") and f.shape[:2] == (2, 16)
    # about 98 % of the return pairs are identical (SOURCES.md)
    both = (f.range_mm[0] > 0) | (f.range_mm[1] > 0)
    same = (f.range_mm[0] == f.range_mm[1]) & both
    assert 0.95 < same.sum() / both.sum() < 1.0
    # this sensor had no GPS: its hour-relative clock is 25.5 min off the recorder's, so the
    # hour comes from the packet stamps (nearest hour) and the times stay within 30 min of them
    assert abs(f.timestamp_ns - 1673400471_900_000_000) < 1_800_000_000_000
    starts = [g.timestamp_ns for g in by_dir[1:4]]
    assert np.allclose(np.diff(starts), 100_000_000, rtol=0.02)  # 10 Hz


@pytest.mark.parametrize("bag, packets", [
    ("nebula/vls128/1614315746471294674", 2193),  # serialization_format: "" (rosbag2 of 2020)
    ("nebula/hesai/qt128/1730273789074637152", None),  # storage_identifier: ""
])
def test_old_rosbag2_metadata_with_empty_fields_opens_with_the_evident_default(ext, bag, packets, tmp_path,
                                                                             monkeypatch):
    import glob
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # this test's own: other workers make their own copies
    before = set(glob.glob(f"{tempfile.gettempdir()}/lidarpkt-bag-*"))
    reader = BagReader(ext(bag), messages=bag_messages())
    with pytest.warns(LidarpktWarning, match="metadata.yaml names no") as said:
        batches = list(reader.batches())
    assert len([w for w in said if "metadata.yaml" in str(w.message)]) == 1  # said once
    assert reader.stats["messages"] > 0 or reader.stats["skipped_topics"]  # the storage was opened and read
    if packets is not None:
        assert sum(len(b) for b in batches) == reader.stats["packets"] == packets
    assert set(glob.glob(f"{tempfile.gettempdir()}/lidarpkt-bag-*")) == before  # the completed copy is gone


def test_empty_storage_and_format_fields_are_filled_from_the_files(tmp_path, ext):
    """The same bag with both fields emptied reads exactly as the original."""
    import shutil

    src = ext(NEBULA)
    bag = tmp_path / "bag"
    shutil.copytree(src, bag)
    meta = (bag / "metadata.yaml").read_text()
    meta = meta.replace("storage_identifier: sqlite3", 'storage_identifier: ""')
    meta = meta.replace("serialization_format: cdr", "serialization_format: ''")
    (bag / "metadata.yaml").write_text(meta)
    with pytest.warns(LidarpktWarning, match="no storage plugin .*sqlite3.*no serialization format"):
        got = list(BagReader(bag, messages=bag_messages()).batches())
    want = list(BagReader(src, messages=bag_messages()).batches())
    assert [b.payload.tobytes() for b in got] == [b.payload.tobytes() for b in want]
    assert [b.timestamp_ns.tolist() for b in got] == [b.timestamp_ns.tolist() for b in want]
    (bag / "1673400471837873222_0.db3").write_bytes(b"neither sqlite nor mcap" * 4)
    with pytest.raises(CaptureFormatError, match="Storage plugin"):  # nothing to infer: rosbags says what is missing
        list(BagReader(bag, messages=bag_messages()).batches())


def _dual_payloads(n: int = 60) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(5)
    t_us = 500_000 + np.rint(np.arange(n) * 663.552).astype(np.int64)
    az = (np.repeat(np.arange(6) * 40, 2)[None, :] + np.arange(n)[:, None] * 240) % 36000
    dist = rng.integers(0, 30000, size=(n, 12, 32))
    dist[:, 1::2] = np.where(rng.random((n, 6, 32)) < 0.9, dist[:, 0::2], dist[:, 1::2])
    refl = rng.integers(0, 256, size=(n, 12, 32))
    payload = encode_data_packets(az, dist, refl, t_us, "dual")
    host = 1_700_000_000_000_000_000 + t_us * 1000
    return payload, host


def test_mcap_written_by_mcap_ros2(tmp_path):
    payload, host = _dual_payloads()
    path = tmp_path / "scan.mcap"
    path.write_bytes(velodyne_scan_mcap(payload, host, packets_per_message=20, frame_id="velodyne"))
    batch = PacketBatch.concatenate(list(BagReader(path, messages=bag_messages()).batches()))
    np.testing.assert_array_equal(batch.payload, payload)
    np.testing.assert_array_equal(batch.timestamp_ns, host)
    frames = list(lidarpkt.open(path))
    dec = VelodyneDecoder()
    direct = dec.push(PacketBatch.from_payloads(payload, host)) + dec.finish()
    assert len(frames) == len(direct)
    for a, b in zip(frames, direct):
        np.testing.assert_array_equal(a.range_mm, b.range_mm)
        np.testing.assert_array_equal(a.column_timestamp_ns, b.column_timestamp_ns)


def test_ros1_bag_written_by_rosbags(tmp_path):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore, get_types_from_msg

    from lidarpkt.vendors.registry import ros_definitions

    store = get_typestore(Stores.ROS1_NOETIC)
    types = {}
    for name, text in ros_definitions().items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    Scan = store.types["velodyne_msgs/msg/VelodyneScan"]
    Packet = store.types["velodyne_msgs/msg/VelodynePacket"]
    Time = store.types["builtin_interfaces/msg/Time"]
    Header = store.types["std_msgs/msg/Header"]
    payload, host = _dual_payloads(40)
    path = tmp_path / "scan.bag"
    with Writer(path) as w:
        conn = w.add_connection("/velodyne_packets", "velodyne_msgs/msg/VelodyneScan", typestore=store)
        for start in (0, 20):
            pk = [Packet(stamp=Time(sec=int(host[i] // 10**9), nanosec=int(host[i] % 10**9)), data=payload[i].copy())
                  for i in range(start, start + 20)]
            msg = Scan(header=Header(seq=start, stamp=pk[0].stamp, frame_id="velodyne"), packets=pk)
            w.write(conn, int(host[start + 19]), store.serialize_ros1(msg, "velodyne_msgs/msg/VelodyneScan"))
    batch = PacketBatch.concatenate(list(BagReader(path, messages=bag_messages()).batches()))
    np.testing.assert_array_equal(batch.payload, payload)
    np.testing.assert_array_equal(batch.timestamp_ns, host)
    assert decode_packets(batch.payload).return_mode.tolist() == [0x39] * 40
    frames = list(lidarpkt.open(path))
    assert sum(int(f.column_valid.sum()) for f in frames) == 40 * 12


def test_unreadable_bag_is_a_library_error(tmp_path):
    bad = tmp_path / "broken.bag"
    bad.write_bytes(b"#ROSBAG V2.0\n" + b"\x00" * 40)
    with pytest.raises(LidarpktError):
        list(BagReader(bad, messages=bag_messages()).batches())
    fake = tmp_path / "fake.db3"
    fake.write_bytes(b"SQLite format 3\x00" + b"\x00" * 100)
    with pytest.raises(CaptureFormatError):
        list(BagReader(fake, messages=bag_messages()).batches())


def test_truncated_mcap_gives_what_it_holds_then_a_warning(tmp_path):
    payload, host = _dual_payloads(60)
    path = tmp_path / "scan.mcap"
    path.write_bytes(velodyne_scan_mcap(payload, host, chunk_size=20_000))
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    # a plain MCAP cut short (a killed recorder) yields what it holds, then warns
    from lidarpkt.errors import TruncatedCaptureWarning

    with pytest.warns(TruncatedCaptureWarning):
        got = list(BagReader(cut, messages=bag_messages()).batches())
    assert 0 < len(got) < 60
    # whatever came out before the damage is intact
    for b in got:
        i = int(np.flatnonzero(host == b.timestamp_ns[0])[0])
        np.testing.assert_array_equal(b.payload[0], payload[i])


def test_damaged_rosbag2_gives_what_it_holds_then_a_clear_error(tmp_path, ext):
    import shutil

    bag = tmp_path / "bag"
    shutil.copytree(ext(NEBULA), bag)
    db = bag / "1673400471837873222_0.db3"
    data = bytearray(db.read_bytes())
    # overwrite the tail of the file (the pages of the last messages) with garbage
    data[len(data) // 2:] = b"\xa5" * (len(data) - len(data) // 2)
    db.write_bytes(bytes(data))
    got = []
    with pytest.raises(LidarpktError):
        for b in BagReader(bag, messages=bag_messages()).batches():
            got.append(b)
    expected = _payloads_from_sqlite(ext(NEBULA + "/1673400471837873222_0.db3"))
    for b, (_, packets) in zip(got, expected):
        assert [row.tobytes() for row in b.payload] == [p for _, p in packets]
