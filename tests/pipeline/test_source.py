"""lidarpkt.open: container detection, routing of streams to decoders, options, errors."""

import numpy as np
import pytest

import lidarpkt
from lidarpkt.errors import UnknownSensorError, UnsupportedContainerError
from lidarpkt.containers.magic import container_kind


def test_veloview_test_through_open(ext):
    """VeloView's own expected output (vlp-16.test): 52 frames and its per-frame point counts,
    with VeloView's block-level cut passed through lidarpkt.open."""
    frames = list(lidarpkt.open(ext("veloview/vlp-16-test-90deg-1-50-frames.pcap"), cut_on_block=True))
    assert len(frames) == 52
    assert frames[0].partial and frames[-1].partial
    counts = {i: frames[i].n_returns for i in (0, 2, 16, 51)}
    assert counts == {0: 5736, 2: 13898, 16: 13860, 51: 274}


def test_default_cut_moves_boundaries_by_at_most_one_firing_sequence(ext):
    path = ext("veloview/vlp-16-test-90deg-1-50-frames.pcap")
    block = list(lidarpkt.open(path, cut_on_block=True))
    sequence = list(lidarpkt.open(path))
    assert len(sequence) == len(block)
    for a, b in zip(block[1:-1], sequence[1:-1]):
        assert abs(a.n_returns - b.n_returns) <= 32  # one firing sequence, two slots at most


def test_two_sensors_on_one_port_each_get_their_own_decoder(ext):
    path = ext("ouster-sdk/same_ports_legacy.pcap")
    reader = lidarpkt.open(path, metadata=[ext("ouster-sdk/same_ports_legacy.1.json"),
                                           ext("ouster-sdk/same_ports_legacy.2.json")])
    frames = list(reader)
    # SOURCES.md: OS-0-128 from 169.254.92.158, OS-1-64 from 169.254.238.111, one packet each.
    by_source = {f.sensor.source.split(":")[0]: f.shape[1] for f in frames}
    assert by_source == {"169.254.92.158": 128, "169.254.238.111": 64}
    assert len(reader.decoders) == 2 and reader.stats.packets_of("ouster", "lidar") == 2


def test_source_filter_keeps_one_sensor(ext):
    path = ext("ouster-sdk/same_ports_legacy.pcap")
    md = [ext("ouster-sdk/same_ports_legacy.1.json"), ext("ouster-sdk/same_ports_legacy.2.json")]
    frames = list(lidarpkt.open(path, metadata=md, source="169.254.238.111"))
    assert [f.shape[1] for f in frames] == [64]


def test_partial_frames_can_be_left_out(ext):
    path = ext("rust-lidar-utils/ouster_example.pcap")
    md = ext("rust-lidar-utils/ouster_example.json")
    assert [f.frame_id for f in lidarpkt.open(path, metadata=md)] == [12072, 12073, 12074]
    assert [f.frame_id for f in lidarpkt.open(path, metadata=md, include_partial=False)] == [12073]


def test_position_packets_are_routed_not_reported_as_unknown(ext):
    reader = lidarpkt.open(ext("rust-lidar-utils/velodyne_vlp16.pcap"))
    frames = list(reader)
    assert frames and reader.stats.unrouted_packets == 0
    assert reader.stats.packets_of("velodyne", "data") == 84 and reader.stats.packets_of("velodyne", "position") == 16


def test_hdl32e_capture_is_decoded_as_an_hdl32e(ext):
    frames = list(lidarpkt.open(ext("rust-lidar-utils/velodyne_vlp32.pcap")))
    assert frames and {f.sensor.model for f in frames} == {"HDL-32E"}


def test_ouster_capture_without_metadata_says_to_pass_it(ext):
    with pytest.raises(UnknownSensorError, match="metadata"):
        list(lidarpkt.open(ext("ouster-sdk/OS-1-32-G_v2.1.1_1024x10.pcap")))


def test_empty_capture_gives_no_frames(ext):
    assert list(lidarpkt.open(ext("ouster-sdk/empty_pcap.pcap"), metadata=ext("ouster-sdk/empty_pcap.json"))) == []


def test_rosbag2_directory_and_db3_file_open_alike(ext):
    folder = ext("nebula/vlp16/1673400471837873222")
    by_dir = list(lidarpkt.open(folder))
    by_file = list(lidarpkt.open(folder / "1673400471837873222_0.db3"))
    assert len(by_dir) == len(by_file) > 0
    for a, b in zip(by_dir, by_file):
        assert np.array_equal(a.range_mm, b.range_mm)
    assert by_dir[1].return_labels == ("last", "strongest")


@pytest.mark.parametrize("content, kind", [
    (b"\xd4\xc3\xb2\xa1" + bytes(20), "pcap"),
    (b"\x0a\x0d\x0d\x0a" + bytes(20), "pcap"),
    (b"\x89MCAP0\r\n" + bytes(8), "mcap"),
    (b"#ROSBAG V2.0\n" + bytes(4), "rosbag1"),
    (b"SQLite format 3\x00", "rosbag2"),
])
def test_container_is_recognised_by_its_first_bytes(tmp_path, content, kind):
    path = tmp_path / "capture.bin"
    path.write_bytes(content)
    assert container_kind(path) == kind


def test_not_a_capture_names_the_file_and_its_first_bytes(tmp_path):
    path = tmp_path / "notes.pcap"
    path.write_text("hello lidar")
    with pytest.raises(UnsupportedContainerError, match=r"notes\.pcap.*68 65 6c 6c 6f"):
        list(lidarpkt.open(path))
    with pytest.raises(UnsupportedContainerError, match="no such file"):
        lidarpkt.open(tmp_path / "missing.pcap")
    with pytest.raises(UnsupportedContainerError, match="metadata.yaml"):
        lidarpkt.open(tmp_path)


def test_source_filter_that_matches_nothing_names_the_sources_seen(ext):
    # SOURCES.md: velodyne_example.pcap comes from 192.168.1.200.
    with pytest.raises(UnknownSensorError, match=r"no packets from source 10\.0\.0\.1.*192\.168\.1\.200 \(84 packets\)"):
        list(lidarpkt.open(ext("rust-lidar-utils/velodyne_example.pcap"), source="10.0.0.1"))


def test_calibration_files_are_accepted_by_path(ext):
    """A ROS YAML / VeloView XML passed by path is used: both generic files have the stock beam angles
    but no vertical beam offset, where the stock calibration (like velodyne_decoder's) has
    vert_offset = 0.04191 m · tan(−ω) (REFERENCE.md). So x, y agree and z differs by exactly that."""
    path = ext("rust-lidar-utils/velodyne_example.pcap")
    stock = list(lidarpkt.open(path))
    omega = np.deg2rad(stock[0].sensor.beam_altitude_deg)  # per row
    for cal in ("rust-lidar-utils/VLP16db.yaml", "veloview/VLP-16.xml"):
        frames = list(lidarpkt.open(path, metadata=ext(cal)))
        assert [f.shape for f in frames] == [f.shape for f in stock]
        a, b = stock[0].xyz(), frames[0].xyz()
        hit = stock[0].range_mm > 0
        assert np.abs(a[..., :2] - b[..., :2])[hit].max() < 1e-6
        dz = (a[..., 2] - b[..., 2])  # [R, H, W]
        expected = np.broadcast_to((0.04191 * np.tan(-omega))[None, :, None], dz.shape)
        assert np.abs(dz - expected)[hit].max() < 1e-5
