"""The multi-return analysis at scale: one map per capture, computed in parallel, and a summary.

:func:`multireturn_maps` runs :func:`analysis.multireturn.multireturn_map` (Rife & Li's
whole-image statistics and monitor) on every capture under PATHS, one pure task per capture on
the job's engine, and writes ``OUTDIR/maps/CAPTURE_STEM.npz`` (what ``lidarpkt multireturn IN -o
MAP.npz`` writes) and ``OUTDIR/summary.csv``: one row per capture, sensor and return slot with
the multi-return fraction, the non-return fraction and the frames used. A capture that cannot be
analysed gets a row with its error. The analysis package is imported by the task, not here:
``lidarpkt`` does not depend on ``analysis``.
"""

from __future__ import annotations

import csv
import os
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

from lidarpkt.errors import LidarpktError, LidarpktWarning

from .engine import EngineOptions, ProgressCallback, run_rows
from .plan import PlanError, is_remote, local_path, plan_captures

SUMMARY_COLUMNS = ("capture", "input", "sensor", "model", "return_mode", "slot", "return_label", "frames_used",
                   "raypaths_with_returns", "multi_return_fraction", "nonreturn_fraction", "monitor_flagged",
                   "map", "seconds", "error")


@dataclass(frozen=True)
class MapTask:
    """One capture's analysis (picklable). ``options`` are :func:`multireturn_map`'s keyword arguments."""

    input: str
    capture: str
    output: str
    metadata: tuple[str, ...] = ()
    frames: tuple[int | None, int | None] | None = None
    grid_deg: float | None = None
    options: tuple[tuple[str, Any], ...] = ()
    open_options: tuple[tuple[str, Any], ...] = ()


def _save_npz(path: Path, arrays: dict[str, Any]) -> None:
    import numpy as np

    from lidarpkt.writers.base import write_atomic

    def save(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **arrays)

    write_atomic(path, save)


def map_capture(task: MapTask) -> list[dict[str, Any]]:
    """Analyse one capture and write its map; the summary rows (one per return slot).

    Never raises on bad input: the capture's one row then carries the error.
    """
    import numpy as np

    from lidarpkt.analysis.multireturn import multireturn_map
    from lidarpkt.analysis.returns import sensor_returns
    from lidarpkt.analysis.stack import load_stack

    start = time.perf_counter()
    base: dict[str, Any] = {c: None for c in SUMMARY_COLUMNS}
    base.update(capture=task.capture, input=task.input)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", LidarpktWarning)
            stack = load_stack(local_path(task.input), metadata=list(task.metadata) or None, frames=task.frames,
                               resolution_deg=task.grid_deg, **dict(task.open_options))
            stack = sensor_returns(stack)  # as the single-capture verb: the returns as the sensor defines them
            mr = multireturn_map(stack, **dict(task.options))
        rel = f"maps/{Path(task.capture).stem}.npz"
        out = Path(local_path(task.output)) / rel
        out.parent.mkdir(parents=True, exist_ok=True)
        _save_npz(out, {**mr.to_npz_dict(), "frame_id": stack.frame_id})
    except (LidarpktError, OSError) as exc:
        text = str(exc) if isinstance(exc, LidarpktError) else f"{task.input}: {exc.strerror or exc}"
        return [{**base, "seconds": time.perf_counter() - start, "error": text}]
    s = mr.stats
    seconds = time.perf_counter() - start
    rows = []
    for i, label in enumerate(s.return_labels):
        samples = int(s.n_samples[i].sum())
        returns = int(s.n_returns[i].sum())
        with_returns = int(np.count_nonzero(s.n_returns[i]))
        rows.append({**base, "sensor": stack.sensor.source or stack.sensor.serial, "model": stack.sensor.model,
                     "return_mode": stack.sensor.return_mode, "slot": i, "return_label": label,
                     "frames_used": len(stack), "raypaths_with_returns": with_returns,
                     "multi_return_fraction": int(np.count_nonzero(s.multi_return[i])) / with_returns
                     if with_returns else None,
                     "nonreturn_fraction": (samples - returns) / samples if samples else None,
                     "monitor_flagged": int(np.count_nonzero(mr.monitor_flags[i])), "map": rel, "seconds": seconds})
    return rows


def multireturn_maps(
    paths: Sequence[str | os.PathLike[str]],
    out: str | os.PathLike[str],
    *,
    metadata: Sequence[str | os.PathLike[str]] = (),
    glob: str | None = None,
    frames: tuple[int | None, int | None] | None = None,
    grid_deg: float | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    client: Any = None,
    progress: ProgressCallback | None = None,
    open_options: Mapping[str, Any] | None = None,
    **map_options: Any,
) -> list[dict[str, Any]]:
    """One multi-return map per capture under ``paths`` in ``out/maps/``, and ``out/summary.csv``.

    Args:
        paths: captures or folders of them (local paths or ``file://``).
        out: the output folder (created; its parent must exist).
        metadata, glob, open_options: as for :func:`lidarpkt.archive.export` (Ouster metadata beside each
            capture by default).
        frames: ``(A, B)``: complete frames A..B-1 of each capture; grid_deg: the VLP-16 azimuth grid.
        workers, scheduler, client, progress: the engine (default: a local cluster of the CPU count), and
            what it tells as it goes (:class:`~lidarpkt.archive.engine.JobProgress`).
        **map_options: :func:`analysis.multireturn.multireturn_map`'s options (``gap_m``,
            ``neighbourhood``, ``monitor_frame``, ``threshold_m``, ``method``).

    Returns:
        the summary rows (:data:`SUMMARY_COLUMNS`), in input order.

    Raises:
        PlanError: bad paths or output folder; EngineError: the engine cannot start.
    """
    out = os.fspath(out)
    if is_remote(out):
        raise PlanError(f"-o {out}: multireturn writes to a local (or file://) folder")
    root = Path(local_path(out))
    if not root.parent.is_dir():
        raise PlanError(f"-o {out}: the folder {root.parent} does not exist; create it first")
    if root.exists() and not root.is_dir():
        raise PlanError(f"-o {out}: a file has this name; give a folder for the maps and the summary")
    root.mkdir(exist_ok=True)
    captures = plan_captures(paths, glob=glob, metadata=metadata, open_options=open_options)
    tasks = [MapTask(c.url, c.name, out, c.metadata, frames, grid_deg, tuple(sorted(map_options.items())),
                     c.open_options) for c in captures]
    rows = run_rows(map_capture, tasks, [c.size_bytes for c in captures],
                    EngineOptions(workers=workers, scheduler=scheduler, client=client), label="multireturn",
                    progress=progress, lost=_lost_map)
    def save(tmp: Path) -> None:
        with open(tmp, "w", newline="", encoding="utf-8") as fh:
            writer = csv.DictWriter(fh, fieldnames=SUMMARY_COLUMNS)
            writer.writeheader()
            writer.writerows(rows)

    from lidarpkt.writers.base import write_atomic

    write_atomic(root / "summary.csv", save)
    return rows


def _lost_map(task: MapTask, why: str) -> list[dict[str, Any]]:
    return [{**{c: None for c in SUMMARY_COLUMNS}, "capture": task.capture, "input": task.input,
             "error": f"{task.input}: {why}"}]
