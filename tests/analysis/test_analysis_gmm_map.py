"""Probabilistic raypath maps (issue 17 §4): the per-pixel mixture equals the per-raypath GMM
(analysis.gmm.fit_em) on the pixels picked, round-trips through NPZ and Parquet (read back by
pyarrow and DuckDB), and serves as registration-impact's map."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from lidarpkt.analysis.cdf import temporal_cdf
from lidarpkt.analysis.gmm import fit_em
from lidarpkt.analysis.gmm_map import fit_gmm_map, load_gmm_map
from lidarpkt.cli import main
from test_analysis_cli import canned  # noqa: F401  (a fixture)
from test_analysis_support import load_fixture, make_stack


def _crop(stack, a: int, b: int):
    """Columns a..b-1 of a stack without a stagger (a smaller image, the same raypaths)."""
    return replace(stack, range_mm=stack.range_mm[..., a:b], reflectivity=stack.reflectivity[..., a:b],
                   column_valid=stack.column_valid[:, a:b], column_timestamp_ns=stack.column_timestamp_ns[:, a:b],
                   azimuth_deg=stack.azimuth_deg[:, a:b])


@pytest.fixture(scope="module")
def scene():
    stack, truth = load_fixture("vlp16-strongest", frames=50, aux=False)
    a, b = 1000, 1300  # holds the window (col 1249) and the foliage (col 1049) raypaths
    return _crop(stack, a, b), truth, a


def _assert_same(gm, stack, slot, r, c):
    cdf = temporal_cdf(stack, r, c, slot)
    if cdf.n_returns == 0:
        assert gm.n_components[slot, r, c] == 0 and not gm.weights[slot, :, r, c].any()
        return
    f = fit_em(cdf, max_components=gm.max_components)
    m = f.n_components
    assert gm.n_components[slot, r, c] == m, (r, c)
    np.testing.assert_allclose(gm.weights[slot, :m, r, c], f.weights, rtol=0, atol=1e-9)
    np.testing.assert_allclose(gm.means_m[slot, :m, r, c], f.means_m, rtol=0, atol=1e-9)
    np.testing.assert_allclose(gm.sigmas_m[slot, :m, r, c], f.sigmas_m, rtol=0, atol=1e-9)
    assert np.all(np.isnan(gm.means_m[slot, m:, r, c])) and not gm.weights[slot, m:, r, c].any()
    assert gm.n_samples[slot, r, c] == cdf.n_samples and gm.n_returns[slot, r, c] == cdf.n_returns


def test_the_map_equals_the_per_raypath_gmm(scene):
    stack, truth, a = scene
    gm = fit_gmm_map(stack)
    assert gm.weights.shape == (1, 4, 16, 300)
    counts = np.bincount(gm.n_components.ravel(), minlength=5)
    assert counts[2:].sum() > 50  # multi-component raypaths to compare
    named = [(r, c - a) for r, c in (v["pixel"][0] for v in truth["raypaths"].values()) if a <= c < a + 300]
    assert len(named) >= 2
    rng = np.random.default_rng(0)
    picked = named
    for m in range(5):
        where = np.argwhere(gm.n_components[0] == m)
        picked += [tuple(p) for p in where[rng.permutation(len(where))[:12]]]
    for r, c in picked:
        _assert_same(gm, stack, 0, int(r), int(c))
    # weights are shares of the samples: they add up to the return fraction
    total = np.nansum(gm.weights[0], axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        np.testing.assert_allclose(total, np.nan_to_num(gm.n_returns[0] / gm.n_samples[0]), atol=1e-12)


def test_a_two_surface_raypath_and_a_pixel_with_no_sample():
    rng = np.random.default_rng(3)
    k = 40
    near = rng.normal(8000, 8, k)
    far = rng.normal(9500, 8, k)
    x = np.where(rng.random(k) < 0.3, far, near).round()
    ranges = np.zeros((k, 1, 2, 3))
    ranges[:, 0, 0, 0] = x
    ranges[:, 0, 0, 1] = rng.normal(5000, 5, k).round()
    ranges[::4, 0, 0, 1] = 0  # a quarter non-returns
    valid = np.ones((k, 3), bool)
    valid[:, 2] = False  # a column never seen: no sample
    st = make_stack(ranges, valid=valid, labels=("strongest",))
    gm = fit_gmm_map(st)
    assert gm.n_components[0, 0, 0] == 2 and gm.n_components[0, 0, 1] == 1 and gm.n_components[0, 0, 2] == 0
    np.testing.assert_allclose(gm.means_m[0, :2, 0, 0], [x[x < 9000].mean() / 1000, x[x > 9000].mean() / 1000], atol=1e-3)
    assert gm.weights[0, 0, 0, 1] == pytest.approx(0.75)
    assert gm.n_samples[0, 0, 2] == 0
    for c in range(2):
        _assert_same(gm, st, 0, 0, c)


@pytest.mark.parametrize("suffix", [".npz", ".parquet"])
def test_files_round_trip_and_are_readable_by_their_readers(scene, tmp_path, suffix):
    stack, _, _ = scene
    gm = fit_gmm_map(_crop(stack, 200, 260))
    path = gm.save(tmp_path / f"map{suffix}")
    back = load_gmm_map(path)
    for name in ("weights", "means_m", "sigmas_m", "n_components", "n_samples", "n_returns"):
        np.testing.assert_array_equal(getattr(back, name), getattr(gm, name), err_msg=name)
    assert back.return_labels == gm.return_labels and back.max_components == 4
    if suffix == ".parquet":
        pq = pytest.importorskip("pyarrow.parquet")
        t = pq.read_table(path)
        assert t.num_rows == 16 * 60 and {"row", "col", "return", "weight_0", "mean_m_3", "sigma_m_1"} <= set(t.column_names)
        duckdb = pytest.importorskip("duckdb")
        n_multi = duckdb.sql(f"select count(*) from read_parquet('{path}') where n_components >= 2").limit(1).fetchall()[0][0]
        assert n_multi == int((gm.n_components >= 2).sum())


def test_multireturn_writes_the_map_and_registration_uses_it(canned, tmp_path, capsys):  # noqa: F811
    pytest.importorskip("small_gicp")
    pcap, _ = canned("vlp16-strongest")
    gpath = tmp_path / "g.npz"
    assert main(["multireturn", str(pcap), "-o", str(tmp_path / "m.npz"), "--gmm-map", str(gpath), "--gmm-components", "3"]) == 0
    text = capsys.readouterr().err  # status lines go to stderr
    assert f"wrote {gpath}" in text
    gm = load_gmm_map(gpath)
    assert gm.max_components == 3 and gm.weights.shape == (1, 3, 16, 1800)
    out = tmp_path / "r.json"
    assert main(["registration-impact", str(pcap), "--map", str(gpath), "--algorithm", "icp_point_to_plane",
                 "--mode", "scan_to_map", "-o", str(out), "-q"]) == 0
    doc = json.loads(out.read_text())
    assert doc["map"] == "gmm_map"
    c = doc["algorithms"]["icp_point_to_plane_scan_to_map"]["conditions"]["all"]
    assert c["frames"] == 5 and c["translation_m"]["max"] < 0.05
    code = main(["multireturn", str(pcap), "-o", str(tmp_path / "x.npz"), "--gmm-map", str(tmp_path / "g.csv")])
    assert code == 2 and "the accepted suffixes are .npz, .parquet" in capsys.readouterr().err
    assert not (tmp_path / "x.npz").exists()
