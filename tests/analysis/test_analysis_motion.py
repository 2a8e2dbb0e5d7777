"""Motion compensation (eqs. 4–6) on stacks whose motion is known because the test moved them."""

import numpy as np
import pytest

from lidarpkt.analysis.cdf import temporal_cdf
from lidarpkt.analysis.motion import estimate_frame_offsets, motion_compensated_cdf
from lidarpkt.errors import AnalysisError
from test_analysis_support import destaggered_by_definition, make_stack

H, W, PAD = 12, 40, 3


def textured_world(seed=0):
    """A scene larger than the image (PAD rows above and below): every range distinct, so
    every 5 x 5 patch is unique and the motion is observable everywhere."""
    rng = np.random.default_rng(seed)
    world = rng.integers(2000, 60000, size=(H + 2 * PAD, W)).astype(np.uint32)
    world[rng.random(world.shape) < 0.05] = 0  # a few non-returns
    return world


def moved_stack(world, motions, shift=None):
    """Frame k looks at world cell (PAD + r + dr_k, c + dc_k) from pixel (r, c) (destaggered)."""
    frames = []
    for dr, dc in motions:
        view = np.roll(world[PAD + dr : PAD + dr + H], -dc, axis=1)
        if shift is not None:  # the wire image is staggered: staggered[u, c] = destaggered[u, (c + shift[u]) % W]
            view = np.stack([np.roll(view[u], -shift[u]) for u in range(H)])
        frames.append(view)
    return make_stack(np.stack(frames)[:, None], shift=shift)


MOTIONS = [(0, 0), (1, 0), (0, -2), (-2, 1), (2, 2), (-1, -1), (0, 1), (1, -2)]


@pytest.mark.parametrize("row,col", [(5, 20), (6, 0), (4, 39)])  # the last two wrap in azimuth
def test_patch_search_recovers_known_motion(row, col):
    world = textured_world()
    stack = moved_stack(world, MOTIONS)
    mc = motion_compensated_cdf(stack, row, col)
    # Frame k's pixel (row - dr, col - dc) sees the cell frame 0 saw at (row, col).
    assert mc.offsets.tolist() == [[-dr, -dc] for dr, dc in MOTIONS]
    assert np.all(mc.cost_m2 == 0.0)
    expected = world[PAD + row, col]
    assert mc.range_mm.tolist() == [expected] * len(MOTIONS)
    assert mc.sample_valid.all()
    raw = temporal_cdf(stack, row, col)
    assert np.unique(raw.range_m).size > 1  # without compensation the moving frames smear the CDF


def test_whole_frame_registration_recovers_known_motion():
    stack = moved_stack(textured_world(1), MOTIONS)
    offsets, cost = estimate_frame_offsets(stack)
    assert offsets.tolist() == [[-dr, -dc] for dr, dc in MOTIONS]
    assert np.all(cost == 0.0)


def test_motion_moves_in_destaggered_columns_for_ouster():
    shift = np.array([0, 3, 6, 9] * 3)
    world = textured_world(2)
    stack = moved_stack(world, MOTIONS, shift=shift)
    row, col = 5, 17  # staggered column; it sees destaggered column (17 + shift[5]) % W
    mc = motion_compensated_cdf(stack, row, col)
    assert mc.offsets.tolist() == [[-dr, -dc] for dr, dc in MOTIONS]
    assert mc.range_mm.tolist() == [world[PAD + row, (col + shift[row]) % W]] * len(MOTIONS)
    offsets, _ = estimate_frame_offsets(stack)
    assert offsets.tolist() == [[-dr, -dc] for dr, dc in MOTIONS]
    # the stack really is staggered: destaggering frame 0 by definition gives the world back
    assert np.array_equal(destaggered_by_definition(stack.range_mm[0, 0], shift), world[PAD : PAD + H])


def test_still_stack_keeps_zero_offsets_and_the_temporal_cdf():
    rng = np.random.default_rng(3)
    base = textured_world(3)[PAD : PAD + H]
    noisy = base[None] + rng.integers(-10, 11, size=(6, H, W)) * (base[None] > 0)  # 1 cm noise, no motion
    stack = make_stack(noisy[:, None].astype(np.uint32))
    mc = motion_compensated_cdf(stack, 6, 10)
    assert np.all(mc.offsets == 0)
    raw = temporal_cdf(stack, 6, 10)
    assert np.array_equal(mc.cdf.range_m, raw.range_m) and np.array_equal(mc.cdf.F, raw.F)


def test_a_flat_patch_prefers_no_motion():
    stack = make_stack(np.full((3, 1, 8, 12), 7000, np.uint32))
    mc = motion_compensated_cdf(stack, 4, 4)
    assert np.all(mc.offsets == 0)  # every offset costs 0: ties go to the smallest move


def test_lost_column_at_the_chosen_pixel_is_missing_not_a_nonreturn():
    world = textured_world(4)
    stack = moved_stack(world, MOTIONS)
    row, col = 5, 20
    k = 2  # frame 2 moved by (0, -2): the pixel it needs is column 22
    stack.column_valid[k, col + 2] = False
    stack.range_mm[k, :, :, col + 2] = 0
    mc = motion_compensated_cdf(stack, row, col)
    assert not mc.sample_valid[k] and mc.sample_valid.sum() == len(MOTIONS) - 1
    assert mc.cdf.n_missing == 1 and mc.cdf.n_nonreturn == 0


def test_given_offsets_are_used_and_checked():
    world = textured_world(5)
    stack = moved_stack(world, MOTIONS)
    offsets = np.array([[-dr, -dc] for dr, dc in MOTIONS])
    mc = motion_compensated_cdf(stack, 5, 20, offsets=offsets)
    assert mc.range_mm.tolist() == [world[PAD + 5, 20]] * len(MOTIONS)
    with pytest.raises(AnalysisError, match="within ±2"):
        motion_compensated_cdf(stack, 5, 20, offsets=offsets * 3)


def test_bad_options_raise_analysis_errors():
    stack = make_stack(np.full((2, 1, 4, 8), 5000, np.uint32))
    with pytest.raises(AnalysisError, match="odd"):
        motion_compensated_cdf(stack, 1, 1, patch=4)
    with pytest.raises(AnalysisError, match="reference frame 5"):
        motion_compensated_cdf(stack, 1, 1, reference=5)
    with pytest.raises(AnalysisError, match="wider than the image"):
        motion_compensated_cdf(stack, 1, 1, search=2, patch=5)
    with pytest.raises(AnalysisError, match="outside"):
        motion_compensated_cdf(stack, 9, 1)


from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000), st.lists(st.tuples(st.integers(-2, 2), st.integers(-2, 2)), min_size=1, max_size=6),
       st.integers(2, 9), st.integers(0, W - 1))
def test_any_motion_within_the_search_is_recovered(seed, motions, row, col):
    motions = [(0, 0)] + motions  # frame 0 is the reference
    world = textured_world(seed)
    world[world == 0] = 1234  # no non-returns: every patch fully textured
    stack = moved_stack(world, motions)
    mc = motion_compensated_cdf(stack, row, col)
    assert mc.offsets.tolist() == [[-dr, -dc] for dr, dc in motions]
    offsets, _ = estimate_frame_offsets(stack)
    assert offsets.tolist() == [[-dr, -dc] for dr, dc in motions]
