"""The MCAP records lidarpkt writes (:mod:`lidarpkt.writers.mcap.chunks`): the ``mcap`` library's file, byte for
byte, whatever pieces the messages come in."""

from __future__ import annotations

import io

import numpy as np
import pytest

from lidarpkt.writers.mcap.chunks import ChunkWriter

mcap_writer = pytest.importorskip("mcap.writer")
mcap_reader = pytest.importorskip("mcap.reader")


def _write(w, messages, *, pieces: bool) -> None:
    """Schemas, channels registered mid-file, metadata between messages, a flush, out-of-order log times."""
    w.start(profile="ros2", library="lidarpkt test")
    schema = w.register_schema("std_msgs/msg/Int32", "ros2msg", b"int32 data")
    a = w.register_channel("/a", "cdr", schema, {"offered_qos_profiles": ""})
    w.add_metadata("first", {"k": "v"})
    b = None
    for i, data in enumerate(messages):
        if i == 5:
            b = w.register_channel("/b", "cdr", schema, {})
        channel = b if b is not None and i % 3 == 0 else a
        given = [data[:7], memoryview(data)[7:]] if pieces else data
        w.add_message(channel, log_time=1000 + (i * 7919) % 500, data=given, publish_time=5 + i)
        if i == 150:
            w.add_metadata("second", {"k": "w"})
            w.flush()
    w.finish()


@pytest.mark.parametrize("compression", ["", "zstd", "lz4"])
def test_chunk_writer_writes_the_mcap_librarys_bytes(tmp_path, compression):
    if compression == "lz4":
        pytest.importorskip("lz4.frame")
    rng = np.random.default_rng(0)
    messages = [rng.integers(0, 255, int(rng.integers(8, 20000)), dtype=np.uint8).tobytes() for _ in range(300)]
    ref = io.BytesIO()
    kind = {"": mcap_writer.CompressionType.NONE, "zstd": mcap_writer.CompressionType.ZSTD,
            "lz4": mcap_writer.CompressionType.LZ4}[compression]
    _write(mcap_writer.Writer(ref, chunk_size=100_000, compression=kind, index_types=mcap_writer.IndexType.ALL,
                              enable_crcs=True), messages, pieces=False)
    path = tmp_path / "ours.mcap"
    with open(path, "wb", buffering=0) as fh:
        _write(ChunkWriter(fh, chunk_size=100_000, compression=compression), messages, pieces=True)
    assert path.read_bytes() == ref.getvalue()
    with open(path, "rb") as fh:
        reader = mcap_reader.make_reader(fh, validate_crcs=True)
        got = [m.data for _, _, m in reader.iter_messages(log_time_order=False)]
    assert got == messages


def test_pointcloud_cdr_pieces_are_the_encoded_message():
    from lidarpkt.containers import rosmsgs
    from lidarpkt.writers.mcap import schemas
    from lidarpkt.writers.mcap.pointcloud import point_fields, pointcloud_cdr

    pc2 = rosmsgs.typestore().types[schemas.POINTCLOUD2]
    for n, dense in ((0, True), (28 * 7, False), (28 * 7 * 3, True)):
        data = np.arange(n, dtype=np.uint8)
        msg = pc2(header=rosmsgs.header(1_700_000_000_123_456_789, "velodyne"), height=n // (28 * 7), width=7,
                  fields=point_fields(), is_bigendian=False, point_step=28, row_step=28 * 7, data=data, is_dense=dense)
        head, points, tail = pointcloud_cdr(msg)
        assert points is data
        assert head + points.tobytes() + tail == rosmsgs.encode(schemas.POINTCLOUD2, msg)


def _chunk_crcs(path) -> list[int]:
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    with open(path, "rb") as fh:
        return [r.uncompressed_crc for r in StreamReader(fh, emit_chunks=True).records if isinstance(r, Chunk)]


def test_decoded_frames_chunks_carry_no_crc_and_packets_alone_do(tmp_path):
    """A decode's file of frames: chunk CRCs 0 ("not computed"), which the official reader accepts while
    checking; of packets alone: every chunk's CRC, checked."""
    from conftest import external
    from lidarpkt.cli import main

    cap = external("rust-lidar-utils/velodyne_vlp16.pcap")
    for topics, computed in (("packets,points", False), ("packets", True)):
        out = tmp_path / f"{topics.replace(',', '_')}.mcap"
        assert main(["decode", str(cap), "-o", str(out), "--topics", topics, "-q"]) == 0
        crcs = _chunk_crcs(out)
        assert crcs and all(crcs) if computed else set(crcs) == {0}
        with open(out, "rb") as fh:
            reader = mcap_reader.make_reader(fh, validate_crcs=True)
            count = reader.get_summary().statistics.message_count
            assert count > 0 and sum(1 for _ in reader.iter_messages()) == count
