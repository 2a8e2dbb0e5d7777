"""`lidarpkt demo` end to end, as a user runs it: a real subprocess, output checked against the scene's ground truth."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lidarpkt import fixtures
from lidarpkt.core.dual import second_strongest_mark

REPO = Path(__file__).resolve().parents[2]
FRAMES = 4


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    proc = subprocess.run(
        [sys.executable, "-m", "lidarpkt", "demo", "-o", str(out), "--frames", str(FRAMES)],
        capture_output=True, text=True, cwd=REPO, timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    return out, proc.stdout, json.loads((out / "summary.json").read_text())


def test_demo_writes_mcap_figures_and_summary_for_every_capture(demo):
    out, stdout, summary = demo
    from lidarpkt.fixtures import CAPTURES

    assert sorted(summary["captures"]) == sorted(CAPTURES)
    for name in CAPTURES:
        assert (out / f"{name}.mcap").stat().st_size > 0
        assert (out / f"{name}-range-image.png").stat().st_size > 10_000
        assert (out / f"{name}-multireturn-map.png").stat().st_size > 10_000
    assert (out / "vlp16-window-modes.png").exists()
    assert "raypath" in stdout and "GMM means" in stdout


def test_demo_table_counts_the_ground_truth_returns(demo):
    _, _, summary = demo
    checked = 0
    for row in summary["raypaths"]:
        pcap = fixtures.ensure(row["capture"], frames=FRAMES)
        truth = fixtures.load_truth(pcap)
        on_wire = truth["raypaths"][row["raypath"]]["samples"]
        rng, refl = np.array(on_wire["range_mm"]), np.array(on_wire["reflectivity"])
        if truth["return_labels"] == ["last", "strongest"]:
            # VLP-16 dual, returns per firing: slot 1 holds the second strongest where the decoder
            # marks it (the last return has the higher signal, reflectivity / range²), else the strongest
            marked = second_strongest_mark(rng.T, refl.T)
            sample = {"last": np.ones(FRAMES, bool), "strongest": np.ones(FRAMES, bool),
                      "second_strongest": marked | (rng[:, 1] == rng[:, 0])}[row["slot"]]
            samples = {"last": rng[:, 0], "strongest": np.where(marked, rng[:, 0], rng[:, 1]),
                       "second_strongest": np.where(marked, rng[:, 1], 0)}[row["slot"]][sample]
        else:
            samples = rng[:, truth["return_labels"].index(row["slot"])]
        assert row["frames"] == samples.size
        assert row["returns"] == int(np.count_nonzero(samples)), row
        checked += 1
    assert checked == 8 * (1 + 1 + 3 + 1 + 2)  # 8 raypaths × returns of the five captures


def test_demo_gmm_finds_the_single_surfaces(demo):
    _, _, summary = demo
    for row in summary["raypaths"]:
        if row["raypath"] == "sign" and row["slot"] in ("strongest", "last"):
            assert row["clusters"] == 1
            assert row["gmm_means_m"] == pytest.approx([7.3], abs=0.02)
        if row["raypath"] == "sky":
            assert row["returns"] == 0 and row["gmm_means_m"] == []
