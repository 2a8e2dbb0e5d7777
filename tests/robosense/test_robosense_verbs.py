"""Every verb takes the RoboSense bag through the vendor registry alone: ``info``, ``decode`` (MCAP with the packets
as ``robosense_msgs/msg/RobosenseScan`` and PointCloud2; NPZ), ``export`` (Parquet holding exactly
``lidarpkt.open``'s returns; pcap holding the 751 payloads byte for byte, MSOP to port 6699 and DIFOP to 7788;
segments equal to the whole file), ``catalog`` on a Dask LocalCluster, ``analyze`` and ``multireturn``; hostile
copies give counted skips or one error line."""

from __future__ import annotations

import json
import re
import warnings

import numpy as np
import pyarrow.dataset as ds
import pytest

import lidarpkt
from archive_cases import lidarpkt_cli
from conftest import external
from robosense_bag import BAG, CSV, all_packets, write_sensor_pcap

mcap_reader = pytest.importorskip("mcap.reader")


def _frames(path, **options) -> list:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return list(lidarpkt.open(path, **options))


def _same_frames(a: list, b: list) -> None:
    assert len(a) == len(b) > 0
    for x, y in zip(a, b):
        assert x.sensor.model == y.sensor.model and x.return_labels == y.return_labels
        np.testing.assert_array_equal(x.range_mm, y.range_mm)
        np.testing.assert_array_equal(x.reflectivity, y.reflectivity)
        np.testing.assert_array_equal(x.azimuth_deg, y.azimuth_deg)
        np.testing.assert_array_equal(x.column_timestamp_ns, y.column_timestamp_ns)
        np.testing.assert_array_equal(x.xyz(), y.xyz())


def _returns(frames: list) -> tuple[np.ndarray, np.ndarray]:
    """(range m, float32 XYZ) of every return of ``frames``, in the order of the Parquet points layout."""
    ranges, xyz = [], []
    for f in frames:
        hit = (f.range_mm > 0) & f.column_valid[None, None, :]
        ranges.append(f.range_mm[hit] / 1000.0)
        xyz.append(f.xyz().astype(np.float32)[hit])
    return np.concatenate(ranges), np.concatenate(xyz)


def test_info_names_model_return_mode_and_calibration_source(tmp_path):
    bag = external(BAG)
    out = lidarpkt_cli("info", str(bag))
    assert out.returncode == 0, out.stderr
    line = next(x for x in out.stdout.splitlines() if "1248 B" in x)
    assert "RoboSense RS-Helios MSOP" in line and "strongest" in line and "calibration: DIFOP" in line
    doc = json.loads(lidarpkt_cli("info", "--json", str(bag)).stdout)
    (stream,) = doc["streams"]
    assert (stream["stream_kind"], stream["vendor"], stream["packets"]) == ("robosense_msop", "robosense", 751)
    assert stream["details"]["model"] == "RS-Helios" and stream["details"]["difop_packets"] == 1
    pcap = write_sensor_pcap(tmp_path / "sensor.pcap")  # MSOP and DIFOP on their own ports
    doc = json.loads(lidarpkt_cli("info", "--json", str(pcap)).stdout)
    kinds = {s["dst_port"]: s for s in doc["streams"]}
    assert kinds[6699]["stream_kind"] == "robosense_msop" and kinds[7788]["stream_kind"] == "robosense_difop"
    assert kinds[7788]["details"]["calibration"] == "DIFOP (32 lasers)"
    assert kinds[7788]["details"]["return_mode"] == "strongest" and kinds[6699]["details"]["model"] == "RS-Helios"
    with_csv = json.loads(lidarpkt_cli("info", "--json", str(pcap), "--metadata", str(external(CSV))).stdout)
    msop = next(s for s in with_csv["streams"] if s["dst_port"] == 6699)
    assert msop["details"]["calibration"].startswith("angle CSV")


def test_decode_to_mcap_writes_robosense_scans_and_points_that_read_back(tmp_path):
    from mcap_ros2.decoder import DecoderFactory

    bag = external(BAG)
    out = tmp_path / "x.mcap"
    run = lidarpkt_cli("decode", str(bag), "-o", str(out), "--topics", "packets,points", "-q")
    assert run.returncode == 0, run.stderr
    with open(out, "rb") as fh:
        reader = mcap_reader.make_reader(fh, decoder_factories=[DecoderFactory()])
        msgs = [(ch.topic, sch.name, m) for sch, ch, _, m in reader.iter_decoded_messages()]
    scans = [m for topic, _, m in msgs if topic == "/robosense_packets"]
    assert {s for t, s, _ in msgs if t == "/robosense_packets"} == {"robosense_msgs/msg/RobosenseScan"}
    payload, stamps = all_packets()
    got = [bytes(p.data[:p.size]) for s in scans for p in s.packets]
    assert got == [row.tobytes() for row in payload]  # every packet, in order, byte for byte
    assert [p.stamp.sec * 1_000_000_000 + p.stamp.nanosec for s in scans for p in s.packets] == stamps.tolist()
    assert [bool(p.is_difop) for s in scans for p in s.packets].count(True) == 1
    assert all(s.header.frame_id == "robosense" for s in scans)
    frames = _frames(bag)
    clouds = [m for topic, _, m in msgs if topic == "/robosense_points"]
    assert len(clouds) == len(frames) and clouds[0].header.frame_id == "robosense"
    assert [c.width * c.height for c in clouds] == [f.range_mm[0].size for f in frames]  # organised: a point a pixel
    _same_frames(_frames(out), frames)


def test_decode_to_npz_holds_the_frames(tmp_path):
    bag = external(BAG)
    run = lidarpkt_cli("decode", str(bag), "-o", str(tmp_path / "x.npz"), "-q")
    assert run.returncode == 0, run.stderr
    npz = np.load(tmp_path / "x.npz")
    frames = _frames(bag)
    gridded = [f.on_grid() for f in frames]  # the NPZ's frames are on the sensor's azimuth grid
    assert npz["range_mm"].shape == (len(frames), 1, 32, 1800)
    np.testing.assert_array_equal(npz["range_mm"], np.stack([g.range_mm for g in gridded]))
    np.testing.assert_array_equal(npz["column_valid"], np.stack([g.column_valid for g in gridded]))
    np.testing.assert_array_equal(npz["column_timestamp_ns"], np.stack([g.column_timestamp_ns for g in gridded]))
    assert sum(int((g.range_mm > 0).sum()) for g in gridded) > 0.99 * sum(int((f.range_mm > 0).sum()) for f in frames)
    assert npz["return_labels"].tolist() == ["strongest"]
    assert json.loads(str(npz["sensor_json"]))["model"] == "RS-Helios"


def test_export_parquet_holds_exactly_opens_returns(tmp_path):
    bag = external(BAG)
    run = lidarpkt_cli("export", str(bag), "--format", "parquet", "-o", str(tmp_path / "pq"), "-q")
    assert run.returncode == 0, run.stderr
    table = ds.dataset(tmp_path / "pq", format="parquet").to_table()
    ranges, xyz = _returns(_frames(bag))
    assert table.num_rows == len(ranges) > 100_000
    np.testing.assert_array_equal(table["range_m"].to_numpy(), ranges)
    np.testing.assert_array_equal(np.stack([table[c].to_numpy() for c in "xyz"], axis=1), xyz)


def test_export_pcap_gives_the_751_payloads_byte_for_byte(tmp_path):
    from lidarpkt.recorder.replay import read_capture

    bag = external(BAG)
    run = lidarpkt_cli("export", str(bag), "--format", "pcap", "-o", str(tmp_path / "pcap"), "-q")
    assert run.returncode == 0, run.stderr
    (pcap,) = (tmp_path / "pcap").rglob("*.pcap")
    packets = list(read_capture(str(pcap)))
    payload, stamps = all_packets()
    assert [p.payload for p in packets] == [row.tobytes() for row in payload]
    assert [p.timestamp_ns for p in packets] == stamps.tolist()
    difop = [p.payload[:8] == bytes.fromhex("a5ff005a11115555") for p in packets]
    # a bag keeps no addresses: each kind its factory port (tests/robosense/test_robosense_ports.py reads them by dpkt)
    assert [p.dst.port for p in packets] == [7788 if d else 6699 for d in difop] and sum(difop) == 1
    _same_frames(_frames(pcap), _frames(bag))


def test_segments_decode_as_the_whole_capture_with_the_difop_of_its_start(tmp_path, monkeypatch):
    """Segments of 150 kB (about 120 packets) start past the capture's one DIFOP, or end before it: each reader
    of a later segment is given the DIFOP of the capture's start, and the export equals the whole file's row for
    row. Without it, those readers hold their packets for a DIFOP that never comes and lose frames."""
    from lidarpkt.archive import export
    from lidarpkt.vendors import registry

    pcap = write_sensor_pcap(tmp_path / "sensor.pcap")

    def rows(out: str) -> list:
        table = ds.dataset(tmp_path / out, format="parquet").to_table()
        return table.sort_by([("frame_id", "ascending"), ("timestamp_ns", "ascending"), ("row", "ascending"),
                              ("return_slot", "ascending")]).drop(["sensor"]).to_pylist()

    whole = export([pcap], tmp_path / "whole", format="parquet", workers=1).to_pylist()
    cut = export([pcap], tmp_path / "cut", format="parquet", workers=1, segment_bytes="150kB").to_pylist()
    assert len(whole) == 1 and len(cut) >= 6 and all(r["status"] == "done" for r in whole + cut)
    assert sum(r["frames"] for r in cut) == whole[0]["frames"] == 6
    assert rows("cut") == rows("whole")
    monkeypatch.setattr(registry, "sensor_files_in_packets", lambda path, setup: [])
    bare = export([pcap], tmp_path / "bare", format="parquet", workers=1, segment_bytes="150kB").to_pylist()
    assert sum(r["frames"] for r in bare) < 6


def test_catalog_on_a_local_dask_cluster(tmp_path):
    distributed = pytest.importorskip("distributed")
    from lidarpkt.archive import catalog

    bag = external(BAG)
    pcap = write_sensor_pcap(tmp_path / "sensor.pcap")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        table = catalog([bag, pcap], client=client)
    rows = table.to_pylist()
    assert table == catalog([bag, pcap], workers=1)
    msop = [r for r in rows if r["kind"] == "RoboSense RS-Helios MSOP"]
    assert len(msop) == 2 and all(r["vendor"] == "robosense" and r["model"] == "RS-Helios" for r in msop)
    assert all(r["frames"] == len(_frames(bag)) and r["lost_packets"] == 0 and r["error"] is None for r in msop)
    assert any(r["kind"] == "RoboSense DIFOP" and r["packets"] == 1 for r in rows)


def test_analysis_verbs_take_the_bag(tmp_path):
    bag = external(BAG)
    run = lidarpkt_cli("analyze", str(bag), "--pixel", "10,100", "--json", "-q")
    assert run.returncode == 0, run.stderr
    report = json.loads(run.stdout)
    assert report["frames"] == 4 and report["pixels"][0]["label"] == "strongest"  # the 4 whole rotations
    run = lidarpkt_cli("multireturn", str(bag), "-o", str(tmp_path / "map.npz"), "-q")  # a bag folder: one capture
    assert run.returncode == 0, run.stderr
    with np.load(tmp_path / "map.npz") as saved:
        assert saved.files and all(saved[k].size for k in saved.files)


def _hostile(tmp_path, name: str, edit) -> tuple:
    """``decode`` of a copy of the sensor pcap whose payloads ``edit`` changed: (exit code, stderr, frames decoded)."""
    from lidarpkt.core.packet import Packet
    from lidarpkt.writers.pcap import write_pcap
    from robosense_bag import sensor_packets

    packets = sensor_packets()
    payload = np.stack([np.frombuffer(p.payload, np.uint8) for p in packets]).copy()
    edit(payload)
    path = tmp_path / f"{name}.pcap"
    write_pcap(path, [Packet(p.timestamp_ns, p.src, p.dst, row.tobytes()) for p, row in zip(packets, payload)])
    run = lidarpkt_cli("decode", str(path), "-o", str(tmp_path / f"{name}.npz"))
    frames = len(np.load(tmp_path / f"{name}.npz")["frame_id"]) if run.returncode == 0 else 0
    return run.returncode, run.stderr, frames


def test_hostile_copies_give_counted_skips_or_one_error_line(tmp_path):
    difop = np.flatnonzero(np.all(all_packets()[0][:, :8] == np.frombuffer(bytes.fromhex("a5ff005a11115555"), np.uint8),
                                  axis=1))

    def flip(p):
        rng = np.random.default_rng(5)
        rows = rng.choice(len(p), 60, replace=False)
        p[rows, rng.integers(0, p.shape[1], 60)] ^= 0xFF

    from lidarpkt.vendors.robosense import packet as P

    def nonsense_angles(p):
        start = P.offset(P.DIFOP_HELIOS, "vertical_angles")
        p[difop, start:start + 96] = 0xFF  # the 32 vertical angles: signs and values no sensor sends

    for name, edit in (("flipped", flip), ("angles", nonsense_angles)):
        rc, err, frames = _hostile(tmp_path, name, edit)
        assert rc == 0 and "Traceback" not in err, err
        assert frames == 6, (name, err)
        skipped = int(re.search(r"of 751 packets, .*?(\d+) skipped as malformed", err).group(1))
        lost = re.search(r"of 751 packets, (\d+) lost", err)
        assert skipped == 1 if name == "angles" else skipped >= 1
        assert int(lost.group(1)) <= skipped if lost else True  # a packet skipped is at most a packet missing
    truncated = tmp_path / "truncated.pcap"
    data = write_sensor_pcap(tmp_path / "whole.pcap").read_bytes()
    truncated.write_bytes(data[: len(data) // 2 + 333])
    run = lidarpkt_cli("decode", str(truncated), "-o", str(tmp_path / "t.npz"))
    assert "Traceback" not in run.stderr
    if run.returncode == 0:
        assert 1 <= len(np.load(tmp_path / "t.npz")["frame_id"]) <= 4
    else:
        assert run.returncode == 2 and len(run.stderr.strip().splitlines()) == 1


def test_model_and_metadata_options_reach_the_decoder(tmp_path):
    """``model=`` and ``metadata=`` (the angle CSV, told apart by content) of ``lidarpkt.open`` and the CLI give the
    decoder's own reading of the bag as a Helios 16P, the one compared with nebula's XYZ."""
    from robosense_bag import decode

    bag, csv = external(BAG), external(CSV)
    opened = _frames(bag, model="RS-Helios-16P", metadata=[str(csv)])
    direct = decode(model="RS-Helios-16P", calibration=str(csv))[0]
    _same_frames(opened, direct)
    assert opened[0].sensor.model == "RS-Helios-16P" and opened[0].sensor.rows == 16
    run = lidarpkt_cli("decode", str(bag), "-o", str(tmp_path / "p.parquet"), "--model", "RS-Helios-16P",
                       "--calibration", str(csv), "-q")
    assert run.returncode == 0, run.stderr
    table = ds.dataset(tmp_path / "p.parquet", format="parquet").to_table()
    assert table.num_rows == len(_returns(opened)[0]) and int(table["row"].to_numpy().max()) == 15
    wrong = lidarpkt_cli("decode", str(bag), "-o", str(tmp_path / "q.npz"), "--model", "RS-Helios-99")
    assert wrong.returncode == 2 and len(wrong.stderr.strip().splitlines()) == 1 and "RS-Helios-16P" in wrong.stderr


def test_frames_read_back_from_parquet_keep_their_xyz(tmp_path):
    from lidarpkt.writers.parquet import read_frames

    bag = external(BAG)
    run = lidarpkt_cli("decode", str(bag), "-o", str(tmp_path / "f.parquet"), "--layout", "frames", "-q")
    assert run.returncode == 0, run.stderr
    again = list(read_frames(tmp_path / "f.parquet"))
    _same_frames(again, _frames(bag))  # XYZ rebuilt by the vendor record from what the file kept, bit for bit
