"""``lidarpkt multireturn PATHS... -o OUTDIR`` / ``lidarpkt.archive.multireturn_maps``: one map per
capture equal to the single-capture verb's, and a summary whose fractions are those of the maps."""

from __future__ import annotations

import csv

import numpy as np

from archive_cases import CANNED, lidarpkt_cli


def test_maps_equal_the_single_capture_verb_and_the_summary_says_their_fractions(tmp_path):
    out = tmp_path / "maps"
    bad = tmp_path / "in" / "broken.pcap"
    bad.parent.mkdir()
    bad.write_bytes(b"nope" * 50)
    res = lidarpkt_cli("multireturn", str(CANNED / "vlp16-dual.pcap"), str(CANNED / "os1-64-dual.pcap"), str(bad),
                       "-o", str(out), "--workers", "1", "--metadata", str(CANNED / "os1-64-dual.json"))
    assert res.returncode == 1 and "failed: broken.pcap" in res.stderr, res.stderr
    rows = list(csv.DictReader(open(out / "summary.csv")))
    assert [(r["capture"], r["return_label"]) for r in rows] == [
        ("vlp16-dual.pcap", "last"), ("vlp16-dual.pcap", "strongest"), ("vlp16-dual.pcap", "second_strongest"),
        ("os1-64-dual.pcap", "strongest"),
        ("os1-64-dual.pcap", "second_strongest"), ("broken.pcap", "")]
    assert "broken.pcap" in rows[-1]["error"]
    for name in ("vlp16-dual", "os1-64-dual"):
        single = tmp_path / f"{name}.npz"
        md = ["--metadata", str(CANNED / "os1-64-dual.json")] if name.startswith("os1") else []
        r = lidarpkt_cli("multireturn", str(CANNED / f"{name}.pcap"), "-o", str(single), *md)
        assert r.returncode == 0, r.stderr
        with np.load(out / "maps" / f"{name}.npz") as got, np.load(single) as want:
            assert sorted(got.files) == sorted(want.files)
            for k in want.files:
                np.testing.assert_array_equal(got[k], want[k], err_msg=k)
            for row in (r for r in rows if r["capture"] == f"{name}.pcap"):
                i = int(row["slot"])
                has = want["n_returns"][i] > 0
                assert float(row["multi_return_fraction"]) == np.count_nonzero(want["multi_return"][i]) / has.sum()
                samples, returns = want["n_samples"][i].sum(), want["n_returns"][i].sum()
                assert float(row["nonreturn_fraction"]) == (samples - returns) / samples
                assert int(row["frames_used"]) == want["frame_id"].size
