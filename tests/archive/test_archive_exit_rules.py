"""catalog and export share their exit rule (1 when a file failed, the output holding the others); catalog
states no profile it cannot know and gives each stream's row its own error; a rosbag2 folder is one capture
for multireturn as for every verb."""

from __future__ import annotations

import json
import shutil

from lidarpkt.cli import main

from conftest import external

OS0 = "ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.pcap"
VLP10 = "rust-lidar-utils/velodyne_example.pcap"


def test_catalog_and_export_exit_1_when_a_file_failed_and_say_no_profile_they_cannot_know(tmp_path, capsys):
    alone = tmp_path / "alone.pcap"  # no metadata beside it: its profile cannot be known
    shutil.copy(external(OS0), alone)
    good = tmp_path / "good.pcap"
    shutil.copy(external(VLP10), good)
    assert main(["catalog", str(alone), str(good), "-o", str(tmp_path / "c.json"), "--workers", "1", "-q"]) == 1
    assert "1 with errors" in capsys.readouterr().err
    rows = json.loads((tmp_path / "c.json").read_text())
    ouster = {r["kind"]: r for r in rows if r["path"].endswith("alone.pcap")}
    assert ouster["Ouster lidar"]["mode"] is None and "no Ouster metadata was given" in ouster["Ouster lidar"]["error"]
    assert ouster["Ouster IMU"]["error"] is None  # the lidar stream's error is not the IMU's
    assert all(r["error"] is None for r in rows if r["path"].endswith("good.pcap"))
    assert main(["export", str(alone), str(good), "-o", str(tmp_path / "ex"), "--format", "npz", "--workers", "1",
                 "-q"]) == 1
    assert main(["catalog", str(good), "-o", str(tmp_path / "g.json"), "--workers", "1", "-q"]) == 0


def test_a_rosbag2_folder_is_one_capture_for_multireturn(tmp_path, capsys):
    bag = external("nebula/vlp16/1673400471837873222")
    out = tmp_path / "map.npz"
    assert main(["multireturn", str(bag), "-o", str(out), "--plot", str(tmp_path / "figs")]) == 0
    assert out.is_file() and (tmp_path / "figs" / "multireturn_map.png").is_file()
    assert "1673400471837873222 (VLP-16, dual): 3 frames of 16x1800" in capsys.readouterr().out  # the whole rotations
