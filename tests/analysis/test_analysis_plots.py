"""Every figure type is produced, as a Figure with the expected axes, titles and PNG output (not pixels)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("matplotlib", reason="plots need the `plot` extra (matplotlib)")

from lidarpkt.analysis import plots  # noqa: E402
from lidarpkt.analysis.compare import compare_slots  # noqa: E402
from lidarpkt.analysis.multireturn import multireturn_map  # noqa: E402
from lidarpkt.analysis.raypath import analyze_raypath  # noqa: E402
from lidarpkt.errors import AnalysisError  # noqa: E402

from test_analysis_support import make_stack

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def stack():
    rng = np.random.default_rng(0)
    k, h, w = 12, 8, 40
    base = np.linspace(4000, 20000, h * w).reshape(h, w)
    r = np.broadcast_to(base, (k, 2, h, w)) + rng.normal(0, 15, (k, 2, h, w))
    pick = rng.random(k) < 0.6
    r[:, 0, 4, 10] = np.where(pick, 9000, 11500) + rng.normal(0, 20, k)  # a two-cluster raypath
    r[rng.random(r.shape) < 0.05] = 0
    refl = rng.integers(5, 200, size=r.shape)
    return make_stack(np.round(r).astype(np.uint32), reflectivity=refl)


def labels(ax):
    return ax.get_xlabel(), ax.get_ylabel()


def check_png(fig, path):
    plots.save(fig, path)
    data = path.read_bytes()
    assert data[:8] == PNG and len(data) > 5000


def test_raypath_figures(stack, tmp_path):
    ra = analyze_raypath(stack, 4, 10, 0, neighbourhood=3, motion_compensation=True, gmm="auto")
    fig = plots.plot_temporal_cdf(ra, "test.pcap (VLP-16, dual)")
    ax, ax2 = fig.axes[:2]
    assert labels(ax) == ("range r (m)", "CDF F(r)")
    assert ax2.get_ylabel().startswith("reflectivity")
    assert "row 4, col 10" in ax.get_title() and "last" in ax.get_title() and "test.pcap" in ax.get_title()
    check_png(fig, tmp_path / "t.png")

    fig = plots.plot_temporal_vs_spatial(ra)
    legend = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert any("spatial 3×3, first frame" in t for t in legend) and any("all frames" in t for t in legend)
    check_png(fig, tmp_path / "ts.png")

    fig = plots.plot_motion_compensation(ra)
    assert labels(fig.axes[0]) == ("range r (m)", "CDF F(r)")
    assert labels(fig.axes[1]) == ("frame (stack index)", "chosen offset (pixels)")
    check_png(fig, tmp_path / "mc.png")

    fig = plots.plot_gmm(ra)
    assert fig.axes[0].get_ylabel() == "density p(r) (1/m)"
    assert labels(fig.axes[1]) == ("range r (m)", "CDF F(r)")
    assert "KS distance" in " ".join(t.get_text() for t in fig.axes[1].get_legend().get_texts())
    check_png(fig, tmp_path / "g.png")


def test_image_figures(stack, tmp_path):
    fig = plots.plot_range_image(stack, 0, 1, [(4, 10), (0, 39)], "test.pcap")
    assert labels(fig.axes[0]) == ("column (azimuth step)", "row (beam, 0 = top)")
    assert "strongest return" in fig.axes[0].get_title()
    check_png(fig, tmp_path / "ri.png")

    mr = multireturn_map(stack, neighbourhood=3)
    fig = plots.plot_multireturn_map(mr, stack, 0, "test.pcap")
    titles = [ax.get_title() for ax in fig.axes]
    assert any(t.startswith("Clusters per raypath") for t in titles)
    assert any(t.startswith("Monitor 'detrend' (3×3, gap about local planes) on frame 0") and "precision" in t for t in titles)
    mr_paper = multireturn_map(stack, neighbourhood=3, method="gap")
    titles = [ax.get_title() for ax in plots.plot_multireturn_map(mr_paper, stack, 0, "test.pcap").axes]
    assert any(t.startswith("Monitor 'gap' (3×3 spatial CDF gap, the paper's)") for t in titles)
    check_png(fig, tmp_path / "map.png")

    fig = plots.plot_roc(mr.evaluation[0])
    assert labels(fig.axes[0]) == ("false-positive rate", "true-positive rate (recall)")
    check_png(fig, tmp_path / "roc.png")

    pc = compare_slots(stack)
    fig = plots.plot_delta_histogram(pc, "test.pcap")
    assert fig.axes[0].get_xlabel().startswith("Δ = |r(last) − r(strongest)|")
    check_png(fig, tmp_path / "dh.png")


def test_mode_cdfs_and_ouster_range_image(tmp_path):
    shift = np.array([0, 6, 12, 18])
    r = np.random.default_rng(1).integers(3000, 9000, size=(3, 1, 4, 32)).astype(np.uint32)
    st = make_stack(r, shift=shift)
    fig = plots.plot_range_image(st, 0, 0, [(1, 3)])
    assert fig.axes[0].get_xlabel() == "column (azimuth step, destaggered)"
    # the marker of staggered pixel (1, 3) sits at destaggered column 3 + 6
    marker = [line for line in fig.axes[0].get_lines() if line.get_marker() == "s"][0]
    assert marker.get_xdata()[0] == 9 and marker.get_ydata()[0] == 1
    from lidarpkt.analysis.cdf import temporal_cdf

    fig = plots.plot_mode_cdfs({"strongest": temporal_cdf(st, 1, 3), "last": temporal_cdf(st, 1, 4)}, 1, 3, ks=0.25)
    assert "KS distance 0.250" in fig.axes[0].get_title()
    check_png(fig, tmp_path / "m.png")


def test_missing_parts_raise_analysis_errors(stack):
    ra = analyze_raypath(stack, 4, 10, 0, gmm=None)
    with pytest.raises(AnalysisError, match="--motion-compensation"):
        plots.plot_motion_compensation(ra)
    with pytest.raises(AnalysisError, match="no Gaussian mixture"):
        plots.plot_gmm(ra)
