"""``lidarpkt info`` on every external capture: the facts SOURCES.md states, through the real CLI."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from lidarpkt.pipeline.describe import describe_capture, format_capture
from lidarpkt.core.packet import Endpoint, Packet
from lidarpkt.writers.framing import frames_for
from lidarpkt.writers.pcap import write_pcap_records
from conftest import external


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "lidarpkt", "info", *args], capture_output=True, text=True, timeout=120)


def _info(relpath: str, *metadata: str) -> dict:
    meta = [arg for m in metadata for arg in ("--metadata", str(external(m)))]
    res = _cli(str(external(relpath)), "--json", *meta)
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout)


def _by(doc, size):
    return [s for s in doc["streams"] if s["payload_size"] == size]


def test_vlp16_early_firmware():
    doc = _info("rust-lidar-utils/velodyne_vlp16.pcap")
    (data,) = _by(doc, 1206)
    (pos,) = _by(doc, 512)
    assert (data["packets"], data["dst_port"], pos["packets"], pos["dst_port"]) == (84, 2368, 16, 8308)
    assert data["kind"] == "VLP-16 data"
    assert data["details"]["return_mode"] == "strongest"
    assert data["details"]["product_id"] == 0x21  # SOURCES.md oddity 2
    assert pos["kind"] == "VLP-16 position"
    assert pos["details"]["nmea_first"] is None  # "position packets with an empty NMEA field"
    assert doc["first_time"].startswith("2014-11-10")  # captured 2014-11-10
    # the text line names the product byte once and says why the stream is still a VLP-16
    res = _cli(str(external("rust-lidar-utils/velodyne_vlp16.pcap")))
    assert res.returncode == 0, res.stderr
    (line,) = [ln for ln in res.stdout.splitlines() if "VLP-16 data" in ln]
    assert line.count("HDL-32E") == 1 and "an early VLP-16 by its packet timing and layout" in line


def test_vlp16_modern_and_veloview():
    doc = _info("rust-lidar-utils/velodyne_example.pcap")
    (data,) = doc["streams"]
    assert (data["packets"], data["details"]["product_id"], data["details"]["return_mode"]) == (84, 0x22, "strongest")
    assert doc["first_time"].startswith("2018-05-03")
    doc = _info("veloview/vlp-16-test-90deg-1-50-frames.pcap")
    (data,) = _by(doc, 1206)
    (pos,) = _by(doc, 512)
    assert (data["packets"], pos["packets"]) == (1902, 367)
    assert data["kind"] == "VLP-16 data" and data["details"]["product_id"] == 0x21
    assert round(data["details"]["rotation_hz"]) == 20  # SOURCES.md: 20 Hz
    assert doc["first_time"].startswith("2014-11-04")


def test_hdl32_is_named_an_hdl32e():
    doc = _info("rust-lidar-utils/velodyne_vlp32.pcap")
    (data,) = _by(doc, 1206)
    (pos,) = _by(doc, 512)
    assert (data["packets"], pos["packets"]) == (91, 9)
    assert data["kind"] == "HDL-32E data" and pos["kind"] == "HDL-32E position"
    # "9 position (valid $GPRMC, fix A)", captured 2012-12-11
    assert pos["details"]["nmea_first"].startswith("$GPRMC")
    assert pos["details"]["fix_valid"] is True
    assert pos["details"]["gps_time_first"].startswith("2012-12-11")


@pytest.mark.parametrize(
    "relpath,metadata,lidar_size,lidar_packets,imu_packets,profile,frames",
    [
        ("ouster-sdk/OS-1-64_1024x10_fw20.pcap", "ouster-sdk/OS-1-64_sensor_config_reduced.json", 12608, 64, 11, "LEGACY", [189, 189]),
        ("ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.pcap", "ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.json", 8448, 64, 10, "RNG19_RFL8_SIG16_NIR16_DUAL", [1453, 1453]),
        ("ouster-sdk/OS-1-32-G_v2.1.1_1024x10.pcap", "ouster-sdk/OS-1-32-G_v2.1.1_1024x10.json", 6464, 64, 0, "LEGACY", [638, 638]),
        ("ouster-sdk/OS-2-32-U0_v2.0.0_1024x10.pcap", "ouster-sdk/OS-2-32-U0_v2.0.0_1024x10.json", 6464, 64, 0, "LEGACY", [5424, 5424]),
        ("ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.pcap", "ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.json", 24832, 64, 10, "RNG19_RFL8_SIG16_NIR16", [1259, 1259]),
        ("ouster-sdk/OS-0-128-U1_v2.3.0_1024x10.pcap", "ouster-sdk/OS-0-128-U1_v2.3.0_1024x10.json", 8448, 64, 10, "RNG15_RFL8_NIR8", [1491, 1491]),
        ("ouster-sdk/crc_test.pcap", "ouster-sdk/crc_test.json", 8448, 34, 10, "RNG15_RFL8_NIR8", [254, 255]),
        ("ouster-sdk/duplicate_id.pcap", "ouster-sdk/duplicate_id.json", 8448, 1, 0, "RNG15_RFL8_NIR8", [1778, 1778]),
        ("rust-lidar-utils/ouster_example.pcap", "rust-lidar-utils/ouster_example.json", 12608, 100, 0, "LEGACY", [12072, 12074]),
    ],
)
def test_ouster_with_metadata(relpath, metadata, lidar_size, lidar_packets, imu_packets, profile, frames):
    doc = _info(relpath, metadata)
    (lidar,) = _by(doc, lidar_size)
    assert lidar["kind"] == "Ouster lidar"
    assert lidar["packets"] == lidar_packets
    assert lidar["details"]["profile"] == profile and lidar["details"]["profile_source"] == "metadata"
    assert lidar["details"]["frame_id"] == frames
    imu = _by(doc, 48)
    assert sum(s["packets"] for s in imu) == imu_packets
    assert all(s["kind"] == "Ouster IMU" for s in imu)


def test_ouster_crc_and_guess_without_metadata():
    doc = _info("ouster-sdk/crc_test.pcap")
    (lidar,) = _by(doc, 8448)
    assert lidar["details"]["crc"] == "valid"  # 34/34 valid CRC-64/XZ
    assert lidar["details"]["profile_source"] == "guess"
    # 8448 B is both 32-ch dual and 128-ch low data rate (oddity 8): the guess must say both
    cands = " ".join(lidar["details"]["candidates"])
    assert "RNG19_RFL8_SIG16_NIR16_DUAL" in cands and "RNG15_RFL8_NIR8" in cands


def test_fragment_counts():
    doc = _info("ouster-sdk/duplicate_id.pcap")
    assert (doc["records"], doc["fragments"], doc["reassembled"], doc["orphaned_fragments"]) == (7, 7, 1, 1)
    (s,) = doc["streams"]
    assert (s["src"], s["dst"], s["payload_size"]) == ("10.5.6.101:50474", "10.5.6.1:34636", 8448)
    doc = _info("ouster-sdk/same_ports_legacy.pcap", "ouster-sdk/same_ports_legacy.1.json", "ouster-sdk/same_ports_legacy.2.json")
    assert (doc["fragments"], doc["reassembled"], doc["orphaned_fragments"]) == (17 + 9, 2, 0)
    sizes = {s["src"].split(":")[0]: s["payload_size"] for s in doc["streams"]}
    assert sizes == {"169.254.92.158": 24896, "169.254.238.111": 12608}
    assert {s["details"]["profile"] for s in doc["streams"]} == {"LEGACY"}


def test_same_ports_nonlegacy_profiles_by_source():
    doc = _info(
        "ouster-sdk/same_ports_nonlegacy.pcap",
        "ouster-sdk/same_ports_nonlegacy.1.json",
        "ouster-sdk/same_ports_nonlegacy.2.json",
    )
    lidar = {s["src"].split(":")[0]: s["details"]["profile"] for s in _by(doc, 16640)}
    assert lidar == {"169.254.238.111": "RNG19_RFL8_SIG16_NIR16_DUAL", "169.254.92.158": "FUSA_RNG15_RFL8_NIR8_DUAL"}
    assert all(s["dst_port"] == 7502 for s in doc["streams"])  # IMU and lidar on the same port
    assert len(_by(doc, 48)) == 2


def test_vli16_is_not_vlp16_and_empty_capture():
    doc = _info("ouster-sdk/VLI-16-one-packet.pcap")
    (s,) = doc["streams"]
    assert (s["payload_size"], s["src"], s["dst"]) == (1212, "192.168.1.200:2369", "192.168.1.102:2368")
    assert s["kind"] == "unknown"
    doc = _info("ouster-sdk/empty_pcap.pcap")
    assert doc["streams"] == [] and doc["records"] == 0 and doc["first_time"] is None


def test_text_output_one_line_per_stream():
    res = _cli(str(external("veloview/vlp-16-test-90deg-1-50-frames.pcap")), str(external("ouster-sdk/crc_test.pcap")))
    assert res.returncode == 0, res.stderr
    stream_lines = [line for line in res.stdout.splitlines() if " → " in line]
    assert len(stream_lines) == 4
    assert any("1902 × 1206 B" in line and "VLP-16 data" in line and "strongest" in line for line in stream_lines)
    assert any("367 × 512 B" in line and "VLP-16 position" in line and "PPS" in line for line in stream_lines)
    assert any("34 × 8448 B" in line and "CRC valid" in line for line in stream_lines)
    assert "orphaned fragments 0" in res.stdout


def test_errors_are_messages_not_tracebacks(tmp_path):
    bad = tmp_path / "notes.pcap"
    bad.write_text("hello, this is text\n")
    good = external("rust-lidar-utils/velodyne_example.pcap")
    res = _cli(str(bad), str(good), "--json")
    assert res.returncode == 2
    doc = json.loads(res.stdout)
    assert doc["captures"][0]["file"] == str(bad) and "68 65 6c 6c" in doc["captures"][0]["error"]
    assert doc["captures"][1]["streams"][0]["packets"] == 84
    res = _cli(str(bad))
    assert res.returncode == 2 and "Traceback" not in res.stderr and str(bad) in res.stderr
    res = _cli(str(good), "--metadata", str(tmp_path / "missing.json"))
    assert res.returncode == 2 and "Traceback" not in res.stderr and "missing.json" in res.stderr


def test_damaged_capture_is_reported(tmp_path):
    packets = [
        Packet(1_700_000_000_000_000_000 + i * 1000, Endpoint("10.0.0.2", 5000), Endpoint("10.0.0.1", 6000), bytes([i]) * 100)
        for i in range(5)
    ]
    big = Packet(1_700_000_000_000_009_000, Endpoint("10.0.0.2", 5001), Endpoint("10.0.0.1", 6000), bytes(4000))
    records = [(p.timestamp_ns, f) for p in packets for f in frames_for(p)]
    records += [(big.timestamp_ns, f) for f in frames_for(big, ident=77)[1:]]  # first fragment lost
    path = tmp_path / "damaged.pcap"
    write_pcap_records(path, records)
    data = path.read_bytes()
    path.write_bytes(data[:-10])  # cut inside the last record
    with pytest.warns(Warning):
        doc = describe_capture(path)
    assert doc["truncated"] and doc["orphaned_fragments"] == 1  # one whole fragment before the cut
    (s,) = doc["streams"]
    assert (s["packets"], s["payload_size"], s["kind"]) == (5, 100, "unknown")
    assert abs(s["duration_s"] - 4e-6) < 1e-12
    text = format_capture(doc)
    assert "TRUNCATED" in text and "orphaned fragments 1" in text


def test_generated_pcapng_dual_mode_and_gps_locked(tmp_path):
    """Packets patched by hand after the VLP-16 manual's layout (return mode byte 1204, product 1205;
    position: µs timestamp at 198, PPS status at 202, NMEA from 206), in a VLAN-tagged ns pcapng."""
    from lidarpkt.containers.pcap_reader import read_packets
    from lidarpkt.writers.pcap import Interface, write_pcapng

    data = [p for p in read_packets(external("rust-lidar-utils/velodyne_example.pcap"))][:20]
    dual = []
    for p in data:
        payload = bytearray(p.payload)
        payload[1204], payload[1205] = 0x39, 0x22
        dual.append(Packet(p.timestamp_ns, p.src, p.dst, bytes(payload)))
    nmea = b"$GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*6A\r\n"
    pos = bytearray(512)
    pos[198:202] = (123_456_789 % 3_600_000_000).to_bytes(4, "little")
    pos[202] = 2  # PPS locked
    pos[206 : 206 + len(nmea)] = nmea
    position = Packet(data[5].timestamp_ns + 1, Endpoint("192.168.1.200", 8308), Endpoint("255.255.255.255", 8308), bytes(pos))
    packets = sorted(dual + [position], key=lambda p: p.timestamp_ns)
    path = tmp_path / "dual.pcapng"
    write_pcapng(path, packets, interfaces=[Interface("ethernet", tsresol=9)], vlan=(42,))
    res = _cli(str(path), "--json")
    assert res.returncode == 0, res.stderr
    doc = json.loads(res.stdout)
    assert doc["format"] == "pcapng"
    (d,) = _by(doc, 1206)
    (g,) = _by(doc, 512)
    assert (d["packets"], d["details"]["return_mode"], d["details"]["product_id"]) == (20, "dual", 0x22)
    assert g["details"]["pps_status"] == "locked"
    assert g["details"]["nmea_first"].startswith("$GPRMC,123519")
    assert g["details"]["gps_time_first"].startswith("1994-03-23T12:35:19")
    text = _cli(str(path)).stdout
    assert "PPS locked" in text and "1994-03-23T12:35:19" in text and "dual" in text


def _all_external_pcaps():
    from conftest import external_root

    root = external_root()
    return sorted(str(p.relative_to(root)) for p in root.glob("*/*.pcap")) if root.exists() else []


@pytest.mark.crosscheck
@pytest.mark.parametrize("relpath", _all_external_pcaps())
def test_streams_match_ouster_sdk_stream_info(relpath):
    """Per stream (src ip:port → dst ip:port): packet count, payload sizes and fragments per packet
    as ouster-sdk's libtins-based ``get_stream_info`` counts them; first/last time of the capture."""
    import warnings

    pytest.importorskip("ouster.sdk")
    from ouster.sdk._bindings import pcap as sdk_pcap

    path = external(relpath)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        info = sdk_pcap.get_stream_info(str(path))
    ref = {}
    for key, s in info.udp_streams.items():
        ref[(f"{key.src_ip}:{key.src_port}", f"{key.dst_ip}:{key.dst_port}")] = (s.count, dict(s.payload_size_counts))
    doc = describe_capture(path)
    ours: dict = {}
    for s in doc["streams"]:
        count, sizes = ours.get((s["src"], s["dst"]), (0, {}))
        ours[(s["src"], s["dst"])] = (count + s["packets"], {**sizes, s["payload_size"]: s["packets"]})
    assert ours == ref
    frags = sum(n * c for s in info.udp_streams.values() for n, c in dict(s.fragment_counts).items())
    assert frags == doc["records"]
    if doc["streams"]:
        first = min(s["first_timestamp_ns"] for s in doc["streams"])
        last = max(s["last_timestamp_ns"] for s in doc["streams"])
        assert (first // 1000, last // 1000) == (round(info.timestamp_min * 1e6), round(info.timestamp_max * 1e6))


def test_rosbag2_of_packets():
    """SOURCES.md: the nebula bag holds 603 VLP-16 packets in 4 messages, all 0x39 (dual) / 0x22."""
    doc = _info("nebula/vlp16/1673400471837873222")
    assert (doc["format"], doc["records"], doc["udp_packets"]) == ("rosbag2", 4, 603)
    (s,) = doc["streams"]
    assert (s["packets"], s["payload_size"], s["src"]) == (603, 1206, None)
    assert (s["details"]["return_mode"], s["details"]["product_id"]) == ("dual", 0x22)
    res = _cli(str(external("nebula/vlp16/1673400471837873222")))
    assert res.returncode == 0 and "(no addresses)  603 × 1206 B" in res.stdout


def test_mcap_with_recorded_metadata(tmp_path):
    """An MCAP written by ``lidarpkt decode`` keeps the Ouster metadata: info names the profile from it."""
    out = tmp_path / "crc.mcap"
    res = subprocess.run(
        [sys.executable, "-m", "lidarpkt", "decode", str(external("ouster-sdk/crc_test.pcap")),
         "--metadata", str(external("ouster-sdk/crc_test.json")), "-o", str(out), "--topics", "packets", "-q"],
        capture_output=True, text=True, timeout=300,
    )
    assert res.returncode == 0, res.stderr
    res = _cli(str(out), "--json")
    assert res.returncode == 0, res.stderr
    doc = json.loads(res.stdout)
    assert doc["format"] == "mcap" and doc["sensor_file_in_capture"]
    (lidar,) = _by(doc, 8448)
    assert lidar["packets"] == 34
    assert (lidar["details"]["profile"], lidar["details"]["profile_source"]) == ("RNG15_RFL8_NIR8", "metadata")
    assert sum(s["packets"] for s in _by(doc, 48)) == 10


def test_directory_of_captures(tmp_path):
    """A directory stands for every capture under it (pcap/pcapng by magic, MCAP, ROS bags)."""
    from conftest import external_root

    root = external_root()
    if not root.exists():
        pytest.skip("external fixtures absent")
    res = _cli(str(root), "--json")
    docs = json.loads(res.stdout)["captures"]
    pcaps = sorted(str(p) for p in root.glob("*/*.pcap"))
    assert sorted(d["file"] for d in docs if d.get("format") == "pcap") == pcaps
    # every rosbag2 folder (old writers' metadata with empty fields included) and every ROS 1 bag, each read
    bags = {str(p.parent) for p in root.rglob("metadata.yaml")} | {str(p) for p in root.rglob("*.bag")}
    assert bags and {d["file"] for d in docs if d.get("format") in ("rosbag2", "rosbag1")} == bags
    # every OSF file too; the one whose CRC fails is the error (exit status 2); info reads no field image, so
    # bad_encoding.osf and bad_16_bit_fields.osf are described (decoding them is the error)
    osf = {str(p) for p in root.rglob("*.osf")}
    assert osf and {d["file"] for d in docs if d.get("format") == "osf" or d["file"].endswith(".osf")} == osf
    failed = {Path(d["file"]).name for d in docs if "error" in d}
    unsupported = {Path(d["file"]).name for d in docs if "is not supported" in d.get("error", "")}  # issue 25's profiles
    assert failed - unsupported == {"bad_crc32.osf"}, failed
    errors = [line for line in res.stderr.splitlines() if line.startswith("lidarpkt: error:")]
    assert res.returncode == 2 and len(errors) == len(failed), res.stderr  # one line each
    vls128 = [d for d in docs if "vls128" in d["file"]]
    assert len(vls128) == 1 and sum(s["packets"] for s in vls128[0]["streams"]) == 2193  # an empty serialization format
    empty = tmp_path / "empty"
    empty.mkdir()
    res = _cli(str(empty))
    assert res.returncode == 2 and "directory" in res.stderr and "Traceback" not in res.stderr
