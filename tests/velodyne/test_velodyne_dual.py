"""The VLP-16 dual-return mark (lidarpkt.vendors.velodyne.dual): which firings' slot 1 holds the second
strongest return, inferred from the signal estimated as reflectivity / range² (issue 17 §2).

Checked by hand-made cases (the model, the tie rule, int64 exactness at the longest range), on the
only real VLP-16 dual data we have (the nebula bag: how many marks the physical rule changes from
the reflectivity-only rule, which is also what VeloView's DUAL_INTENSITY_HIGH/LOW flags and nebula's
return types compare), and on the generated scene in tests/analysis/test_analysis_returns.py.
"""

from __future__ import annotations

import numpy as np
import pytest

import lidarpkt
from lidarpkt.core.dual import second_strongest_mark, signal_order_undecided


def _pairs(*rows):
    """[(r0, f0, r1, f1), ...] → range_mm [2, N], reflectivity [2, N]."""
    a = np.array(rows, dtype=np.int64)
    return np.stack([a[:, 0], a[:, 2]]), np.stack([a[:, 1], a[:, 3]])


def test_mark_compares_reflectivity_over_range_squared_with_ties_unmarked():
    rng, refl = _pairs(
        (6000, 200, 2000, 20),  # last 200/36 > 20/4: the last was the strongest → marked
        (6000, 90, 2000, 20),  # last has the higher reflectivity but 90/36 < 20/4 → slot 1 strongest
        (6000, 90, 2000, 10),  # 90/36 == 10/4: a tie, not marked
        (6000, 91, 2000, 10),  # one reflectivity unit breaks the tie
        (4000, 40, 4000, 40),  # one return sent twice: never marked
        (0, 0, 0, 0),  # no return
        (5000, 50, 0, 0),  # slot 1 empty (not what a VLP-16 sends): not marked
    )
    assert second_strongest_mark(rng, refl).tolist() == [True, False, False, True, False, False, False]


def test_mark_is_exact_at_the_longest_range_and_accepts_frame_shapes():
    far = 0xFFFF * 2  # 131 070 mm, the largest VLP-16 range
    rng, refl = _pairs((far, 255, far - 2, 254), (far, 255, far - 400, 254))
    # 255·(far-2)² > 254·far²: the last is stronger; 255·(far-400)² < 254·far²: it is not (products
    # about 4.4e12, exact in int64; the uint16/uint32 inputs would overflow without the cast).
    assert second_strongest_mark(rng, refl).tolist() == [True, False]
    assert second_strongest_mark(rng.astype(np.uint32), refl.astype(np.uint8)).tolist() == [True, False]  # frame dtypes
    frame_shape = np.zeros((2, 16, 7), np.uint32), np.zeros((2, 16, 7), np.uint8)
    assert second_strongest_mark(*frame_shape).shape == (16, 7)
    with pytest.raises(ValueError, match=r"\[2, \.\.\.\]"):
        second_strongest_mark(np.zeros((3, 4)), np.zeros((3, 4)))
    with pytest.raises(ValueError, match="same shape"):
        second_strongest_mark(np.zeros((2, 4)), np.zeros((2, 5)))


def test_undecided_firings_are_those_whose_bytes_cannot_order_the_signals():
    rng, refl = _pairs(
        (6000, 90, 2000, 10),  # exact tie
        (6000, 91, 2000, 10),  # 90.5..91.5 over 36 vs 9.5..10.5 over 4: intervals overlap
        (6000, 200, 2000, 20),  # 199.5/36 = 5.54 > 20.5/4 = 5.125: decided
        (6000, 255, 2000, 5),  # saturated: any signal above 254.5/36 = 7.07, vs 4.5/4..5.5/4: decided
        (6000, 255, 2000, 30),  # saturated: the last could be as weak as 7.07, slot 1 is 7.375..7.625
        (4000, 40, 4000, 40),  # one return: nothing to decide
    )
    assert signal_order_undecided(rng, refl).tolist() == [True, True, False, False, True, False]


def test_real_dual_capture_marks_under_the_old_and_the_new_rule(ext):
    """The nebula bag (tier4/nebula, the only real VLP-16 dual data): counts of the marks the physical
    rule changes. VeloView flags the return with the higher intensity byte DUAL_INTENSITY_HIGH and
    nebula labels it *_STRONGEST: both compare the bytes alone, the rule this module replaces."""
    frames = list(lidarpkt.open(ext("nebula/vlp16/1673400471837873222"), metadata=ext("nebula/VLP16.yaml")))
    assert len(frames) == 5
    two = old = old_on_pairs = new = undecided = 0
    for f in frames:
        r, fl = f.range_mm.astype(np.int64), f.reflectivity.astype(np.int64)
        mark = f.extra["second_strongest"]
        assert np.array_equal(mark, second_strongest_mark(r, fl))  # the decoder uses this rule
        pair = (r[0] > 0) & (r[1] > 0) & (r[0] != r[1])
        assert not (pair & (r[1] > r[0])).any()  # slot 0 is the last return: never the nearer one
        old_rule = (r[1] != r[0]) & (fl[0] > fl[1])  # the decoder's rule before issue 17
        bytes_only = pair & (fl[0] > fl[1])  # VeloView's / nebula's comparison (both skip zero ranges)
        assert not (mark & ~bytes_only).any()  # the range term only ever lowers the far return's signal
        two += int(pair.sum())
        old += int(old_rule.sum())
        old_on_pairs += int(bytes_only.sum())
        new += int(mark.sum())
        undecided += int(signal_order_undecided(r, fl).sum())
    # 708 firings with two different returns. The old rule marked 640 firings: 301 of them have an
    # empty slot (range 0, whose reflectivity byte means nothing: the packet does not say the last
    # return was the strongest), 339 are pairs, of which the range term keeps 146. So 494 marks
    # change, all from "second strongest" to "strongest"; 91 pairs cannot be ordered from the bytes.
    assert (two, old, old_on_pairs, new, undecided) == (708, 640, 339, 146, 91)


def test_nebula_return_types_compare_the_bytes_and_the_mark_keeps_a_subset(ext):
    """nebula's decoded cloud of the bag's 4th message labels each return of a two-return firing by
    comparing the two intensity bytes (ties: the nearer is the strongest). The PCD's codes, read off
    its output: 9 the last return is the stronger, 4 it is the weaker; 10 and 5 the same for the
    nearer return; 6 one return. The mark agrees with nebula's "last is strongest" on a subset only."""
    from test_velodyne_nebula import read_pcd

    neb = read_pcd(ext("nebula/vlp16/1673400472138016708.pcd"))
    f = list(lidarpkt.open(ext("nebula/vlp16/1673400471837873222"), metadata=ext("nebula/VLP16.yaml")))[3]
    r, fl, mark = f.range_mm.astype(np.int64), f.reflectivity.astype(np.int64), f.extra["second_strongest"]
    pair = (r[0] > 0) & (r[1] > 0) & (r[0] != r[1])
    where = {}
    for s, row, col in zip(*np.nonzero(r)):
        where.setdefault((15 - int(row), int(r[s, row, col]), int(fl[s, row, col])), (int(s), int(row), int(col)))
    dist_mm = np.rint(neb["distance"].astype(np.float64) * 1000).astype(int)
    nebula_last_strongest, ours_too, checked = set(), set(), 0
    for k in range(len(neb)):
        s, row, col = where[(int(neb["channel"][k]), int(dist_mm[k]), int(neb["intensity"][k]))]
        code = int(neb["return_type"][k])
        if not pair[row, col] or code == 6:
            continue
        checked += 1
        last_higher = fl[0, row, col] > fl[1, row, col]
        assert code == ((9 if last_higher else 4) if s == 0 else (5 if last_higher else 10))
        if last_higher:
            nebula_last_strongest.add((row, col))
            ours_too |= {(row, col)} if mark[row, col] else set()
        else:
            assert not mark[row, col]  # never "last strongest" where nebula's bytes say it is not
    # 336 nebula points on two-return firings, every one labelled by the byte comparison; of the 89
    # firings where nebula calls the last return the strongest, the range term keeps 42
    assert checked == 336
    assert (len(nebula_last_strongest), len(ours_too)) == (89, 42)
