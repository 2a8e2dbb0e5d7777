"""The analysis on every real third-party capture (few frames: spatial CDFs and the map; the VeloView
50-frame capture: temporal statistics), and the spatial CDF of real Ouster frames against a hand
computation on ouster-sdk's own decoded and destaggered range images."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from lidarpkt.analysis.returns import available_returns, sample_mask, select_returns
from lidarpkt.analysis.cdf import RangeCDF, spatial_cdf, temporal_cdf
from lidarpkt.analysis.multireturn import image_statistics, multireturn_map
from lidarpkt.analysis.stack import load_stack
from lidarpkt.cli import main

E_OUSTER = [
    ("ouster-sdk/OS-1-64_1024x10_fw20.pcap", "ouster-sdk/OS-1-64_sensor_config_reduced.json"),
    ("ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.pcap", "ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.json"),
    ("ouster-sdk/OS-0-32-U1_v2.2.0_1024x10-single-packet.pcap", "ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.json"),
    ("ouster-sdk/OS-1-32-G_v2.1.1_1024x10.pcap", "ouster-sdk/OS-1-32-G_v2.1.1_1024x10.json"),
    ("ouster-sdk/OS-2-32-U0_v2.0.0_1024x10.pcap", "ouster-sdk/OS-2-32-U0_v2.0.0_1024x10.json"),
    ("ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.pcap", "ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.json"),
    ("ouster-sdk/OS-0-128-U1_v2.3.0_1024x10.pcap", "ouster-sdk/OS-0-128-U1_v2.3.0_1024x10.json"),
    ("ouster-sdk/crc_test.pcap", "ouster-sdk/crc_test.json"),
    ("ouster-sdk/duplicate_id.pcap", "ouster-sdk/duplicate_id.json"),
    ("ouster-sdk/same_ports_legacy.pcap", "ouster-sdk/same_ports_legacy.1.json"),
    ("ouster-sdk/same_ports_nonlegacy.pcap", "ouster-sdk/same_ports_nonlegacy.1.json"),
    ("rust-lidar-utils/ouster_example.pcap", "rust-lidar-utils/ouster_example.json"),
]
E_VELODYNE = [
    ("rust-lidar-utils/velodyne_example.pcap", None),
    ("rust-lidar-utils/velodyne_vlp16.pcap", None),
    ("veloview/vlp-16-test-90deg-1-50-frames.pcap", None),
    ("nebula/vlp16/1673400471837873222/1673400471837873222_0.db3", None),
]
ALL = E_OUSTER + E_VELODYNE


def pixel_with_return(stack, slot=0):
    """A pixel near the middle row whose column is valid and holds a return in frame 0."""
    h = stack.range_mm.shape[2]
    for row in [h // 2] + list(range(h)):
        cols = np.flatnonzero((stack.range_mm[0, slot, row] > 0) & stack.column_valid[0])
        if cols.size:
            return row, int(cols[cols.size // 2])
    pytest.fail("no return in frame 0")


@pytest.mark.parametrize("pcap,meta", ALL, ids=[p.split("/")[-1] for p, _ in ALL])
def test_analysis_runs_on_every_real_capture(ext, tmp_path, capsys, pcap, meta):
    path = ext(pcap)
    meta_args = ["--metadata", str(ext(meta))] if meta else []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # partial-frame fallback and decoder skips are reported, not failures
        stack = load_stack(path, metadata=ext(meta) if meta else None)
    row, col = pixel_with_return(stack)
    out = tmp_path / "a.json"
    code = main(["analyze", str(path), *meta_args, "--pixel", f"{row},{col}", "-o", str(out)])
    text, err = capsys.readouterr()
    assert code == 0, err
    entry = json.loads(out.read_text())["pixels"][0]
    k = len(stack)
    assert entry["n_frames"] + entry["n_missing"] == k
    assert entry["n_returns"] + entry["n_nonreturn"] == entry["n_frames"] >= 1
    sp = entry["spatial_cdf"]
    assert len(sp["range_m"]) >= 1 and sp["range_m"] == sorted(sp["range_m"]) and 0 < sp["F"][-1] <= 1
    assert stack.range_mm[0, 0, row, col] / 1000 in sp["range_m"]  # the pixel itself is in its neighbourhood
    # the map: every pixel's samples are its column's valid frames
    npz = tmp_path / "m.npz"
    assert main(["multireturn", str(path), *meta_args, "-o", str(npz)]) == 0
    capsys.readouterr()
    kinds = select_returns(stack, available_returns(stack))  # what multireturn maps
    samples = sample_mask(kinds)
    with np.load(npz) as z:
        n_samples = z["n_samples"]
        assert n_samples.shape == kinds.range_mm.shape[1:]
        assert np.array_equal(n_samples, samples.sum(axis=0))
        assert np.array_equal(z["n_returns"], ((kinds.range_mm > 0) & samples).sum(axis=0))
        assert np.all(z["n_clusters"] <= z["n_returns"])


def test_veloview_capture_temporal_statistics(ext, capsys):
    path = ext("veloview/vlp-16-test-90deg-1-50-frames.pcap")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        stack = load_stack(path)
    # vlp-16.test: VeloView counts 52 frames, the first and last partial
    assert len(stack) == 50
    # 20 Hz: firing sequences 0.4° apart, so the analysis grid is 0.4° (900 columns), nearly all filled
    assert stack.range_mm.shape == (50, 1, 16, 900)
    assert stack.column_valid.mean() > 0.98
    stats = image_statistics(stack)
    with_returns = stats.n_returns[0] > 0
    assert with_returns.mean() > 0.9
    assert np.nanmedian(stats.std_m[0][stats.n_clusters[0] == 1]) < 0.05  # single surfaces: cm-level noise
    assert int(stats.multi_return[0].sum()) == 1448  # of 14400 raypaths (measured on the one grid; the temporal truth is exact)
    row, col = pixel_with_return(stack)
    cdf = temporal_cdf(stack, row, col)
    assert cdf.n_samples + cdf.n_missing == 50
    mr = multireturn_map(stack)
    ev = mr.evaluation[0]
    assert ev.n_pixels == int(with_returns.sum()) == 14348
    # what the default monitor reaches on this real scene (measured): AUC 0.715, precision 0.548, recall 0.376
    assert ev.auc == pytest.approx(0.7153, abs=0.005)
    assert ev.precision == pytest.approx(0.5483, abs=0.01) and ev.recall == pytest.approx(0.3764, abs=0.01)


@pytest.mark.crosscheck
@pytest.mark.parametrize("pcap,meta", [c for c in E_OUSTER if "duplicate" not in c[0]], ids=lambda v: v.split("/")[-1])
def test_spatial_cdf_matches_ouster_sdk_destaggered_frames(ext, pcap, meta):
    sdk_pcap = pytest.importorskip("ouster.sdk.pcap")
    core = pytest.importorskip("ouster.sdk.core")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        src = sdk_pcap.PcapFrameSetSource(str(ext(pcap)), meta=[str(ext(meta))])
        sdk = [fs[0] for fs in src if fs[0] is not None][0]
        info = src.sensor_info[0]
        stack = load_stack(ext(pcap), metadata=ext(meta), include_partial=True)
    rng = core.destagger(info, sdk.field("RANGE"))  # the SDK's own destaggering
    valid = core.destagger(info, np.broadcast_to(sdk.status.astype(bool) if sdk.status.dtype != bool else sdk.status,
                                                 rng.shape).astype(np.uint8)).astype(bool)
    h, w = rng.shape
    shift = np.asarray(info.format.pixel_shift_by_row)
    rs = np.random.default_rng(0)
    for row, col in [(0, 0), (h - 1, w - 1), (h // 2, 3)] + [tuple(x) for x in rs.integers(0, [h, w], size=(6, 2))]:
        for n in (3, 5):
            d = (col + shift[row]) % w  # where the staggered pixel sits in the destaggered image
            vals = [int(rng[r, (d + dc) % w]) for r in range(max(0, row - n // 2), min(h, row + n // 2 + 1))
                    for dc in range(-(n // 2), n // 2 + 1) if valid[r, (d + dc) % w]]
            want = RangeCDF.from_samples(np.array(vals, np.uint32))
            got = spatial_cdf(stack, row, col, 0, n=n, frame=0)
            assert np.array_equal(got.range_m, want.range_m) and np.array_equal(got.F, want.F), (row, col, n)


def test_capture_without_a_complete_frame_falls_back_to_partial_frames(ext):
    from lidarpkt.errors import LidarpktWarning

    path = ext("rust-lidar-utils/velodyne_example.pcap")  # about 1.1 rotations: no whole frame
    with pytest.warns(LidarpktWarning, match="no complete frame, analysing 2 partial frame"):
        stack = load_stack(path)
    assert len(stack) == 2 and 0.3 < stack.column_valid.mean() < 0.8
    with pytest.warns(LidarpktWarning):
        assert len(load_stack(path, frames=(1, None))) == 1


@pytest.mark.parametrize("pcap", ["ouster-sdk/VLI-16-one-packet.pcap", "einride-vlp16-go/recording.bin"])
def test_captures_of_other_sensors_or_formats_are_refused_in_one_line(ext, tmp_path, capsys, pcap):
    code = main(["multireturn", str(ext(pcap)), "-o", str(tmp_path / "m.npz")])
    _, err = capsys.readouterr()
    assert code == 2 and err.startswith("lidarpkt: error: ") and "Traceback" not in err
    assert not (tmp_path / "m.npz").exists()
