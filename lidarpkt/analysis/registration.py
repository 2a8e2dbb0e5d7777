"""The paper's §4.2 measured: how much pose error multi-return raypaths cause in scan matching, and
how much of it the monitor removes (``lidarpkt registration-impact``).

The capture comes from a stationary sensor, so the true motion between any two frames is none.
Each frame is registered to the first (``scan_to_scan``) and to a map made of all frames
(``scan_to_map``, or a probabilistic raypath map, :mod:`analysis.gmm_map`) by the two families the
paper discusses, as implemented by small_gicp (the ``registration`` extra): point-based ICP
(point-to-point and point-to-plane) and the voxel-distribution VGICP (of the NDT family). The
error of each estimated pose is its translation (m) and its rotation angle (deg), in three
conditions:

* ``all``: every raypath with a return;
* ``monitor_removed``: without the raypaths the one-frame monitor (:func:`analysis.multireturn.monitor_score`)
  flags, each frame judged on its own (the monitor a vehicle could run);
* ``multireturn_removed``: without the raypaths that the temporal statistics of the whole stack
  call multi-return (``n_clusters >= 2``, the truth the monitor is scored against).

Points are the stack's ranges through the sensor's own geometry (:meth:`SensorInfo.geometry`),
on the stack's column grid (for the VLP-16, at each column's measured azimuth).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Sequence, cast

import numpy as np

from lidarpkt.errors import AnalysisError
from lidarpkt.core.frame import Frame
from lidarpkt.core.sequence import FrameStack

from .gmm import DEFAULT_GAP_M
from .multireturn import DEFAULT_MONITOR_METHOD, MONITOR_METHODS, image_statistics, monitor_score
from .returns import resolve, sample_mask

#: Registration algorithms: name → small_gicp ``registration_type`` (VGICP uses a voxel map).
ALGORITHMS = {"icp_point_to_point": "ICP", "icp_point_to_plane": "PLANE_ICP", "vgicp": "VGICP"}
#: Targets a frame is registered to.
MODES = ("scan_to_scan", "scan_to_map")
#: Which raypaths are left out (module docstring).
CONDITIONS = ("all", "monitor_removed", "multireturn_removed")


@dataclass(frozen=True)
class RegistrationSettings:
    """small_gicp parameters (metres): voxel-grid downsampling of every cloud, the largest
    correspondence distance, VGICP's voxel size, iterations, neighbours for normals and
    covariances, and threads."""

    downsampling_m: float = 0.25
    max_correspondence_m: float = 1.0
    voxel_m: float = 1.0
    max_iterations: int = 50
    #: convergence: stop when an update moves less than this (small_gicp's default of 1 mm and
    #: 0.1° would stop at errors of the size measured here)
    translation_epsilon_m: float = 1e-6
    rotation_epsilon_deg: float = 1e-5
    num_neighbors: int = 10
    threads: int = 1

    def check(self) -> None:
        for name in ("downsampling_m", "max_correspondence_m", "voxel_m"):
            if not getattr(self, name) > 0:
                raise AnalysisError(f"registration {name} must be a positive number of metres, not {getattr(self, name)}")
        if self.max_iterations < 1 or self.num_neighbors < 3 or self.threads < 1:
            raise AnalysisError("registration needs max_iterations >= 1, num_neighbors >= 3 and threads >= 1")


@dataclass(frozen=True, eq=False)
class PoseErrors:
    """Pose errors of one algorithm, target and condition: ``frame`` (stack indices of the
    registered frames), ``translation_m`` and ``rotation_deg`` (``float64[n]``), ``converged``
    (``bool[n]``) and the points left out of those frames (``points_removed``)."""

    frame: np.ndarray
    translation_m: np.ndarray
    rotation_deg: np.ndarray
    converged: np.ndarray
    points_removed: int

    def summary(self) -> dict:
        def stats(x: np.ndarray) -> dict:
            if not x.size:
                return {"median": None, "p95": None, "max": None}
            return {"median": float(np.median(x)), "p95": float(np.quantile(x, 0.95)), "max": float(x.max())}

        return {
            "translation_m": stats(self.translation_m),
            "rotation_deg": stats(self.rotation_deg),
            "frames": int(self.frame.size),
            "points_removed": int(self.points_removed),
            "not_converged": int(np.count_nonzero(~self.converged)),
        }


@dataclass(frozen=True, eq=False)
class RegistrationImpact:
    """:func:`registration_impact`'s result. ``errors[algorithm][mode][condition]`` is a
    :class:`PoseErrors`; ``removed_fraction[condition]`` the share of returns left out."""

    label: str
    frames: int
    points_per_frame: float
    settings: RegistrationSettings
    monitor_method: str
    errors: dict[str, dict[str, dict[str, PoseErrors]]] = field(default_factory=dict)
    removed_fraction: dict[str, float] = field(default_factory=dict)
    map_source: str = "frames"

    def to_json(self) -> dict:
        """The ``registration-impact --json`` document (keys documented in README):
        ``algorithms`` → ``"<algorithm>_<mode>"`` → ``conditions`` → ``all`` /
        ``monitor_removed`` / ``multireturn_removed`` → ``translation_m`` / ``rotation_deg`` →
        ``median`` / ``p95`` / ``max``, with ``frames`` and ``points_removed``."""
        algorithms = {}
        for alg, by_mode in self.errors.items():
            for mode, by_cond in by_mode.items():
                algorithms[f"{alg}_{mode}"] = {
                    "algorithm": alg,
                    "mode": mode,
                    "conditions": {cond: e.summary() for cond, e in by_cond.items()},
                }
        return {
            "return": self.label,
            "frames": self.frames,
            "points_per_frame": self.points_per_frame,
            "monitor_method": self.monitor_method,
            "map": self.map_source,
            "removed_fraction": dict(self.removed_fraction),
            "settings": {k: getattr(self.settings, k) for k in self.settings.__dataclass_fields__},
            "algorithms": algorithms,
        }


def _small_gicp():
    try:
        import small_gicp
    except ImportError:  # pragma: no cover - depends on the install
        raise AnalysisError("registration-impact needs small_gicp: pip install 'lidarpkt[registration]'") from None
    return small_gicp


def points_of(stack: FrameStack, frame: int, range_mm: np.ndarray) -> np.ndarray:
    """XYZ (``float64[H, W, 3]`` m, zeros where ``range_mm`` is 0) of a ``[H, W]`` range image
    taken in frame ``frame``'s columns, through the sensor's geometry. Raises AnalysisError
    without a geometry."""
    geometry = stack.sensor.geometry
    if geometry is None:
        raise AnalysisError(f"{stack.sensor.source or stack.sensor.model}: no {stack.sensor.model} calibration to compute "
                            "points; give the sensor's file with --metadata (metadata=... in Python)")
    h, w = range_mm.shape
    az_cdeg = (np.rint(np.mod(stack.azimuth_deg[frame], 360.0) * 100.0).astype(np.int64) % 36000).astype(np.uint16)
    # what every vendor's geometry reads of a frame: its ranges, its columns' azimuths (Hesai, RoboSense)
    # and its firings' azimuths (Velodyne)
    view = SimpleNamespace(range_mm=np.ascontiguousarray(range_mm[None], np.uint32),
                           azimuth_deg=np.asarray(stack.azimuth_deg[frame], np.float64),
                           column_valid=stack.column_valid[frame], sensor=stack.sensor,
                           extra={"azimuth_cdeg": np.broadcast_to(az_cdeg, (h, w))})
    return geometry.xyz(cast("Frame", view))[0]


def removal_masks(
    stack: FrameStack,
    slot: int,
    *,
    method: str = DEFAULT_MONITOR_METHOD,
    gap_m: float = DEFAULT_GAP_M,
    neighbourhood: int = 5,
    threshold_m: float | None = None,
    conditions: Sequence[str] = CONDITIONS,
) -> dict[str, np.ndarray]:
    """``bool[K, H, W]`` per condition: the raypaths left out of each frame (see module docstring)."""
    k, _, h, w = stack.range_mm.shape
    thr = gap_m if threshold_m is None else float(threshold_m)
    out = {"all": np.zeros((k, h, w), bool)}
    if "monitor_removed" in conditions:
        out["monitor_removed"] = np.stack(
            [monitor_score(stack, frame=i, n=neighbourhood, method=method)[slot] > thr for i in range(k)])
    if "multireturn_removed" in conditions:
        out["multireturn_removed"] = np.broadcast_to(image_statistics(stack, gap_m=gap_m).multi_return[slot], (k, h, w))
    return out


def pose_error(t: np.ndarray) -> tuple[float, float]:
    """(translation m, rotation deg) of a 4 × 4 pose whose truth is the identity."""
    cos = np.clip((np.trace(t[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.linalg.norm(t[:3, 3])), float(np.degrees(np.arccos(cos)))


class _Registrar:
    """small_gicp targets built once per condition, sources registered against them."""

    def __init__(self, settings: RegistrationSettings):
        self.sg = _small_gicp()
        self.s = settings

    def prepare(self, points: np.ndarray):
        if len(points) < self.s.num_neighbors:
            raise AnalysisError(f"only {len(points)} points to register: too few returns (or too many removed)")
        cloud, tree = self.sg.preprocess_points(points, downsampling_resolution=self.s.downsampling_m,
                                                num_neighbors=self.s.num_neighbors, num_threads=self.s.threads)
        voxels = self.sg.GaussianVoxelMap(self.s.voxel_m)
        voxels.insert(cloud)
        return cloud, tree, voxels

    def align(self, target, source, algorithm: str):
        cloud, tree, voxels = target
        src = source[0]
        common = dict(max_correspondence_distance=self.s.max_correspondence_m, num_threads=self.s.threads,
                      max_iterations=self.s.max_iterations, translation_epsilon=self.s.translation_epsilon_m,
                      rotation_epsilon=np.radians(self.s.rotation_epsilon_deg))
        if algorithm == "vgicp":
            result = self.sg.align(voxels, src, **common)
        else:
            result = self.sg.align(cloud, src, tree, registration_type=ALGORITHMS[algorithm], **common)
        return np.asarray(result.T_target_source), bool(result.converged)


def registration_impact(
    stack: FrameStack,
    *,
    slot: int | str = 0,
    algorithms: Sequence[str] = tuple(ALGORITHMS),
    modes: Sequence[str] = MODES,
    monitor_method: str = DEFAULT_MONITOR_METHOD,
    gap_m: float = DEFAULT_GAP_M,
    neighbourhood: int = 5,
    threshold_m: float | None = None,
    settings: RegistrationSettings | None = None,
    map_range_mm: np.ndarray | None = None,
    conditions: Sequence[str] = CONDITIONS,
) -> RegistrationImpact:
    """Register every frame of a stationary capture and report the pose errors per condition.

    Args:
        stack: two or more frames of a stationary sensor.
        slot: the return to use (index or kind, :mod:`analysis.returns`).
        algorithms: names from :data:`ALGORITHMS`; modes: from :data:`MODES`.
        monitor_method, gap_m, neighbourhood, threshold_m: the monitor and the temporal
            statistics, as in :func:`analysis.multireturn.multireturn_map`.
        settings: small_gicp parameters.
        map_range_mm: ``[C, H, W]`` ranges (mm, 0 = none) to use as the scan-to-map target instead
            of all frames: e.g. a probabilistic raypath map's component means
            (:meth:`analysis.gmm_map.GmmMap.map_range_mm`), taken in frame 0's columns.
        conditions: a subset of :data:`CONDITIONS` to measure (all three by default).

    Raises:
        AnalysisError: fewer than two frames, unknown names, no geometry, too few points;
            small_gicp missing.
    """
    settings = settings or RegistrationSettings()
    settings.check()
    for kind, names, known in (("registration algorithm", algorithms, tuple(ALGORITHMS)), ("registration mode", modes, MODES),
                               ("condition", conditions, CONDITIONS), ("monitor method", [monitor_method], MONITOR_METHODS)):
        for name in names:
            if name not in known:
                raise AnalysisError(f"unknown {kind} {name!r}; choose from {', '.join(known)}")
    stack, slot = resolve(stack, slot)
    k = len(stack)
    if k < 2:
        raise AnalysisError(f"{stack.sensor.source or stack.sensor.model}: registration matches one frame to the next "
                            f"and this capture gives {k} {'frame' if k == 1 else 'frames'}; give a capture of 2 or more "
                            "rotations")
    removed = removal_masks(stack, slot, method=monitor_method, gap_m=gap_m, neighbourhood=neighbourhood,
                            threshold_m=threshold_m, conditions=conditions)
    rng = stack.range_mm[:, slot]
    has_return = sample_mask(stack, slot) & (rng > 0)
    xyz = np.stack([points_of(stack, i, np.where(has_return[i], rng[i], 0)) for i in range(k)])  # [K, H, W, 3]
    reg = _Registrar(settings)
    errors: dict = {a: {m: {} for m in modes} for a in algorithms}
    removed_fraction = {}
    n_ret = int(has_return.sum())
    for cond in conditions:
        keep = has_return & ~removed[cond]
        removed_fraction[cond] = float(np.count_nonzero(has_return & removed[cond]) / max(1, n_ret))
        sources = [reg.prepare(xyz[i][keep[i]]) for i in range(k)]
        targets = {}
        if "scan_to_scan" in modes:
            targets["scan_to_scan"] = (sources[0], range(1, k))
        if "scan_to_map" in modes:
            if map_range_mm is None:
                map_points = xyz[keep]
            else:
                map_points = _map_points(stack, map_range_mm, ~removed[cond][0])
            targets["scan_to_map"] = (reg.prepare(map_points), range(k))
        for mode, (target, frame_range) in targets.items():
            frames = np.fromiter(frame_range, np.int64)
            lost = int(np.count_nonzero((has_return & removed[cond])[frames]))
            for alg in algorithms:
                errors[alg][mode][cond] = _register(reg, target, [sources[i] for i in frames], alg, frames, lost)
    label = stack.return_labels[slot]
    return RegistrationImpact(label, k, n_ret / k, settings, monitor_method, errors, removed_fraction,
                              "frames" if map_range_mm is None else "gmm_map")


def _register(reg: _Registrar, target, sources: list, algorithm: str, frames: np.ndarray, lost: int) -> PoseErrors:
    """Each source registered to ``target``: their pose errors (the truth is no motion)."""
    poses = [reg.align(target, src, algorithm) for src in sources]
    err = np.array([pose_error(t) for t, _ in poses]).reshape(-1, 2)
    return PoseErrors(frames, err[:, 0], err[:, 1], np.array([c for _, c in poses], bool), lost)


def _map_points(stack: FrameStack, map_range_mm: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Points of a ``[C, H, W]`` range map (0 = no component) at the pixels ``keep``."""
    m = np.asarray(map_range_mm)
    if m.ndim != 3 or m.shape[1:] != stack.range_mm.shape[2:]:
        raise AnalysisError(f"the map has shape {m.shape}; expected [C, {stack.range_mm.shape[2]}, {stack.range_mm.shape[3]}] for this capture")
    pts = [points_of(stack, 0, np.where(keep & (m[c] > 0), m[c], 0)) for c in range(m.shape[0])]
    ok = [(m[c] > 0) & keep for c in range(m.shape[0])]
    return np.concatenate([p[o] for p, o in zip(pts, ok)])
