"""Return selection as the sensor defines it (issue 17 §2), checked on the generated scene whose one
set of firings is encoded in the strongest, last and dual VLP-16 modes (fixtures/scene.py): the
single-mode captures are the truth of what a dual capture's returns are."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lidarpkt.analysis.cdf import temporal_cdf
from lidarpkt.analysis.compare import compare_slots, compare_stacks
from lidarpkt.analysis.returns import (
    ReturnStack,
    available_returns,
    parse_return,
    resolve,
    sample_mask,
    select_returns,
)
from lidarpkt.cli import main
from lidarpkt.core.dual import signal_order_undecided
from lidarpkt.fixtures import ensure
from test_analysis_support import load_fixture, make_stack

FRAMES = 50


@pytest.fixture(scope="module")
def modes():
    return {m: load_fixture(f"vlp16-{m}", frames=FRAMES, aux=False)[0] for m in ("strongest", "last", "dual")}


def test_dual_last_and_strongest_equal_the_single_mode_captures_in_every_pixel(modes):
    dual, strongest, last = modes["dual"], modes["strongest"], modes["last"]
    assert isinstance(dual, ReturnStack) and dual.second_strongest is not None  # the decoder's mark, carried
    assert dual.range_mm.shape == (FRAMES, 2, 16, 1800) and np.array_equal(dual.column_valid, strongest.column_valid)
    sel = select_returns(dual, ["last", "strongest", "second_strongest"])
    assert sel.return_labels == ("last", "strongest", "second_strongest")
    assert sel.sources == (0, None, None)
    # last: slot 0 everywhere
    assert np.array_equal(sel.range_mm[:, 0], last.range_mm[:, 0])
    assert np.array_equal(sel.reflectivity[:, 0], last.reflectivity[:, 0])
    # truth of "slot 1 holds the second strongest": slot 1 is not what strongest mode reported
    truth_marked = dual.range_mm[:, 1] != strongest.range_mm[:, 0]
    # where slot 1 is not the strongest, the last return is: the dual encoding is consistent
    assert np.array_equal(dual.range_mm[:, 0][truth_marked], strongest.range_mm[:, 0][truth_marked])
    # with the true mark, the per-firing strongest equals strongest mode in every one of the 1,440,000 pixels
    exact = select_returns(ReturnStack(**{**_fields(dual), "second_strongest": truth_marked}), ["strongest"])
    assert exact.range_mm[:, 0].size == 1_440_000
    assert np.array_equal(exact.range_mm[:, 0], strongest.range_mm[:, 0])
    assert np.array_equal(exact.reflectivity[:, 0], strongest.reflectivity[:, 0])
    # with the decoder's mark (the signal estimated from the packet as reflectivity / range²; the
    # generator derives the reported reflectivity from the echo strength as a sensor does) it differs
    # exactly where the mark is wrong, and the mark is wrong only where the quantised reflectivity
    # bytes cannot order the two returns' signals: 9 of 1,440,000 pixels (62 are undecided). The
    # reflectivity-only rule before issue 17 is wrong in 245 (352 on the generator before
    # GENERATOR_VERSION 5, whose reflectivity was drawn apart from the echo strength)
    differ = sel.range_mm[:, 1] != strongest.range_mm[:, 0]
    two = dual.range_mm[:, 0] != dual.range_mm[:, 1]
    assert np.array_equal(differ, (dual.second_strongest != truth_marked) & two)
    undecided = signal_order_undecided(np.moveaxis(dual.range_mm, 1, 0), np.moveaxis(dual.reflectivity, 1, 0))
    assert not (differ & ~undecided).any()  # every firing the bytes decide is right
    assert int(differ.sum()) == 9 and int(undecided.sum()) == 62
    old_rule = two & (dual.reflectivity[:, 0] > dual.reflectivity[:, 1])
    assert int(((old_rule != truth_marked) & two).sum()) == 245
    # raw slot 1 is not the strongest return: it differs wherever the last return was the strongest
    # (240 firings); the decoder marks 237 (the 9 wrong marks above: some missed, some extra)
    assert int(truth_marked.sum()) == 240 and int(dual.second_strongest.sum()) == 237


def test_second_strongest_is_no_sample_where_the_sensor_did_not_report_it(modes):
    dual, strongest = modes["dual"], modes["strongest"]
    sel = select_returns(dual, ["second_strongest"])
    mask = sample_mask(sel, 0)
    marked = dual.second_strongest
    one_return = dual.range_mm[:, 0] == dual.range_mm[:, 1]
    col = np.broadcast_to(dual.column_valid[:, None, :], marked.shape)
    assert np.array_equal(mask, col & (marked | one_return))
    assert np.array_equal(sel.range_mm[:, 0][marked], dual.range_mm[:, 1][marked])
    assert not sel.range_mm[:, 0][one_return & ~marked].any()  # one return: no second (a non-return)
    # a raypath's temporal CDF counts only its samples; the others are "missing"
    k = len(dual)
    r, c = np.argwhere(marked.sum(axis=0) > 0)[0]
    cdf = temporal_cdf(dual, int(r), int(c), "second_strongest")
    assert cdf.n_samples == int(mask[:, r, c].sum()) and cdf.n_missing == k - cdf.n_samples
    assert strongest is not None


def test_compare_returns_pairs_the_same_kinds_and_finds_them_identical(modes, tmp_path, capsys):
    dual_p, strongest_p, last_p = (ensure(f"vlp16-{m}", frames=FRAMES, aux=False) for m in ("dual", "strongest", "last"))
    for single, kind in ((last_p, "last"), (strongest_p, "strongest")):
        out = tmp_path / f"{kind}.json"
        assert main(["compare-returns", str(single), str(dual_p), "--paired", "-o", str(out)]) == 0
        doc = json.loads(out.read_text())
        capsys.readouterr()
        assert doc["modes"]["labels"] == [kind, kind]
        frac = doc["paired"]["fraction_identical"]
        dual, strongest = modes["dual"], modes["strongest"]
        if kind == "last":
            assert frac == 1.0
        else:  # identical but in the 9 firings whose order the reflectivity bytes cannot decide (above)
            wrong = (dual.second_strongest != (dual.range_mm[:, 1] != strongest.range_mm[:, 0])) & (
                dual.range_mm[:, 0] != dual.range_mm[:, 1])
            assert int(wrong.sum()) == 9
            assert frac == pytest.approx(1.0 - wrong.mean(), abs=1e-12)
    # the raw slot, asked for by index, is the old comparison: it differs wherever the last was the strongest
    out = tmp_path / "raw.json"
    assert main(["compare-returns", str(strongest_p), str(dual_p), "--return2", "1", "--paired", "-o", str(out)]) == 0
    raw_marked = modes["dual"].range_mm[:, 1] != modes["strongest"].range_mm[:, 0]
    assert json.loads(out.read_text())["paired"]["fraction_identical"] == pytest.approx(1.0 - raw_marked.mean(), abs=1e-12)
    capsys.readouterr()
    # the API agrees with the CLI
    dist, pc = compare_stacks(modes["strongest"], modes["dual"], "strongest", "strongest", paired=True)
    assert pc.summary()["fraction_identical"] == pytest.approx(frac)
    assert compare_slots(modes["dual"], "last", "strongest").labels == ("last", "strongest")


def test_selection_parsing_and_errors():
    assert parse_return("1") == 1 and parse_return(0) == 0 and parse_return("last") == "last"
    with pytest.raises(Exception, match="give a slot index"):
        parse_return("loudest")
    single = make_stack(np.full((2, 1, 2, 3), 5000), labels=("strongest",))
    assert available_returns(single) == ("strongest",)
    assert resolve(single, "strongest") == (single, 0)
    with pytest.raises(Exception, match="'last' is not in this capture"):
        resolve(single, "last")
    with pytest.raises(Exception, match="slot 1 does not exist"):
        resolve(single, 1)
    ouster = make_stack(np.full((2, 2, 2, 3), 5000), labels=("strongest", "second_strongest"), shift=[0, 0])
    assert available_returns(ouster) == ("strongest", "second_strongest")
    st, i = resolve(ouster, "second_strongest")
    assert st is ouster and i == 1  # a kind that is one slot: no copy


def _fields(stack):
    from dataclasses import fields

    return {f.name: getattr(stack, f.name) for f in fields(stack)}
