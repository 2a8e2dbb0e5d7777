"""``info`` says what ``lidarpkt.open`` makes of each stream as a typed kind (``stream_kind``) and which
sensor module described it (``vendor``), so that programs (the archive catalog) never read the display
text (``"VLP-16 data"``)."""

from __future__ import annotations

from pathlib import Path

from lidarpkt.pipeline.describe import describe_capture
from lidarpkt.vendors.ouster import load_metadata
from lidarpkt.core.streams import StreamKind
from conftest import external


def _kinds(doc):
    return {(s["payload_size"], s["stream_kind"], s["vendor"]) for s in doc["streams"]}


def test_velodyne_streams():
    doc = describe_capture(external("veloview/vlp-16-test-90deg-1-50-frames.pcap"))
    assert _kinds(doc) == {(1206, "velodyne_data", "velodyne"), (512, "velodyne_position", "velodyne")}
    assert all(StreamKind.parse(s["stream_kind"]).vendor == s["vendor"] for s in doc["streams"])


def test_ouster_streams_need_the_metadata_to_be_routed():
    pcap = external("ouster-sdk/OS-1-64_1024x10_fw20.pcap")
    md = load_metadata(external("ouster-sdk/OS-1-64_sensor_config_reduced.json"))
    with_md = describe_capture(pcap, [md])
    assert {k for _, k, _ in _kinds(with_md)} == {"ouster_lidar", "ouster_imu"}
    assert [s["stream_kind"] == "ouster_lidar" for s in with_md["streams"]].count(True) == 1
    # without metadata the module still recognises Ouster packets (a guess), but lidarpkt.open routes none
    without = describe_capture(pcap)
    assert {(k, v) for _, k, v in _kinds(without)} == {("other", "ouster")}


def test_info_and_archive_jobs_find_the_same_captures(tmp_path):
    """One discovery: a folder stands for the same captures in ``info`` and in an archive job (a rosbag2
    folder is one capture; a capture is known by its suffix or its first bytes; other files are left out)."""
    from conftest import external_root
    from lidarpkt.archive.plan import expand_paths
    from lidarpkt.cli.info import _expand

    root = external_root()
    (tmp_path / "notes.txt").write_text("not a capture")
    (tmp_path / "renamed.dat").write_bytes(external("veloview/vlp-16-test-90deg-1-50-frames.pcap").read_bytes()[:4096])
    for folder in (root, tmp_path):
        found = _expand([str(folder)])
        assert found == [url for url, _, _ in expand_paths([str(folder)])]
    assert _expand([str(tmp_path)]) == [str(tmp_path / "renamed.dat")]  # by its pcap magic
    assert any(Path(p, "metadata.yaml").is_file() for p in _expand([str(root)]))  # a rosbag2 folder, whole
