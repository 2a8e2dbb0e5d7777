"""``lidarpkt decode`` to NPZ and MCAP: against the facts SOURCES.md gives for the real captures,
lidarpkt.open, and ouster-sdk (crosscheck)."""

from __future__ import annotations

import subprocess
import sys
import warnings

import numpy as np
import pytest

import lidarpkt
from conftest import end_process, external, start_process
from test_replay_record import REPO, _messages

OS1 = "ouster-sdk/OS-1-64_1024x10_fw20.pcap"
OS1_JSON = "ouster-sdk/OS-1-64_sensor_config_reduced.json"


def _decode(*args):
    r = subprocess.run([sys.executable, "-m", "lidarpkt", "decode", *map(str, args)], capture_output=True,
                       text=True, timeout=120, cwd=REPO)
    return r


def test_npz_of_the_veloview_capture_has_its_52_frames_on_the_grid(tmp_path):
    pcap = external("veloview/vlp-16-test-90deg-1-50-frames.pcap")
    out = tmp_path / "v.npz"
    r = _decode(pcap, "-o", out, "-q")
    assert r.returncode == 0, r.stderr
    d = np.load(out)
    # SOURCES.md / vlp-16.test: VeloView counts 52 frames, partial first and last included
    # a 20 Hz capture: the one default grid is 0.4° (the firing rate), 900 columns (issue 14 item 1)
    assert d["range_mm"].shape == (52, 1, 16, 900) and d["range_mm"].dtype == np.uint32
    assert d["partial"][0] and d["partial"][-1] and not d["partial"][1:-1].any()
    frames = [f.on_grid() for f in lidarpkt.open(pcap)]
    assert np.array_equal(d["range_mm"], np.stack([f.range_mm for f in frames]))
    assert np.array_equal(d["column_valid"], np.stack([f.column_valid for f in frames]))
    assert np.array_equal(d["column_timestamp_ns"], np.stack([f.column_timestamp_ns for f in frames]))
    assert list(d["return_labels"]) == ["strongest"]


def test_npz_of_the_legacy_os1_capture(tmp_path):
    out = tmp_path / "o.npz"
    r = _decode(external(OS1), "--metadata", external(OS1_JSON), "-o", out, "-q", "--compress")
    assert r.returncode == 0, r.stderr
    d = np.load(out)
    # SOURCES.md: exactly one complete frame, frame_id 189, measurement ids 0-1023, status all valid
    assert d["frame_id"].tolist() == [189]
    assert np.array_equal(d["measurement_id"][0], np.arange(1024))
    assert (d["status"] == 0xFFFFFFFF).all()
    assert d["range_mm"].shape == (1, 1, 64, 1024) and d["near_ir"].shape == (1, 64, 1024)


@pytest.mark.crosscheck
def test_npz_ranges_equal_ouster_sdk(tmp_path):
    sdk_pcap = pytest.importorskip("ouster.sdk.pcap")
    out = tmp_path / "o.npz"
    assert _decode(external(OS1), "--metadata", external(OS1_JSON), "-o", out, "-q").returncode == 0
    d = np.load(out)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        src = sdk_pcap.PcapFrameSetSource(str(external(OS1)), meta=[str(external(OS1_JSON))])
        scans = [fs[0] for fs in src if fs[0] is not None]
    assert len(scans) == 1
    assert np.array_equal(d["range_mm"][0, 0], scans[0].field("RANGE"))
    assert np.array_equal(d["signal"][0, 0], scans[0].field("SIGNAL"))
    assert np.array_equal(d["column_timestamp_ns"][0], scans[0].timestamp.astype(np.int64))


@pytest.mark.crosscheck
def test_pointcloud2_equals_ouster_sdk_xyz(tmp_path):
    sdk_pcap = pytest.importorskip("ouster.sdk.pcap")
    core = pytest.importorskip("ouster.sdk.core")
    out = tmp_path / "o.mcap"
    r = _decode(external(OS1), "--metadata", external(OS1_JSON), "-o", out, "--topics", "points", "-q")
    assert r.returncode == 0, r.stderr
    _, msgs = _messages(out)
    (pc,) = [m for t, _, m in msgs if t == "/ouster/points"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        src = sdk_pcap.PcapFrameSetSource(str(external(OS1)), meta=[str(external(OS1_JSON))])
        scan = [fs[0] for fs in src if fs[0] is not None][0]
        info = src.sensor_info[0]
    xyz = core.destagger(info, core.XYZLut(info, use_extrinsics=False)(scan))  # [H, W, 3] metres
    pts = np.frombuffer(bytes(pc.data), np.dtype({"names": [f.name for f in pc.fields],
                                                   "formats": ["<f4" if f.datatype == 7 else "<u2" if f.datatype == 4
                                                               else "<u4" for f in pc.fields],
                                                   "offsets": [f.offset for f in pc.fields],
                                                   "itemsize": pc.point_step})).reshape(pc.height, pc.width)
    got = np.stack([pts["x"], pts["y"], pts["z"]], axis=-1).astype(np.float64)
    no_return = core.destagger(info, scan.field("RANGE")) == 0  # NaN in the cloud (ouster-sdk: at the origin)
    assert np.isnan(got[no_return]).all() and not np.isnan(got[~no_return]).any()
    np.testing.assert_allclose(got[~no_return], xyz[~no_return], rtol=0, atol=2e-6 * max(1.0, np.abs(xyz).max()))
    assert np.array_equal(pts["range"], core.destagger(info, scan.field("RANGE")))


def test_mcap_topic_choice(tmp_path):
    out = tmp_path / "p.mcap"
    pcap = external("rust-lidar-utils/velodyne_example.pcap")
    assert _decode(pcap, "-o", out, "--topics", "points", "-q").returncode == 0
    _, msgs = _messages(out)
    assert {t for t, _, _ in msgs} == {"/velodyne_points"}
    assert len(msgs) == len(list(lidarpkt.open(pcap)))
    out2 = tmp_path / "i.mcap"
    assert _decode(pcap, "-o", out2, "--topics", "packets,images", "-q").returncode == 0
    _, msgs = _messages(out2)
    assert {t for t, _, _ in msgs} == {"/velodyne_packets", "/velodyne/range_image", "/velodyne/reflectivity_image"}


def test_decode_errors_are_clear(tmp_path):
    pcap = external("rust-lidar-utils/velodyne_example.pcap")
    for args, message in (
        ((pcap, "-o", tmp_path / "x.txt"), "the accepted suffixes are .mcap, .npz"),
        ((tmp_path / "missing.pcap", "-o", tmp_path / "x.npz"), "no such file"),
        ((pcap, "-o", tmp_path / "x.mcap", "--topics", "bogus"), "choose among"),
        ((external("einride-vlp16-go/packet.bin"), "-o", tmp_path / "x.npz"), "not a capture"),
        ((pcap, "-o", tmp_path / "nodir" / "x.npz"), "does not exist"),
    ):
        r = _decode(*args)
        assert r.returncode == 2 and message in r.stderr and "Traceback" not in r.stderr, (args, r.stderr)


def test_progress_bar_on_a_terminal_and_none_in_a_pipe(tmp_path):
    import os
    import pty

    pcap = external("veloview/vlp-16-test-90deg-1-50-frames.pcap")
    master, slave = pty.openpty()
    try:
        proc = start_process([sys.executable, "-m", "lidarpkt", "decode", str(pcap), "-o", str(tmp_path / "p.npz")],
                             stderr=slave, stdout=subprocess.DEVNULL, cwd=REPO)
        os.close(slave)
        chunks = []
        while True:
            try:
                data = os.read(master, 4096)
            except OSError:  # EIO: the child closed the terminal
                break
            if not data:
                break
            chunks.append(data)
        assert proc.wait(timeout=120) == 0
    finally:
        os.close(master)
        if "proc" in locals():
            end_process(proc)
    text = b"".join(chunks).decode(errors="replace")
    assert "decode:" in text and "%|" in text and "52 frames" in text  # tqdm's bar, with the frame count
    piped = _decode(pcap, "-o", tmp_path / "q.npz")
    assert piped.returncode == 0 and "\r" not in piped.stderr and "52 frames" in piped.stderr


def test_npz_of_two_sensors_has_the_first_bare_and_the_second_prefixed(tmp_path):
    out = tmp_path / "two.npz"
    vlp = external("rust-lidar-utils/velodyne_example.pcap")
    r = _decode(vlp, external(OS1), "--metadata", external(OS1_JSON), "-o", out, "-q")
    assert r.returncode == 0, r.stderr
    d = np.load(out)
    n_vlp = len(list(lidarpkt.open(vlp)))
    assert d["range_mm"].shape == (n_vlp, 1, 16, 1800) and d["s1_range_mm"].shape == (1, 1, 64, 1024)
    assert "signal" not in d and d["s1_signal"].shape == (1, 1, 64, 1024)
    assert d["sensor_prefixes"].tolist() == ["", "s1_"] and "s0_range_mm" not in d
    assert d["s1_frame_id"].tolist() == [189]


def test_frames_are_logged_at_the_host_time_of_their_last_packet(tmp_path):
    """The OS1 capture's clock counts from boot (SOURCES.md: fw 2.0, no PTP) while the pcap holds
    2021 host times: frame messages must sit among their packets, not in 1970."""
    from lidarpkt.containers.pcap_reader import read_packets

    out = tmp_path / "t.mcap"
    r = _decode(external(OS1), "--metadata", external(OS1_JSON), "-o", out, "--topics", "packets,points", "-q")
    assert r.returncode == 0, r.stderr
    _, msgs = _messages(out)
    (log_time,) = [lt for t, lt, _ in msgs if t == "/ouster/points"]
    lidar_times = [p.timestamp_ns for p in read_packets(external(OS1)) if len(p.payload) == 12608]
    assert abs(log_time - lidar_times[-1]) < 5_000_000  # the frame's last packet, within 5 ms of jitter
    (pc,) = [m for t, _, m in msgs if t == "/ouster/points"]
    assert pc.header.stamp.sec < 1000  # header.stamp stays the sensor's own time
    # VLP-16: each frame within a packet period or so of the host time its rotation's scan was logged
    vlp = external("veloview/vlp-16-test-90deg-1-50-frames.pcap")
    out2 = tmp_path / "v.mcap"
    assert _decode(vlp, "-o", out2, "--topics", "packets,points", "-q").returncode == 0
    _, msgs = _messages(out2)
    points = [lt for t, lt, _ in msgs if t == "/velodyne_points"]
    scans = [lt for t, lt, _ in msgs if t == "/velodyne_packets"]
    assert points == sorted(points)
    host = [p.timestamp_ns for p in read_packets(vlp) if len(p.payload) == 1206]
    assert host[0] <= points[0] and points[-1] <= host[-1] + 5_000_000
    near = [min(abs(p - s) for s in scans) for p in points[1:-1]]
    assert max(near) < 5_000_000
