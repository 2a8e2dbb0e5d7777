"""The analysis verbs on a real capture of every family, through the vendor registry: each gives its result
(exit 0) or says in one line why this capture cannot be analysed (exit 2); never a traceback. In process
(``lidarpkt.cli.main``): an exception that escapes fails the test."""

from __future__ import annotations

import pytest

from lidarpkt.cli import main

from conftest import external

HESAI = "nebula/hesai/"
# family: (capture, sensor file or None)
CAPTURES = {
    "velodyne-hdl32e": ("rust-lidar-utils/velodyne_vlp32.pcap", None),
    "velodyne-vlp16-dual-bag": ("nebula/vlp16/1673400471837873222", None),
    "ouster-dual": ("ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.pcap", "ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.json"),
    "ouster-osf": ("ouster-sdk/single_scan_016.osf", None),
    "hesai-xt32": (HESAI + "xt32/1673400677802009732", HESAI + "PandarXT32.csv"),
    "hesai-xt32m": (HESAI + "xt32m/1660893203042895158", HESAI + "PandarXT32M.csv"),
    "hesai-without-its-csv": (HESAI + "xt32/1673400677802009732", None),
    "robosense-helios": ("nebula/robosense/helios16p/rosbag2_2023_08_03-11_02_46", None),
}
VERBS = {
    "analyze": ["--pixel", "5,100"],
    "multireturn": ["-o", "{tmp}/map.npz"],
    "compare-returns": [],
    "registration-impact": ["--algorithm", "icp_point_to_point", "--mode", "scan_to_scan"],
}


@pytest.mark.parametrize("family", list(CAPTURES))
def test_the_analysis_verbs_work_on_every_family_or_say_why_in_one_line(family, tmp_path, capsys):
    capture, sensor_file = CAPTURES[family]
    argv_sensor = ["--metadata", str(external(sensor_file))] if sensor_file else []
    results = {}
    for verb, extra in VERBS.items():
        status = main([verb, str(external(capture)), *argv_sensor, *[a.format(tmp=tmp_path) for a in extra]])
        err = capsys.readouterr().err
        errors = [ln for ln in err.splitlines() if ln.startswith("lidarpkt: error: ")]
        assert status in (0, 2), (family, verb, status, err)
        assert "Traceback" not in err and "  File " not in err, (family, verb, err)
        assert len(errors) == (status == 2), (family, verb, err)
        if status == 2:
            assert "; " in errors[0] or " (" in errors[0], (family, verb, errors[0])  # what to do
        results[verb] = status
    if family == "hesai-without-its-csv":  # points need the angles; the image analysis does not
        assert results["registration-impact"] == 2 and results["analyze"] == 0
    elif family != "ouster-osf":
        assert results["analyze"] == results["multireturn"] == 0, results
    if family in ("hesai-xt32", "velodyne-hdl32e"):
        assert results["registration-impact"] == 0, results
