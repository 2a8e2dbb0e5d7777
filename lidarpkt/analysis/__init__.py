"""The multi-return analysis of Rife & Li, "Characterizing Lidar Range-Measurement Ambiguity due
to Multiple Returns": temporal and spatial range CDFs per raypath, motion compensation, Gaussian
mixtures, whole-image multi-return statistics and monitor, return-mode comparison, return selection as the
sensor defines it (:mod:`analysis.returns`), the scan-matching error multi-return raypaths cause
(:mod:`analysis.registration`), per-pixel mixture maps (:mod:`analysis.gmm_map`), plots.

Input is a :class:`lidarpkt.core.sequence.FrameStack` (``load_stack(path)`` makes one from a capture).
Plots live in :mod:`analysis.plots` (matplotlib, the ``plot`` extra) and are not imported here.
"""

from .cdf import RangeCDF, pixel_samples, reflectivity_vs_range, spatial_cdf, temporal_cdf
from .compare import DistributionComparison, PairedComparison, compare_slots, compare_stacks, ks_image
from .gmm import DEFAULT_GAP_M, GaussianMixture, fit_auto, fit_em, fit_gmm, fit_thresholds, gap_thresholds, ks_distance, parse_method
from .motion import MotionCompensation, estimate_frame_offsets, motion_compensated_cdf
from .multireturn import (
    DEFAULT_MONITOR_METHOD,
    MONITOR_METHODS,
    ImageStatistics,
    MonitorEvaluation,
    MultiReturnMap,
    evaluate_monitor,
    image_statistics,
    detrended_gap_score,
    monitor_score,
    multireturn_map,
    spatial_gap_score,
)
from .gmm_map import GmmMap, fit_gmm_map, load_gmm_map
from .raypath import RaypathAnalysis, analyze, analyze_pixel, analyze_raypath
from .registration import RegistrationImpact, RegistrationSettings, registration_impact
from .returns import (RETURN_KINDS, ReturnStack, available_returns, resolve, sample_mask, select_returns,
                      sensor_returns)
from .stack import load_stack, select_frames

__all__ = [
    "RangeCDF", "pixel_samples", "reflectivity_vs_range", "spatial_cdf", "temporal_cdf",
    "DistributionComparison", "PairedComparison", "compare_slots", "compare_stacks", "ks_image",
    "DEFAULT_GAP_M", "GaussianMixture", "fit_auto", "fit_em", "fit_gmm", "fit_thresholds", "gap_thresholds", "ks_distance", "parse_method",
    "MotionCompensation", "estimate_frame_offsets", "motion_compensated_cdf",
    "ImageStatistics", "MonitorEvaluation", "MultiReturnMap", "evaluate_monitor", "image_statistics",
    "multireturn_map", "spatial_gap_score", "detrended_gap_score", "monitor_score", "MONITOR_METHODS",
    "DEFAULT_MONITOR_METHOD",
    "RaypathAnalysis", "analyze", "analyze_pixel", "analyze_raypath",
    "GmmMap", "fit_gmm_map", "load_gmm_map",
    "RegistrationImpact", "RegistrationSettings", "registration_impact",
    "RETURN_KINDS", "ReturnStack", "available_returns", "resolve", "sample_mask", "select_returns", "sensor_returns",
    "load_stack", "select_frames",
]
