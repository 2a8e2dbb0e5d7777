"""Everything the paper computes for one raypath, gathered in one result (what ``lidarpkt analyze``
reports per ``--pixel``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np

from lidarpkt.core.sequence import FrameStack

from .cdf import RangeCDF, reflectivity_vs_range, spatial_cdf, temporal_cdf
from .gmm import GaussianMixture, fit_gmm
from .motion import MotionCompensation, motion_compensated_cdf
from .returns import resolve
from .stack import check_pixel


@dataclass(frozen=True, eq=False)
class RaypathAnalysis:
    """The analysis of pixel (row, col), return ``label`` over a stack.

    ``slot`` is the capture's slot the return was read from, or None when it was selected per
    firing from both slots (a VLP-16 dual capture's strongest or second strongest return).

    ``spatial`` is the spatial CDF of the first frame of the stack (the monitor's view);
    ``spatial_all`` the same neighbourhood over all frames superimposed (Fig. 9).
    ``motion`` and ``gmm`` are None when not asked for (or, for ``gmm``, without returns).
    """

    row: int
    col: int
    slot: int | None
    label: str
    n_frames: int  # frames of the stack
    temporal: RangeCDF
    reflectivity: np.ndarray  # uint8[n_returns], aligned with temporal.range_m
    spatial: RangeCDF
    spatial_all: RangeCDF
    neighbourhood: int
    motion: MotionCompensation | None
    gmm: GaussianMixture | None

    def to_json(self) -> dict:
        """One entry of ``analyze --json``'s ``pixels`` list.

        ``n_frames`` counts the frames with a sample of this pixel (``n_returns + n_nonreturn``,
        the CDF's denominator); ``n_missing`` the frames where its column was lost. ``range_m``
        is sorted and ``F`` is the CDF at each sample; ``reflectivity`` is aligned with the
        temporal ``range_m``. ``spatial_cdf`` is the first frame's; ``motion_compensated`` and
        ``gmm`` are null when not computed (``gmm`` describes the compensated samples when
        motion compensation is on). GMM weights are shares of all samples, non-returns included.
        """
        t = self.temporal
        return {
            "row": self.row,
            "col": self.col,
            "slot": self.slot,  # null: selected per firing from both slots (see analysis.returns)
            "label": self.label,
            "n_frames": t.n_samples,
            "n_returns": t.n_returns,
            "n_nonreturn": t.n_nonreturn,
            "n_missing": t.n_missing,
            "temporal_cdf": t.to_json(),
            "reflectivity": self.reflectivity.tolist(),
            "spatial_cdf": self.spatial.to_json(),
            "motion_compensated": None if self.motion is None else self.motion.to_json(),
            "gmm": None if self.gmm is None else self.gmm.to_json(),
        }


def analyze_raypath(
    stack: FrameStack,
    row: int,
    col: int,
    slot: int | str = 0,
    *,
    neighbourhood: int = 5,
    motion_compensation: bool = False,
    gmm: str | Sequence[float] | np.ndarray | None = "em",
) -> RaypathAnalysis:
    """Temporal CDF, reflectivity, spatial CDFs, optionally the motion-compensated CDF and a GMM
    (``gmm``: ``"em"``, ``"auto"``, CDF thresholds, or None) of one raypath.

    The GMM is fitted to the motion-compensated samples when motion compensation is on, else
    to the temporal ones; it is None when there is no return. ``slot``: a slot index or a return
    kind (``"strongest"``, ``"last"``, ``"second_strongest"``), selected per firing as the sensor
    defines it (:mod:`analysis.returns`). Raises AnalysisError for a bad pixel, slot or option.
    """
    stack, slot = resolve(stack, slot)
    check_pixel(stack, row, col, slot)
    temporal = temporal_cdf(stack, row, col, slot)
    _, refl = reflectivity_vs_range(stack, row, col, slot)
    spatial = spatial_cdf(stack, row, col, slot, n=neighbourhood, frame=0)
    spatial_all = spatial_cdf(stack, row, col, slot, n=neighbourhood, frame=None)
    motion = motion_compensated_cdf(stack, row, col, slot) if motion_compensation else None
    fitted = None
    if gmm is not None:
        target = motion.cdf if motion is not None else temporal
        if target.n_returns:
            fitted = fit_gmm(target, gmm)
    sources = getattr(stack, "sources", None)
    source_slot = slot if sources is None else sources[slot]
    return RaypathAnalysis(
        row, col, source_slot, stack.return_labels[slot], len(stack), temporal, refl, spatial, spatial_all,
        neighbourhood, motion, fitted,
    )


def analyze_pixel(stack: FrameStack, row: int, col: int, slot: int | str = 0, **options) -> dict:
    """:func:`analyze_raypath` as the JSON-ready dict of one ``analyze --json`` pixel entry."""
    return analyze_raypath(stack, row, col, slot, **options).to_json()


def analyze(stack: FrameStack, pixels: Iterable[tuple[int, int]], slot: int | str = 0, **options) -> dict:
    """The whole ``analyze --json`` document: ``{"frames": K, "pixels": [...]}``."""
    stack, slot = resolve(stack, slot)  # once, not per pixel
    return {"frames": len(stack), "pixels": [analyze_pixel(stack, r, c, slot, **options) for r, c in pixels]}
