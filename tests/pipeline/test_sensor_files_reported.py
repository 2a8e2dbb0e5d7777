"""Every sensor file given either applies to a stream of the capture or is reported: a warning naming the file
where the capture decodes without it, an error saying what differs where nothing could be decoded with it,
and a warning where a file of another mode of the sensor (another rate) is used."""

from __future__ import annotations

import json
import warnings

import pytest

import lidarpkt
from lidarpkt.errors import LidarpktError, UnknownSensorError, UnusedSensorFileWarning

from conftest import external

VLP10 = "rust-lidar-utils/velodyne_example.pcap"
OS = "ouster-sdk/"
HESAI = "nebula/hesai/"


def _open(capture, metadata):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        frames = list(lidarpkt.open(external(capture), metadata=metadata))
    return frames, [str(w.message) for w in caught], [w.category for w in caught]


@pytest.mark.parametrize("wrong", [HESAI + "PandarXT32.csv", OS + "OS-0-32-U1_v2.2.0_1024x10.json"])
def test_a_file_of_another_vendor_for_a_velodyne_capture_is_named_as_not_used(wrong):
    frames, messages, categories = _open(VLP10, str(external(wrong)))
    assert frames
    assert UnusedSensorFileWarning in categories
    assert any(str(external(wrong)) in m and "not used" in m for m in messages), messages


def test_a_velodyne_calibration_for_a_hesai_bag_says_which_file_it_needs():
    with pytest.raises(LidarpktError, match="Velodyne calibration .* takes a Hesai angle-correction CSV"):
        _open(HESAI + "xt32/1673400677802009732", str(external("rust-lidar-utils/VLP16db.yaml")))


def test_ouster_metadata_of_another_sensor_of_the_same_packet_size_says_what_differs():
    with pytest.raises(UnknownSensorError) as info:
        _open(OS + "OS-0-32-U1_v2.2.0_1024x10.pcap", str(external(OS + "OS-0-128-U1_v2.3.0_1024x10.json")))
    text = str(info.value)
    assert "8448 B packets as these are, but their header names another sensor (not init_id 5431292" in text
    assert "but these packets are 8448 B" not in text


def test_legacy_ouster_metadata_of_another_rate_is_said(tmp_path):
    doc = json.loads(external(OS + "OS-1-32-G_v2.1.1_1024x10.json").read_text())
    assert doc["lidar_mode"] == "1024x10"
    doc["lidar_mode"] = "1024x20"
    wrong = tmp_path / "os1-32-1024x20.json"
    wrong.write_text(json.dumps(doc))
    frames, messages, _ = _open(OS + "OS-1-32-G_v2.1.1_1024x10.pcap", str(wrong))
    assert frames and any("says 20 Hz, but its frames take 100 ms (10 Hz)" in m for m in messages), messages
    _, messages, _ = _open(OS + "OS-1-32-G_v2.1.1_1024x10.pcap", str(external(OS + "OS-1-32-G_v2.1.1_1024x10.json")))
    assert not any("Hz" in m for m in messages), messages
    _, messages, _ = _open(OS + "OS-2-32-U0_v2.0.0_1024x10.pcap", str(external(OS + "OS-2-32-U0_v2.0.0_1024x10.json")))
    assert not any("Hz" in m for m in messages), messages  # a 20 Hz capture whose file says 20 Hz
