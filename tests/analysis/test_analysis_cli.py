"""The analysis verbs end to end on real files: the canned fixture captures (checked against their
ground truth) and the external captures; errors are one line on stderr and exit status 2."""

from __future__ import annotations

import importlib
import json
import subprocess
import sys

import numpy as np
import pytest

from lidarpkt.cli import main

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def canned():
    fixtures = importlib.import_module("lidarpkt.fixtures")

    def get(name):
        pcap = fixtures.canned(name)
        return pcap, fixtures.load_truth(pcap)

    return get


def run(argv, capsys):
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def assert_png(path):
    data = path.read_bytes()
    assert data[:8] == PNG and len(data) > 5000, path


def test_analyze_json_has_the_issue_schema_and_the_truth(canned, tmp_path, capsys):
    pcap, truth = canned("vlp16-strongest")
    wall = truth["raypaths"]["wall"]["pixel"][0]
    window = truth["raypaths"]["window"]["pixel"][0]
    out = tmp_path / "a.json"
    code, text, err = run(
        ["analyze", str(pcap), "--pixel", f"{wall[0]},{wall[1]}", "--pixel", f"{window[0]},{window[1]}",
         "--motion-compensation", "--gmm", "auto", "-o", str(out), "--plot", str(tmp_path / "fig")],
        capsys,
    )
    assert code == 0, err
    doc = json.loads(out.read_text())
    k = len(truth["frames"])
    assert set(doc) == {"frames", "pixels"} and doc["frames"] == k
    assert [(p["row"], p["col"]) for p in doc["pixels"]] == [tuple(wall), tuple(window)]
    for entry, name in zip(doc["pixels"], ("wall", "window")):
        assert set(entry) == {"row", "col", "slot", "label", "n_frames", "n_returns", "n_nonreturn", "n_missing",
                              "temporal_cdf", "reflectivity", "spatial_cdf", "motion_compensated", "gmm"}
        assert entry["slot"] == 0 and entry["label"] == "strongest"
        x = np.array(truth["raypaths"][name]["samples"]["range_mm"])[:, 0]
        ret = np.sort(x[x > 0])
        assert entry["n_frames"] == k and entry["n_missing"] == 0
        assert entry["n_returns"] == ret.size and entry["n_nonreturn"] == k - ret.size
        assert entry["temporal_cdf"]["range_m"] == (ret / 1000).tolist()
        assert entry["temporal_cdf"]["F"] == [np.count_nonzero(ret <= v) / k for v in ret]
        assert sorted(entry["reflectivity"]) == sorted(np.array(truth["raypaths"][name]["samples"]["reflectivity"])[x > 0, 0].tolist())
        assert set(entry["spatial_cdf"]) == {"range_m", "F"}
        assert entry["spatial_cdf"]["range_m"] == sorted(entry["spatial_cdf"]["range_m"])
        assert set(entry["motion_compensated"]) == {"offsets", "range_m", "F"} and len(entry["motion_compensated"]["offsets"]) == k
        assert set(entry["gmm"]) == {"method", "weights", "means_m", "sigmas_m", "ks"} and entry["gmm"]["method"] == "auto"
    assert doc["pixels"][0]["gmm"]["means_m"] == pytest.approx([8.0], abs=0.02)
    figs = sorted(p.name for p in (tmp_path / "fig").iterdir())
    assert "range_image.png" in figs and len(figs) == 1 + 2 * 4
    for p in (tmp_path / "fig").iterdir():
        assert_png(p)
    assert "strongest" in text and f"{wall[0]:>4} {wall[1]:>5}" in text


def test_analyze_return_slot_by_label_and_frame_range(canned, tmp_path, capsys):
    pcap, truth = canned("vlp16-dual")
    r, c = truth["raypaths"]["window"]["pixel"][0]
    out = tmp_path / "a.json"
    code, _, err = run(["analyze", str(pcap), "--pixel", f"{r},{c}", "--return", "strongest", "--frames", "2:5",
                        "--gmm", "em", "--neighbourhood", "3", "-o", str(out)], capsys)
    assert code == 0, err
    doc = json.loads(out.read_text())
    entry = doc["pixels"][0]
    # the strongest return of each firing, read from both slots: no single slot holds it
    assert doc["frames"] == 3 and entry["slot"] is None and entry["label"] == "strongest"
    # what the strongest-mode capture of the same firings reports (slot 0 where the decoder marks slot 1
    # as the second strongest, else slot 1), which raw slot 1 is not in these frames
    _, strongest_truth = canned("vlp16-strongest")
    x = np.array(strongest_truth["raypaths"]["window"]["samples"]["range_mm"])[2:5, 0]
    raw1 = np.array(truth["raypaths"]["window"]["samples"]["range_mm"])[2:5, 1]
    assert (raw1 != x).any()  # frame 4: the last return was the strongest, slot 1 the second
    assert entry["temporal_cdf"]["range_m"] == (np.sort(x[x > 0]) / 1000).tolist()
    assert entry["motion_compensated"] is None
    # 3 x 3 neighbourhood of one frame: 9 samples
    # F(r_i) = #{returns ≤ r_i} / 9 (non-returns in the denominator)
    r_m = np.array(entry["spatial_cdf"]["range_m"])
    assert 1 <= len(r_m) <= 9 and np.all(np.diff(r_m) >= 0)
    assert entry["spatial_cdf"]["F"] == [np.count_nonzero(r_m <= x) / 9 for x in r_m]


def test_analyze_ouster_with_metadata(canned, tmp_path, capsys):
    pcap, truth = canned("os1-64-dual")
    r, c = truth["raypaths"]["window"]["pixel"][0]
    out = tmp_path / "o.json"
    code, _, err = run(["analyze", str(pcap), "--metadata", str(pcap.with_suffix(".json")), "--pixel", f"{r},{c}",
                        "--return", "1", "-o", str(out)], capsys)
    assert code == 0, err
    entry = json.loads(out.read_text())["pixels"][0]
    assert entry["label"] == "second_strongest"
    x = np.array(truth["raypaths"]["window"]["samples"]["range_mm"])[:, 1]
    assert entry["temporal_cdf"]["range_m"] == (np.sort(x[x > 0]) / 1000).tolist()


@pytest.mark.parametrize(
    "extra,message",
    [
        (["--pixel", "99,3"], "outside the 16 x 1800 range image"),
        (["--pixel", "3"], "expected ROW,COL"),
        (["--pixel", "3,4", "--return", "2"], "slot 2 does not exist"),
        (["--pixel", "3,4", "--return", "second_strongest"], "is not in this capture"),
        (["--pixel", "3,4", "--frames", "4:2"], "need 0 <= A < B"),
        (["--pixel", "3,4", "--frames", "x"], "expected A:B"),
        (["--pixel", "3,4", "--frames", "40:50"], "no frames in frames 40:50"),
        (["--pixel", "3,4", "--neighbourhood", "4"], "odd"),
        (["--pixel", "3,4", "--gmm", "0.9,0.2"], "increasing CDF values"),
    ],
)
def test_analyze_errors_are_one_actionable_line(canned, capsys, extra, message):
    pcap, _ = canned("vlp16-strongest")
    code, out, err = run(["analyze", str(pcap)] + extra, capsys)
    assert code == 2
    assert err.startswith("lidarpkt: error: ") and message in err and "Traceback" not in err


def test_analyze_missing_file_and_metadata(tmp_path, capsys):
    code, _, err = run(["analyze", str(tmp_path / "none.pcap"), "--pixel", "1,1"], capsys)
    assert code == 2 and "no such file" in err
    code, _, err = run(["analyze", str(tmp_path), "--pixel", "1,1", "--metadata", str(tmp_path / "m.json")], capsys)
    assert code == 2 and "--metadata" in err


def test_analyze_error_from_the_console_script_has_no_traceback(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "lidarpkt", "analyze", str(tmp_path / "x.pcap"), "--pixel", "0,0"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "no such file" in proc.stderr and "Traceback" not in proc.stderr


def test_multireturn_writes_the_map_and_its_figure(canned, tmp_path, capsys):
    pcap, truth = canned("vlp16-dual")
    out = tmp_path / "map.npz"
    code, text, err = run(["multireturn", str(pcap), "-o", str(out), "--plot", str(tmp_path / "figs"), "--return", "last"], capsys)
    assert code == 0, err
    with np.load(out) as z:
        # the returns as the sensor defines them, selected per firing from the two slots
        assert z["n_clusters"].shape == (3, 16, 1800)
        assert z["return_labels"].tolist() == ["last", "strongest", "second_strongest"]
        wall = tuple(truth["raypaths"]["wall"]["pixel"][0])
        assert z["n_clusters"][(0,) + wall] == 1 and z["n_returns"][(0,) + wall] == len(truth["frames"])
        assert z["monitor_flags"].dtype == bool and np.isfinite(z["slot0_auc"])
    assert_png(tmp_path / "figs" / "multireturn_map.png")
    assert "precision" in text and "slot 1 (strongest)" in text


def test_multireturn_method_choice_is_recorded_and_checked(canned, tmp_path, capsys):
    pcap, truth = canned("vlp16-strongest")
    flagged = {}
    for method in (None, "gap", "plane", "row"):
        out = tmp_path / f"{method}.npz"
        code, text, err = run(["multireturn", str(pcap), "-o", str(out)] + ([] if method is None else ["--method", method]), capsys)
        assert code == 0, err
        with np.load(out) as z:
            assert str(z["monitor_method"]) == (method or "detrend")
            assert bool(z["monitor_by_row"]) == (method == "row")
            assert np.array_equal(z["monitor_flags"], z["monitor_score_m"] > 0.1)
            flagged[method] = int(z["monitor_flags"].sum())
        assert f"monitor ({method or 'detrend'})" in text
    assert flagged[None] < flagged["gap"] / 5  # the paper's score flags the ground as well
    with pytest.raises(SystemExit) as exc:
        main(["multireturn", str(pcap), "-o", str(tmp_path / "y.npz"), "--method", "median"])
    assert exc.value.code == 2 and "invalid choice: 'median'" in capsys.readouterr().err


def test_compare_returns_dual_and_two_modes(canned, tmp_path, capsys):
    dual, truth = canned("vlp16-dual")
    out = tmp_path / "c.json"
    r, c = truth["raypaths"]["window"]["pixel"][0]
    code, text, err = run(["compare-returns", str(dual), "-o", str(out), "--plot", str(tmp_path / "d"),
                           "--pixel", f"{r},{c}"], capsys)
    assert code == 0, err
    doc = json.loads(out.read_text())
    assert doc["slots"]["labels"] == ["last", "strongest"]
    samples = np.array(truth["raypaths"]["window"]["samples"]["range_mm"])
    assert doc["raypaths"][0]["cdfs"][0]["range_m"] == (np.sort(samples[samples[:, 0] > 0, 0]) / 1000).tolist()
    assert_png(tmp_path / "d" / "delta_histogram.png")
    assert_png(tmp_path / "d" / f"r{r}_c{c}_modes.png")

    strongest, _ = canned("vlp16-strongest")
    last, _ = canned("vlp16-last")
    out2 = tmp_path / "c2.json"
    code, text, err = run(["compare-returns", str(strongest), str(last), "--paired", "-o", str(out2),
                           "--pixel", f"{r},{c}"], capsys)
    assert code == 0, err
    doc = json.loads(out2.read_text())
    assert doc["modes"]["labels"] == ["strongest", "last"] and doc["paired"]["pairs"] > 0
    assert doc["raypaths"][0]["labels"] == ["strongest", "last"]


def test_compare_returns_on_a_single_return_capture_alone_is_an_error(canned, capsys):
    pcap, _ = canned("vlp16-strongest")
    code, _, err = run(["compare-returns", str(pcap)], capsys)
    assert code == 2 and "give a dual-return capture, or a second capture" in err


def test_not_a_capture_and_an_empty_capture_are_clear_errors(ext, tmp_path, capsys):
    junk = tmp_path / "notes.pcap"
    junk.write_text("these are not packets\n" * 10)
    code, _, err = run(["analyze", str(junk), "--pixel", "0,0"], capsys)
    assert code == 2 and err.startswith("lidarpkt: error: ") and "Traceback" not in err
    empty = ext("ouster-sdk/empty_pcap.pcap")
    code, _, err = run(["multireturn", str(empty), "--metadata", str(ext("ouster-sdk/empty_pcap.json")),
                        "-o", str(tmp_path / "m.npz")], capsys)
    assert code == 2 and "no frames to analyse" in err and not (tmp_path / "m.npz").exists()


def test_compare_returns_picks_slots_of_two_captures(canned, tmp_path, capsys):
    dual, truth = canned("vlp16-dual")
    last, _ = canned("vlp16-last")
    out = tmp_path / "c.json"
    code, _, err = run(["compare-returns", str(dual), str(last), "--return", "last", "--return2", "0", "--paired",
                        "-o", str(out)], capsys)
    assert code == 0, err
    doc = json.loads(out.read_text())
    # the dual capture's last-return slot and the last-mode capture report the same firings
    assert doc["modes"]["labels"] == ["last", "last"] and doc["paired"]["fraction_identical"] == 1.0
    code, _, err = run(["compare-returns", str(dual), str(last), "--return", "second_strongest"], capsys)
    assert code == 2 and "is not in this capture" in err


@pytest.mark.parametrize("name", ["vlp16-dual", "os1-64-dual"])
def test_analyze_mcap_input_gives_the_same_document_as_the_pcap(canned, tmp_path, capsys, name):
    importlib.import_module("lidarpkt.cli.decode")
    pcap, truth = canned(name)
    meta = ["--metadata", str(pcap.with_suffix(".json"))] if name.startswith("os1") else []
    mcap = tmp_path / "x.mcap"
    assert main(["decode", str(pcap), *meta, "-o", str(mcap), "-q"]) == 0
    r, c = truth["raypaths"]["window"]["pixel"][0]
    for src, extra, out in ((pcap, meta, "p.json"), (mcap, [], "m.json")):
        code, _, err = run(["analyze", str(src), *extra, "--pixel", f"{r},{c}", "--return", "1", "-o", str(tmp_path / out)], capsys)
        assert code == 0, err
    assert (tmp_path / "p.json").read_text() == (tmp_path / "m.json").read_text()
