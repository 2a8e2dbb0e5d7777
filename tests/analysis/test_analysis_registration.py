"""``registration-impact`` (issue 17 §3) where the answer is known: a generated static scene (true
motion: none) without multi-return raypaths, and the same scene with multi-return raypaths
injected, registered by small_gicp; then a real capture through the CLI."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

pytest.importorskip("small_gicp", reason="registration-impact needs the registration extra (small_gicp)")

from lidarpkt.analysis.multireturn import image_statistics  # noqa: E402
from lidarpkt.analysis.registration import CONDITIONS, pose_error, registration_impact  # noqa: E402
from lidarpkt.analysis.stack import select_frames  # noqa: E402
from lidarpkt.cli import main  # noqa: E402
from test_analysis_cli import assert_png, canned  # noqa: E402,F401  (canned: a fixture)
from test_analysis_support import load_fixture  # noqa: E402

FRAMES = 10
ALGS = ("icp_point_to_point", "icp_point_to_plane")


@pytest.fixture(scope="module")
def scenes():
    """(without, with) multi-return raypaths: the generated courtyard with its own multi-return
    raypaths made single (every frame reports frame 0's range there), then 1,647 wall pixels on
    one side turned into multi-return raypaths: in each frame, each patch of 100 columns reports
    either the wall or a surface 0.3 m behind it (a pane or a hedge seen through)."""
    stack = select_frames(load_fixture("vlp16-strongest", frames=50, aux=False)[0], 0, FRAMES)
    multi = image_statistics(stack).multi_return[0]
    rng = stack.range_mm.copy()
    rng[:, 0][:, multi] = rng[0, 0][multi]
    without = replace(stack, range_mm=rng)
    block = np.zeros(multi.shape, bool)
    block[2:14, 100:500] = True
    block &= (rng[0, 0] > 2000) & (rng[0, 0] < 20000)
    state = np.random.default_rng(1).random((FRAMES, 18)) < 0.5
    far = state[:, np.arange(multi.shape[1]) // 100]  # [K, W]: the patch of each column shows the far surface
    injected = rng.copy()
    injected[:, 0] = np.where(block[None] & far[:, None, :], rng[:, 0] + 300, rng[:, 0])
    return without, replace(stack, range_mm=injected), block


def _median(impact, alg, mode, cond):
    return float(np.median(impact.errors[alg][mode][cond].translation_m))


def test_injected_multireturn_raypaths_cause_error_that_removing_them_takes_away(scenes):
    without, with_multi, block = scenes
    clean = registration_impact(without, algorithms=ALGS, modes=("scan_to_scan",))
    dirty = registration_impact(with_multi, algorithms=ALGS, modes=("scan_to_scan",))
    # the temporal statistics find the injected raypaths (and nothing in the clean scene)
    assert clean.removed_fraction["multireturn_removed"] == 0.0
    assert dirty.removed_fraction["multireturn_removed"] > 0.05
    for alg in ALGS:
        e_all, e_removed = clean.errors[alg]["scan_to_scan"]["all"], clean.errors[alg]["scan_to_scan"]["multireturn_removed"]
        # without multi-return raypaths, removing them removes nothing and changes nothing
        assert e_removed.points_removed == 0
        assert np.array_equal(e_all.translation_m, e_removed.translation_m)
        assert np.array_equal(e_all.rotation_deg, e_removed.rotation_deg)
        assert e_all.frame.tolist() == list(range(1, FRAMES))
    # with them, point-to-point ICP is pulled off the truth, and removing them restores the clean error
    p2p = "icp_point_to_point"
    d_all, d_removed = _median(dirty, p2p, "scan_to_scan", "all"), _median(dirty, p2p, "scan_to_scan", "multireturn_removed")
    c_all = _median(clean, p2p, "scan_to_scan", "all")
    assert d_all > 3 * d_removed and d_all > 3 * c_all
    assert d_removed < 2 * c_all
    doc = dirty.to_json()
    entry = doc["algorithms"]["icp_point_to_point_scan_to_scan"]["conditions"]
    assert set(entry) == set(CONDITIONS)
    assert entry["all"]["translation_m"]["median"] == pytest.approx(d_all)
    assert entry["multireturn_removed"]["points_removed"] > 0.9 * block.sum() * (FRAMES - 1)


def test_pose_error_of_known_poses():
    t = np.eye(4)
    assert pose_error(t) == (0.0, 0.0)
    a = np.radians(2.0)
    t[:3, :3] = [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]
    t[:3, 3] = [0.003, -0.004, 0.0]
    tr, rot = pose_error(t)
    assert tr == pytest.approx(0.005) and rot == pytest.approx(2.0)


def test_cli_on_a_real_capture_writes_the_documented_json_table_and_figures(ext, tmp_path, capsys):
    pcap = ext("veloview/vlp-16-test-90deg-1-50-frames.pcap")
    out = tmp_path / "r.json"
    code = main(["registration-impact", str(pcap), "--frames", "0:5", "-o", str(out), "--plot", str(tmp_path / "fig")])
    text, err = capsys.readouterr()
    assert code == 0, err
    doc = json.loads(out.read_text())
    assert doc["frames"] == 5 and doc["monitor_method"] == "detrend"
    names = {f"{a}_{m}" for a in ("icp_point_to_point", "icp_point_to_plane", "vgicp") for m in ("scan_to_scan", "scan_to_map")}
    assert set(doc["algorithms"]) == names
    for name, entry in doc["algorithms"].items():
        assert set(entry["conditions"]) == {"all", "monitor_removed", "multireturn_removed"}
        for cond, c in entry["conditions"].items():
            assert {"translation_m", "rotation_deg", "frames", "points_removed"} <= set(c)
            for q in ("translation_m", "rotation_deg"):
                assert set(c[q]) == {"median", "p95", "max"}
                assert 0 <= c[q]["median"] <= c[q]["p95"] <= c[q]["max"]
            assert c["frames"] == (4 if name.endswith("scan_to_scan") else 5)
            assert (c["points_removed"] == 0) == (cond == "all")
        # a static sensor: ICP stays within centimetres of no motion
        if entry["algorithm"] != "vgicp":
            assert entry["conditions"]["all"]["translation_m"]["max"] < 0.05
    assert "icp_point_to_plane" in text and "multireturn_removed" in text
    for name in ("registration_translation_cdf.png", "registration_rotation_cdf.png"):
        assert_png(tmp_path / "fig" / name)
    # --json without a file: the document alone on stdout
    code = main(["registration-impact", str(pcap), "--frames", "0:3", "--algorithm", "icp_point_to_point",
                 "--mode", "scan_to_scan", "--json"])
    text, err = capsys.readouterr()
    assert code == 0, err
    assert set(json.loads(text)["algorithms"]) == {"icp_point_to_point_scan_to_scan"}


@pytest.mark.parametrize(
    "extra,message",
    [
        (["--downsample", "0"], "--downsample 0: out of range; --downsample takes a number in (0, 100] metres"),
        (["--workers", "0"], "--workers 0: out of range; --workers takes a whole number in [1, 1024]"),
        (["--return", "loudest"], "--return 'loudest'"),
        (["--neighbourhood", "4"], "--neighbourhood 4"),
    ],
)
def test_cli_errors_are_one_line_and_exit_2(canned, tmp_path, capsys, extra, message):
    pcap, _ = canned("vlp16-strongest")
    code = main(["registration-impact", str(pcap), "-o", str(tmp_path / "x.json"), *extra])
    _, err = capsys.readouterr()
    assert code == 2 and message in err and err.startswith("lidarpkt: error: ")
    assert not (tmp_path / "x.json").exists()
