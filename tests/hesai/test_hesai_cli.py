"""The Pandar bags through the real CLI and lidarpkt.open: ``info`` names model, protocol and return mode;
``export --format parquet`` holds one row per return of ``lidarpkt.open``; the source counts what it routed."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

import lidarpkt

# folder, bag, model, protocol, the return mode the tail byte names (0x39 Last+Strongest, 0x3B First+Last,
# 0x3C First+Strongest: bytes 1052+10 etc., read by hand), packets in the bag
BAGS = [
    ("40p", "1673400149412331409", "Pandar40P", "none (no version field)", "last_strongest", 1439),
    ("64", "1673403880599376836", "Pandar64", "none (no version field)", "last_strongest", 2400),
    ("qt64", "1673401195788312575", "PandarQT64", "3.1", "first_last", 1200),
    ("qt128", "1730273789074637152", "PandarQT128", "3.2", "last_strongest", 1800),
    ("xt16", "1732848127890747768", "PandarXT16", "6.1", "last_strongest", 1626),
    ("xt32", "1673400677802009732", "PandarXT32", "6.1", "last_strongest", 2000),
    ("xt32m", "1660893203042895158", "PandarXT32M", "6.1", "first_strongest", 1815),
]


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "lidarpkt", *args], capture_output=True, text=True, timeout=120,
                          check=False)


@pytest.fixture(scope="module")
def info_docs():
    from conftest import external

    paths = [str(external(f"nebula/hesai/{b[0]}/{b[1]}")) for b in BAGS]
    res = _cli("info", *paths, "--json")
    assert res.returncode == 0, res.stderr
    text = _cli("info", *paths)
    assert text.returncode == 0, text.stderr
    return json.loads(res.stdout)["captures"], text.stdout


@pytest.mark.parametrize("i", range(len(BAGS)), ids=[b[0] for b in BAGS])
def test_info_names_model_protocol_and_return_mode(ext, info_docs, i):
    _, _, model, protocol, mode, packets = BAGS[i]
    docs, text = info_docs
    (stream,) = docs[i]["streams"]
    d = stream["details"]
    assert stream["kind"] == f"Hesai {model} data" and stream["packets"] == packets
    assert (d["model"], d["protocol"], d["return_mode"]) == (model, protocol, mode)
    assert d["malformed_packets"] == 0 and d["motor_speed_rpm"] in (599, 600)
    assert f"Hesai {model} data, protocol {protocol}, {mode}, 10.0 Hz" in text


def test_export_parquet_holds_one_row_per_return(ext, tmp_path):
    import pyarrow.parquet as pq

    bag, csv = ext("nebula/hesai/xt32/1673400677802009732"), ext("nebula/hesai/PandarXT32.csv")
    res = _cli("export", str(bag), "-o", str(tmp_path), "--format", "parquet", "--workers", "1", "--metadata", str(csv))
    assert res.returncode == 0, res.stderr
    (out,) = tmp_path.glob("**/*.parquet")
    table = pq.read_table(out).to_pandas()
    frames = list(lidarpkt.open(bag, metadata=csv))
    assert len(table) == sum(int(np.count_nonzero(f.range_mm)) for f in frames) > 400_000
    f = frames[3]
    rows = table[table.frame_id == f.frame_id].sort_values(["return_slot", "row", "column"])
    slot, row, col = np.nonzero(f.range_mm)
    assert np.array_equal(rows["range_m"].to_numpy(), f.range_mm[slot, row, col] / 1000.0)
    assert np.allclose(rows[["x", "y", "z"]].to_numpy(), f.xyz()[slot, row, col], atol=1e-6)
    assert set(rows["return_label"]) == {"last", "strongest"}


def test_open_counts_hesai_packets_and_says_what_a_csv_is_for(ext):
    bag, csv = ext("nebula/hesai/xt16/1732848127890747768"), ext("nebula/hesai/PandarXT16.csv")
    with lidarpkt.open(bag, metadata=[csv]) as reader:  # an archive job's --metadata: the CSV is the calibration
        frames = list(reader)
    assert reader.stats.packets_of("hesai", "data") == 1626 and reader.stats.unrouted_packets == 0
    assert frames[1].sensor.geometry is not None and frames[1].sensor.beam_altitude_deg[0] == 15.0
    assert frames[1].sensor.return_mode == "last_strongest" and frames[1].sensor.frequency_hz == pytest.approx(10.0, abs=0.02)
    without = list(lidarpkt.open(bag))
    assert np.isnan(without[1].sensor.beam_altitude_deg).all()
    with pytest.raises(lidarpkt.errors.CalibrationError, match="calibration"):
        without[1].xyz()


@pytest.mark.parametrize("folder, bag, model, columns", [
    ("xt32", "1673400677802009732", "PandarXT32", 2000), ("qt128", "1730273789074637152", "PandarQT128", 900),
    ("qt64", "1673401195788312575", "PandarQT64", 600), ("64", "1673403880599376836", "Pandar64", 1800)])
def test_whole_frames_fill_the_default_grid(ext, folder, bag, model, columns):
    """The XT and QT send their firings on the grid (0.18°, 0.4°, 0.6° steps): every column is its own
    bin. The Pandar64's azimuths wander by up to ±0.04° about 0.2° steps (and a rotation holds 1799 or 1800
    firings): a few share a bin, fewer than 2 %."""
    from lidarpkt.core.sequence import FrameStack

    frames = [f for f in lidarpkt.open(ext(f"nebula/hesai/{folder}/{bag}")) if not f.partial]
    stack = FrameStack.from_frames(frames)
    assert stack.range_mm.shape[1:] == (2, frames[0].shape[1], columns)
    collisions = [f.on_grid().counters.grid_collisions for f in frames]
    if folder == "64":
        assert max(collisions) < 0.02 * columns and stack.column_valid.mean() > 0.98
    else:
        assert stack.column_valid.all() and collisions == [0] * len(frames)


def test_catalog_names_vendor_model_mode_and_counts_frames(ext):
    from lidarpkt.archive import catalog

    rows = catalog([ext("nebula/hesai")], workers=1).to_pylist()
    by_model = {r["model"]: r for r in rows}
    assert set(by_model) == {b[2] for b in BAGS}
    for _, _, model, _, mode, packets in BAGS:
        r = by_model[model]
        assert (r["vendor"], r["mode"], r["packets"], r["error"]) == ("hesai", mode, packets, None)
        # the XT32M bag lost packets in every rotation: each of its frames misses columns (partial)
        assert r["frames"] - r["partial_frames"] >= (0 if model == "PandarXT32M" else 1)
    assert by_model["PandarXT32M"]["lost_packets"] == 852  # its UDP sequence skips 414 + 45 + 396 - 3
    assert by_model["PandarXT32M"]["partial_frames"] == by_model["PandarXT32M"]["frames"] == 5


def test_decode_to_mcap_keeps_the_packets_and_names_nebulas_topic(ext, tmp_path):
    from mcap.reader import make_reader

    bag, csv = ext("nebula/hesai/xt32/1673400677802009732"), ext("nebula/hesai/PandarXT32.csv")
    out = tmp_path / "out.mcap"
    res = _cli("decode", str(bag), "-o", str(out), "--calibration", str(csv))
    assert res.returncode == 0, res.stderr
    with open(out, "rb") as fh:
        summary = make_reader(fh).get_summary()
    counts = {summary.channels[c].topic: n for c, n in summary.statistics.channel_message_counts.items()}
    assert counts == {"/lidarpkt/other_packets": 2000, "/pandar_points": 5, "/pandar_points2": 5}
    again, frames = list(lidarpkt.open(out, metadata=csv)), list(lidarpkt.open(bag, metadata=csv))
    assert [f.sensor.model for f in again] == ["PandarXT32"] * 5
    assert all(np.array_equal(a.range_mm, b.range_mm) for a, b in zip(again, frames))


def test_the_analysis_splits_last_strongest_into_three_returns(ext):
    """Last+Strongest: slot 1 holds the strongest, or the second strongest where the last return is the
    strongest (the decoder's mark); the analysis selects each kind per firing as for the VLP-16's dual mode."""
    from lidarpkt.analysis.returns import available_returns, select_returns
    from lidarpkt.analysis.stack import stack_frames

    frames = [f for f in lidarpkt.open(ext("nebula/hesai/xt32/1673400677802009732")) if not f.partial]
    stack = stack_frames(frames, None)
    assert available_returns(stack) == ("last", "strongest", "second_strongest")
    sel = select_returns(stack, ["last", "strongest", "second_strongest"])
    marks = np.stack([f.on_grid().extra["second_strongest"] for f in frames])
    r0, r1 = stack.range_mm[:, 0], stack.range_mm[:, 1]
    assert np.array_equal(sel.range_mm[:, 1], np.where(marks, r0, r1))  # strongest: the last where it is marked
    assert np.array_equal(sel.range_mm[:, 2], np.where(marks, r1, 0))
    two = (r1 > 0) & (r0 != r1)  # firings with two echoes (most have one, sent in both blocks)
    assert 0.02 < marks[two].mean() < 0.98 and not marks[~two].any()  # both cases occur in the real scene
