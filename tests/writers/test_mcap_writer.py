"""MCAP output checked with the official readers (``mcap`` + ``mcap_ros2``), rosbags and real captures."""

from __future__ import annotations

import json
import sqlite3
import subprocess
import sys
import warnings

import numpy as np
import pytest

import lidarpkt
from lidarpkt.errors import DiskFullError, TruncatedCaptureWarning
from lidarpkt.containers.pcap_reader import read_packets
from lidarpkt.writers.mcap import schemas
from lidarpkt.vendors.velodyne import ros as vros
from lidarpkt.vendors.ouster import ros as oros
from lidarpkt.containers import rosmsgs
from lidarpkt.writers.mcap.writer import McapWriter
from conftest import external

mcap_reader = pytest.importorskip("mcap.reader")
mcap_ros2_decoder = pytest.importorskip("mcap_ros2.decoder")

VLP = "rust-lidar-utils/velodyne_vlp16.pcap"  # data + position packets
OS1 = "ouster-sdk/OS-1-64_1024x10_fw20.pcap"  # legacy OS1-64, lidar + IMU
OS1_JSON = "ouster-sdk/OS-1-64_sensor_config_reduced.json"


def _encode(msgtype, message):
    return rosmsgs.encode(msgtype, message, schemas.typestore())


def _official(path):
    """(summary, metadata records, decoded messages) through the official readers."""
    with open(path, "rb") as fh:
        reader = mcap_reader.make_reader(fh, decoder_factories=[mcap_ros2_decoder.DecoderFactory()])
        summary = reader.get_summary()
        meta = list(reader.iter_metadata())
        msgs = [(ch.topic, m.log_time, dec) for _, ch, m, dec in reader.iter_decoded_messages(log_time_order=False)]
    return summary, meta, msgs


def _decode(tmp_path, *args):
    out = tmp_path / "out.mcap"
    rc = subprocess.run([sys.executable, "-m", "lidarpkt", "decode", *map(str, args), "-o", str(out), "-q"],
                        capture_output=True, text=True, timeout=120)
    assert rc.returncode == 0, rc.stderr
    return out


# ---------------------------------------------------------------------------- CDR codecs
def test_velodyne_scan_codec_matches_rosbags_and_the_official_decoder():
    store = schemas.typestore()
    pkt, scan = store.types["velodyne_msgs/msg/VelodynePacket"], store.types[vros.VELODYNE_SCAN]
    rng = np.random.default_rng(1)
    for n in (0, 1, 2, 151):
        payload = rng.integers(0, 256, (n, 1206), dtype=np.uint8)
        host = rng.integers(0, 2**31 * 10**9, n)
        ref = _encode(vros.VELODYNE_SCAN, scan(
            header=rosmsgs.header(1_673_400_471_837_873_222, "velodyne", schemas.typestore()),
            packets=[pkt(stamp=rosmsgs.ros_time(t, schemas.typestore()), data=p) for t, p in zip(host, payload)]))
        ours = vros.encode_velodyne_scan(payload, host, 1_673_400_471_837_873_222)
        assert ours == ref
        stamp, frame_id, host2, payload2 = vros.decode_velodyne_scan(ours)
        assert (stamp, frame_id) == (1_673_400_471_837_873_222, "velodyne")
        assert np.array_equal(host2, host) and np.array_equal(payload2, payload)
    from mcap_ros2._dynamic import generate_dynamic

    msg = generate_dynamic(vros.VELODYNE_SCAN, schemas.schema_text(vros.VELODYNE_SCAN))[vros.VELODYNE_SCAN](ours)
    assert [bytes(p.data) for p in msg.packets] == [p.tobytes() for p in payload]
    assert [p.stamp.sec * 10**9 + p.stamp.nanosec for p in msg.packets] == host.tolist()


def test_velodyne_scan_decoder_reads_the_real_nebula_bag_blobs():
    """Third-party CDR (tier4/nebula rosbag2): our decoder gives what rosbags gives, and our
    encoder writes the same bytes (nebula's blobs end with 2 alignment bytes we do not write)."""
    db = external("nebula/vlp16/1673400471837873222/1673400471837873222_0.db3")
    with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as con:
        blobs = [bytes(r[0]) for r in con.execute("select data from messages order by id")]
    assert [len(b) for b in blobs]
    for blob in blobs:
        stamp, frame_id, host, payload = vros.decode_velodyne_scan(blob)
        ref = schemas.decode(vros.VELODYNE_SCAN, blob)
        assert frame_id == ref.header.frame_id == "velodyne"
        assert stamp == ref.header.stamp.sec * 10**9 + ref.header.stamp.nanosec
        assert np.array_equal(payload, np.stack([p.data for p in ref.packets]))
        assert host.tolist() == [p.stamp.sec * 10**9 + p.stamp.nanosec for p in ref.packets]
        assert vros.encode_velodyne_scan(payload, host, stamp, frame_id) == blob[:-2]


def test_packet_msg_and_stamped_packet_codecs_match_rosbags():
    store = schemas.typestore()
    payload = bytes(range(256)) * 49 + b"xyz"
    ref = _encode(oros.PACKET_MSG, store.types[oros.PACKET_MSG](buf=np.frombuffer(payload, np.uint8)))
    assert oros.encode_packet_msg(payload) == ref
    assert oros.decode_packet_msg(ref) == payload
    t = 1_415_145_600_123_456_789
    ref = _encode(rosmsgs.STAMPED_PACKET, store.types[rosmsgs.STAMPED_PACKET](
        stamp=rosmsgs.ros_time(t, schemas.typestore()), data=np.frombuffer(payload[:512], np.uint8)))
    assert rosmsgs.encode_stamped_packet(payload[:512], t) == ref
    assert rosmsgs.decode_stamped_packet(ref) == (t, payload[:512])


# ------------------------------------------------------------------------ raw packet files
def test_vlp16_pcap_to_mcap_is_lossless_with_the_official_readers(tmp_path):
    pcap = external(VLP)
    out = _decode(tmp_path, pcap, "--topics", "packets")
    summary, meta, msgs = _official(out)
    packets = list(read_packets(pcap))
    data = [p for p in packets if len(p.payload) == 1206]
    position = [p for p in packets if len(p.payload) == 512]
    # data packets: one VelodyneScan per rotation, every packet with its host time, in order
    scans = [m for t, _, m in msgs if t == "/velodyne_packets"]
    assert len(scans) == 2  # SOURCES.md: about 1.1 rotations, one wrap
    got = [(p.stamp.sec * 10**9 + p.stamp.nanosec, bytes(p.data)) for s in scans for p in s.packets]
    assert got == [(p.timestamp_ns, p.payload) for p in data]
    # header.stamp = sensor time: µs past the hour of the first packet, in the capture's hour
    first = scans[0].packets[0]
    toh_us = int.from_bytes(bytes(first.data)[1200:1204], "little")
    stamp = scans[0].header.stamp.sec * 10**9 + scans[0].header.stamp.nanosec
    assert stamp % 3_600_000_000_000 == toh_us * 1000 and abs(stamp - data[0].timestamp_ns) < 1_800 * 10**9
    pos = [(lt, m) for t, lt, m in msgs if t == "/velodyne_position_packets"]
    assert [(lt, bytes(m.data)) for lt, m in pos] == [(p.timestamp_ns, p.payload) for p in position]
    # profile, encodings, QoS, compression, index, metadata record
    assert summary.statistics.message_count == len(msgs)
    assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
    assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
    assert all("reliability: 2" in c.metadata["offered_qos_profiles"] for c in summary.channels.values())
    assert summary.chunk_indexes and {ci.compression for ci in summary.chunk_indexes} == {"zstd"}
    sensor = [m.metadata for m in meta if m.name == "lidarpkt.sensor"]
    assert sensor and sensor[0]["return_mode"] == "strongest" and sensor[0]["vendor"] == "velodyne"
    with open(out, "rb") as fh:
        assert mcap_reader.make_reader(fh).get_header().profile == "ros2"


def test_ouster_pcap_to_mcap_keeps_lidar_imu_and_metadata(tmp_path):
    pcap, meta_json = external(OS1), external(OS1_JSON)
    out = _decode(tmp_path, pcap, "--metadata", meta_json, "--topics", "packets")
    summary, meta, msgs = _official(out)
    packets = list(read_packets(pcap))
    for topic, size in (("/ouster/lidar_packets", 12608), ("/ouster/imu_packets", 48)):
        got = [(lt, bytes(m.buf)) for t, lt, m in msgs if t == topic]
        assert got == [(p.timestamp_ns, p.payload) for p in packets if len(p.payload) == size]
    (text,) = [m.data for t, _, m in msgs if t == "/ouster/metadata"]
    assert json.loads(text) == json.loads(meta_json.read_text())
    qos = {c.topic: c.metadata["offered_qos_profiles"] for c in summary.channels.values()}
    assert "durability: 1" in qos["/ouster/metadata"]  # latched, like ouster-ros
    assert any(m.name == "lidarpkt.sensor" and json.loads(m.metadata["metadata_json"]) for m in meta)


@pytest.mark.parametrize("capture, meta", [
    (VLP, None),
    ("veloview/vlp-16-test-90deg-1-50-frames.pcap", None),
    ("nebula/vlp16/1673400471837873222", None),  # the real dual-return rosbag2
    (OS1, OS1_JSON),
])
def test_frames_from_recorded_mcap_equal_frames_from_the_pcap(tmp_path, capture, meta):
    pcap = external(capture)
    args = [pcap, "--topics", "packets"] + (["--metadata", external(meta)] if meta else [])
    out = _decode(tmp_path, *args)
    direct = list(lidarpkt.open(pcap, metadata=external(meta) if meta else None))
    again = list(lidarpkt.open(out))  # the Ouster metadata comes from the file itself
    assert len(again) == len(direct) > 0
    for a, b in zip(direct, again):
        assert a.frame_id == b.frame_id and a.partial == b.partial
        for name in ("range_mm", "reflectivity", "column_valid", "column_timestamp_ns", "azimuth_deg",
                     "signal", "near_ir", "measurement_id", "status"):
            x, y = getattr(a, name), getattr(b, name)
            assert (x is None and y is None) or np.array_equal(x, y), name


# -------------------------------------------------------------------------- frames as messages
@pytest.mark.parametrize("capture, meta", [(VLP, None), (OS1, OS1_JSON)])
def test_pointcloud2_decodes_to_frame_xyz(tmp_path, capture, meta):
    pcap = external(capture)
    out = _decode(tmp_path, pcap, "--topics", "points,images", *(["--metadata", external(meta)] if meta else []))
    _, _, msgs = _official(out)
    frames = list(lidarpkt.open(pcap, metadata=external(meta) if meta else None))
    clouds = [m for t, _, m in msgs if t in ("/velodyne_points", "/ouster/points")]
    assert len(clouds) == len(frames)
    for frame, pc in zip(frames, clouds):
        r, h, w = frame.shape
        assert (pc.height, pc.width) == (h, w)
        names = [f.name for f in pc.fields]
        assert names[:3] == ["x", "y", "z"] and {"intensity", "ring", "time", "range"} <= set(names)
        # decode with the PointField offsets/datatypes the message declares (not our dtype)
        np_types = {7: "<f4", 4: "<u2", 6: "<u4", 2: "u1"}
        dt = np.dtype({"names": names, "formats": [np_types[f.datatype] for f in pc.fields],
                       "offsets": [f.offset for f in pc.fields], "itemsize": pc.point_step})
        pts = np.frombuffer(bytes(pc.data), dt).reshape(h, w)
        xyz = frame.xyz()[0]
        rng = frame.range_mm[0]
        if frame.sensor.vendor == "ouster":  # clouds are destaggered, as ouster-ros publishes them
            xyz = np.moveaxis(frame.destaggered(np.moveaxis(xyz, -1, 0)), 0, -1)
            rng = frame.destaggered(rng)
        got = np.stack([pts["x"], pts["y"], pts["z"]], axis=-1)
        # pixels without a return are NaN (ROS organised-cloud convention), not points at the origin
        no_return = rng == 0
        if frame.sensor.vendor == "ouster":
            no_return |= ~frame.destaggered(np.broadcast_to(frame.column_valid, rng.shape))
        else:
            no_return |= ~frame.column_valid[None, :]
        np.testing.assert_array_equal(got, np.where(no_return[..., None], np.nan, xyz).astype(np.float32))
        assert pc.is_dense == (not no_return.any())
        assert np.array_equal(pts["range"], rng)
        assert pc.header.stamp.sec * 10**9 + pc.header.stamp.nanosec == frame.timestamp_ns
        # time: seconds after header.stamp of each pixel's firing (column time + firing offset)
        t_ns = np.where(frame.column_valid, frame.column_timestamp_ns - frame.timestamp_ns, 0)[None, :]
        if frame.pixel_time_offset_ns is not None:
            t_ns = t_ns + frame.pixel_time_offset_ns
        t_ns = np.broadcast_to(t_ns, (h, w))
        if frame.sensor.vendor == "ouster":
            t_ns = frame.destaggered(t_ns)
        np.testing.assert_allclose(pts["time"], t_ns * 1e-9, rtol=1e-6, atol=1e-9)
        assert pts["time"].min() >= 0 and pts["time"].max() < 0.2  # within one rotation
        rings = pts["ring"][:, 0].tolist()
        assert rings == (list(range(15, -1, -1)) if frame.sensor.vendor == "velodyne" else list(range(h)))
    images = [m for t, _, m in msgs if t.endswith("/range_image")]
    assert len(images) == len(frames) and images[0].encoding == "32FC1"


# ------------------------------------------------------------------------ chunks, kill, rotation
class _Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def test_chunks_close_by_time_and_a_cut_file_reads_back_up_to_its_last_chunk(tmp_path):
    clock = _Clock()
    path = tmp_path / "cut.mcap"
    w = McapWriter(path, chunk_seconds=0.5, clock=clock)
    sizes = []
    for i in range(103):
        w.write(oros.LIDAR_TOPIC, oros.encode_packet_msg(bytes([i]) * 1000), 1_000 + i)
        clock.t += 0.125  # 8 messages a second (binary-exact steps)
        sizes.append(path.stat().st_size)
    # every 0.5 s of messages reached the file without close(): as after a SIGKILL
    data = path.read_bytes()
    assert len(set(sizes)) >= 20  # a chunk closes once it spans 0.5 s: every 5 messages
    (tmp_path / "killed.mcap").write_bytes(data)
    w.close()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        from lidarpkt.containers.bags import BagReader
        from lidarpkt.vendors.registry import bag_messages

        batches = list(BagReader(tmp_path / "killed.mcap", messages=bag_messages()).batches())
    got = [b.payload[0].tobytes() for b in batches]
    assert len(got) == 100 and got == [bytes([i]) * 1000 for i in range(len(got))]
    assert not caught or issubclass(caught[0].category, TruncatedCaptureWarning)
    # cut inside a chunk: a warning, and everything before the damage
    (tmp_path / "torn.mcap").write_bytes(data[: len(data) * 2 // 3])
    with pytest.warns(TruncatedCaptureWarning, match="cut short"):
        torn = list(BagReader(tmp_path / "torn.mcap", messages=bag_messages()).batches())
    assert [b.payload[0].tobytes() for b in torn] == got[: len(torn)] and len(torn) > 40
    # the closed file is complete: summary with one chunk index per chunk
    summary, _, msgs = _official(path)
    assert len(msgs) == 103 and len(summary.chunk_indexes) == 21


def test_rotation_by_size_gives_complete_files_each_with_the_metadata(tmp_path):
    clock = _Clock()
    w = McapWriter(tmp_path / "rot.mcap", chunk_seconds=0.2, rotate_bytes=20_000, clock=clock)
    w.add_metadata("lidarpkt.sensor", {"vendor": "ouster"})
    w.write_latched(oros.METADATA_TOPIC, _encode(
        rosmsgs.STRING, schemas.typestore().types[rosmsgs.STRING](data="{}")), 1)
    for i in range(200):
        w.write(oros.LIDAR_TOPIC, oros.encode_packet_msg(np.random.default_rng(i).bytes(1000)), 10 + i)
        clock.t += 0.05
    w.close()
    assert len(w.files) >= 3 and [f.name for f in w.files][:2] == ["rot_0000.mcap", "rot_0001.mcap"]
    total = 0
    for f in w.files:
        summary, meta, msgs = _official(f)
        assert [m.name for m in meta] == ["lidarpkt.sensor"]
        assert msgs[0][0] == "/ouster/metadata"
        total += sum(1 for t, _, _ in msgs if t == "/ouster/lidar_packets")
    assert total == 200


def test_rotated_files_start_with_every_sensors_latched_messages(tmp_path):
    """Two sensors' /ouster/metadata and /tf_static: every rotated file starts with both of each
    (keyed by sensor); a later message of the same key replaces the earlier one."""
    clock = _Clock()
    w = McapWriter(tmp_path / "rot.mcap", chunk_seconds=0.2, rotate_bytes=20_000, clock=clock)
    string = schemas.typestore().types[rosmsgs.STRING]
    for key, text in (("A", '{"sensor": "A"}'), ("B", '{"sensor": "B"}'), ("A", '{"sensor": "A2"}')):
        w.write_latched(oros.METADATA_TOPIC, _encode(rosmsgs.STRING, string(data=text)), 1, key=key)
    for i in range(200):
        w.write(oros.LIDAR_TOPIC, oros.encode_packet_msg(np.random.default_rng(i).bytes(1000)), 10 + i)
        clock.t += 0.05
    w.close()
    assert len(w.files) >= 3
    for f in w.files[1:]:
        _, _, msgs = _official(f)
        head = [m.data for t, _, m in msgs if t == "/ouster/metadata"]
        assert head == ['{"sensor": "B"}', '{"sensor": "A2"}'] or head == ['{"sensor": "A2"}', '{"sensor": "B"}']


def test_disk_full_is_a_clear_error_and_the_file_stays_readable(tmp_path):
    mnt = tmp_path / "small"
    mnt.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(mnt)],
                      capture_output=True).returncode != 0:
        pytest.skip("cannot mount a small tmpfs here (needs root) to fill a disk")
    try:
        w = McapWriter(mnt / "full.mcap", chunk_seconds=0.0, compression="none")
        rng = np.random.default_rng(0)
        with pytest.raises(DiskFullError, match="no space left.*readable up to its last complete chunk"):
            for i in range(1000):
                w.write(oros.LIDAR_TOPIC, oros.encode_packet_msg(rng.bytes(4000)), i)
        with pytest.warns(TruncatedCaptureWarning):
            from lidarpkt.containers.bags import BagReader
            from lidarpkt.vendors.registry import bag_messages

            got = list(BagReader(mnt / "full.mcap", messages=bag_messages()).batches())
        assert len(got) > 10
        rng = np.random.default_rng(0)
        assert [b.payload[0].tobytes() for b in got] == [rng.bytes(4000) for _ in got]
    finally:
        subprocess.run(["umount", str(mnt)], capture_output=True)


def test_rotation_by_time(tmp_path):
    clock = _Clock()
    w = McapWriter(tmp_path / "t.mcap", chunk_seconds=0.25, rotate_seconds=1.0, clock=clock)
    for i in range(40):  # 4 s of messages, 10 a second
        w.write(oros.IMU_TOPIC, oros.encode_packet_msg(bytes(48)), i)
        clock.t += 0.125 if i % 5 else 0.0625
    w.close()
    counts = [sum(1 for t, _, _ in _official(f)[2] if t == "/ouster/imu_packets") for f in w.files]
    assert len(w.files) >= 3 and sum(counts) == 40 and all(c > 0 for c in counts)


def test_one_velodyne_scan_per_rotation_and_dual_returns_on_their_own_topics(tmp_path):
    from lidarpkt import fixtures

    pcap = fixtures.canned("vlp16-dual")
    out = _decode(tmp_path, pcap, "--topics", "packets,points")
    _, _, msgs = _official(out)
    scans = [m for t, _, m in msgs if t == "/velodyne_packets"]
    first_az = [[int.from_bytes(bytes(p.data)[2:4], "little") for p in s.packets] for s in scans]
    for k, az in enumerate(first_az):
        assert all(a < b for a, b in zip(az, az[1:])), "no wrap inside a scan"
        if k:
            assert az[0] < first_az[k - 1][-1], "each scan starts with the wrap"
    frames = list(lidarpkt.open(pcap))
    assert frames[0].return_labels == ("last", "strongest")
    for topic, slot in (("/velodyne_points", 0), ("/velodyne_points2", 1)):
        clouds = [m for t, _, m in msgs if t == topic]
        assert len(clouds) == len(frames)
        for frame, pc in zip(frames, clouds):
            pts = np.frombuffer(bytes(pc.data), np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4")] + [
                ("rest", "V%d" % (pc.point_step - 12))])).reshape(pc.height, pc.width)
            xyz = frame.xyz()[slot].astype(np.float32)
            no_return = (frame.range_mm[slot] == 0) | ~frame.column_valid[None, :]
            xyz[no_return] = np.nan  # no return: NaN, not a point at the origin
            assert np.array_equal(np.stack([pts["x"], pts["y"], pts["z"]], -1), xyz, equal_nan=True)


def test_damaged_cdr_messages_raise_lidarpkt_errors():
    from lidarpkt.errors import CaptureFormatError, PacketFormatError

    good = vros.encode_velodyne_scan(np.zeros((3, 1206), np.uint8), np.arange(3), 5)
    for cut in (0, 10, 30, len(good) - 1):
        with pytest.raises(CaptureFormatError):
            vros.decode_velodyne_scan(good[:cut])
    with pytest.raises(CaptureFormatError, match="not little-endian CDR"):
        vros.decode_velodyne_scan(b"\x00\x00" + good[2:])
    with pytest.raises(PacketFormatError):
        vros.encode_velodyne_scan(np.zeros((2, 512), np.uint8), np.arange(2), 0)
    with pytest.raises(CaptureFormatError):
        oros.decode_packet_msg(oros.encode_packet_msg(b"abc")[:-1])
    with pytest.raises(CaptureFormatError):
        rosmsgs.decode_stamped_packet(rosmsgs.encode_stamped_packet(b"abc", 1)[:-1])


def test_mcap_to_mcap_keeps_non_legacy_ouster_topics_from_the_recorded_metadata(tmp_path):
    pcap = external("ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.pcap")
    meta = external("ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.json")
    first = _decode(tmp_path, pcap, "--metadata", meta, "--topics", "packets")
    (tmp_path / "second").mkdir()
    second = _decode(tmp_path / "second", first, "--topics", "packets")  # no --metadata: the file has it
    _, _, a = _official(first)
    _, _, b = _official(second)
    topics = lambda msgs: sorted({t for t, _, _ in msgs})  # noqa: E731
    assert topics(b) == topics(a) == ["/ouster/imu", "/ouster/imu_packets", "/ouster/lidar_packets", "/ouster/metadata"]  # /ouster/imu: decoded samples
    lidar = lambda msgs: [bytes(m.buf) for t, _, m in msgs if t == "/ouster/lidar_packets"]  # noqa: E731
    assert lidar(b) == lidar(a) and len(lidar(a)) == 64


def test_calibration_and_frame_sensor_info_are_metadata_records(tmp_path):
    pcap = external(VLP)
    calib = external("rust-lidar-utils/VLP16db.yaml")
    out = _decode(tmp_path, pcap, "--calibration", calib, "--topics", "packets,points")
    _, meta, _ = _official(out)
    by_name = {}
    for m in meta:
        by_name.setdefault(m.name, []).append(m.metadata)
    assert by_name["lidarpkt.calibration"][0]["content"] == calib.read_text()
    (frames,) = by_name["lidarpkt.frames"]
    info = json.loads(frames["sensor_info"])
    assert info["vendor"] == "velodyne" and info["rows"] == 16 and frames["calibration"] == str(calib)
