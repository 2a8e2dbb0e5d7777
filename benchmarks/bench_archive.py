"""Archive jobs on Dask: a folder of captures exported with 1 and 2 workers, one large capture by
segments, Dask's overhead per task, and the throughput per core (issue 13).

At ``--scale 1`` (the default) the folder holds 20 dual-return VLP-16 captures of ~105 MB each
(2.1 GB) and the large capture is ~1 GB; ``--scale 0.05`` makes everything 20 times smaller for
a quick check. Captures are generated once into ``--workdir`` (kept between runs) by
:func:`bench_velodyne.build` (lidarpkt's encoder, real pcap framing); every export goes to a fresh
folder there, removed afterwards.

    python benchmarks/bench_archive.py [--scale 1] [--format parquet] [--workdir DIR] [--json FILE]

Reported: wall time and MB/s of each run, the speedup of 2 workers over 1 (``--workers 1`` runs in
this process, ``--workers 2`` on a LocalCluster of 2 processes, its start-up included), the
overhead of one Dask task (a no-op mapped 2000 times on the running cluster), and the throughput
per core (input MB/s divided by the workers).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

from lidarpkt.archive import export  # noqa: E402

SECONDS_PER_FILE = 55.0  # ~105 MB of dual-return VLP-16 packets
FILES = 20
LARGE_SECONDS = 530.0  # ~1 GB


def _noop(x: int) -> int:
    return x


def make_archive(workdir: Path, scale: float) -> tuple[Path, Path]:
    """(folder of FILES captures, one large capture), built once per scale."""
    from bench_velodyne import build

    folder = workdir / f"archive-{scale:g}"
    large = workdir / f"large-{scale:g}" / "large.pcap"
    if not (folder / f"drive{FILES - 1:02d}.pcap").exists():
        folder.mkdir(parents=True, exist_ok=True)
        base = folder / "drive00.pcap"
        build(base, SECONDS_PER_FILE * scale, seed=0)
        for i in range(1, FILES):  # the same packets: decoding cost does not depend on the content much
            shutil.copyfile(base, folder / f"drive{i:02d}.pcap")
    if not large.exists():
        large.parent.mkdir(parents=True, exist_ok=True)
        build(large, LARGE_SECONDS * scale, seed=1)
    return folder, large


def timed_export(paths: list[Path], out: Path, fmt: str, **options) -> tuple[float, list[dict]]:
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    rows = export(paths, out, format=fmt, **options).to_pylist()
    wall = time.perf_counter() - t0
    shutil.rmtree(out, ignore_errors=True)
    failed = [r for r in rows if r["status"] != "done"]
    if failed:
        raise SystemExit(f"export failed: {failed[0]['error']}")
    return wall, rows


def count_pass_cpu(large: Path, segment_bytes: int) -> float:
    """CPU seconds of the count pass a segmented export runs before its units (all segments but the last)."""
    from lidarpkt.archive.ordinals import CountTask, count_segment
    from lidarpkt.containers.segments import plan_segments

    segments = plan_segments(large, segment_bytes)
    t0 = time.process_time()
    for seg in segments[:-1]:
        count_segment(CountTask(f"seg{seg.index}", str(large), seg))
    return time.process_time() - t0


def dask_overhead(n_tasks: int = 2000) -> dict:
    """Seconds per task of a no-op on a LocalCluster of 2 processes, and the cluster's start-up."""
    import distributed

    t0 = time.perf_counter()
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                                  silence_logs=logging.ERROR) as c, \
            distributed.Client(c) as client:
        startup = time.perf_counter() - t0
        client.gather(client.map(_noop, range(50), pure=False))  # warm up
        t1 = time.perf_counter()
        client.gather(client.map(_noop, range(n_tasks), pure=False))
        per_task = (time.perf_counter() - t1) / n_tasks
    return {"cluster_startup_s": startup, "per_task_s": per_task, "tasks": n_tasks}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scale", type=float, default=1.0, help="size factor (1: 20 × 105 MB + 1 GB; 0.05 for a quick run)")
    ap.add_argument("--format", default="parquet", help="export format (default parquet)")
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/lidarpkt_bench_archive"), help="captures and outputs")
    ap.add_argument("--json", type=Path, help="also write the figures as JSON")
    args = ap.parse_args()
    args.workdir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    folder, large = make_archive(args.workdir, args.scale)
    files = sorted(folder.glob("*.pcap"))
    folder_mb = sum(f.stat().st_size for f in files) / 1e6
    large_mb = large.stat().st_size / 1e6
    print(f"captures: {len(files)} files, {folder_mb:.0f} MB; large capture {large_mb:.0f} MB "
          f"(ready in {time.perf_counter() - t0:.1f} s); format {args.format}; {os.cpu_count()} CPUs")
    out = args.workdir / "out"
    figures: dict = {"scale": args.scale, "format": args.format, "folder_mb": folder_mb, "large_mb": large_mb}
    for workers in (1, 2):
        wall, rows = timed_export([folder], out, args.format, workers=workers)
        cpu = sum(r["cpu_seconds"] for r in rows)
        figures[f"folder_{workers}w_s"] = wall
        figures[f"folder_{workers}w_unit_cpu_s"] = cpu
        print(f"folder, {workers} worker(s): {wall:7.2f} s  {folder_mb / wall:7.1f} MB/s  "
              f"{folder_mb / wall / workers:6.1f} MB/s per worker; units used {cpu:.1f} CPU s = "
              f"{folder_mb / cpu:.1f} MB per CPU second  ({sum(r['frames'] for r in rows)} frames)")
    figures["folder_speedup"] = figures["folder_1w_s"] / figures["folder_2w_s"]
    print(f"folder speedup 2 vs 1 worker: {figures['folder_speedup']:.2f}x")
    segment = max(1 << 20, int(large.stat().st_size // 16))
    for workers in (1, 2):
        wall, rows = timed_export([large], out, args.format, workers=workers, segment_bytes=segment)
        figures[f"large_{workers}w_s"] = wall
        print(f"large capture, {len(rows)} segments, {workers} worker(s): {wall:7.2f} s  {large_mb / wall:7.1f} MB/s")
        figures[f"large_{workers}w_unit_cpu_s"] = sum(r["cpu_seconds"] for r in rows)
    figures["large_speedup"] = figures["large_1w_s"] / figures["large_2w_s"]
    print(f"large capture speedup 2 vs 1 worker: {figures['large_speedup']:.2f}x")
    count_cpu = count_pass_cpu(large, segment)
    figures["large_count_pass_cpu_s"] = count_cpu
    print(f"large capture count pass (whole-file VLP-16 ordinals of the segments): {count_cpu:.2f} CPU s = "
          f"{count_cpu / figures['large_1w_unit_cpu_s'] * 100:.0f}% of the units' {figures['large_1w_unit_cpu_s']:.2f} CPU s")
    over = dask_overhead()
    figures.update(over)
    print(f"Dask: LocalCluster(2) start-up {over['cluster_startup_s']:.2f} s, {over['per_task_s'] * 1e3:.2f} ms per task "
          f"({over['tasks']} no-op tasks)")
    # per core: the CPU the units used (on a shared machine, wall time also counts other people's work)
    per_core = folder_mb / figures["folder_2w_unit_cpu_s"]
    figures["mb_per_cpu_s"] = per_core
    core_hours_pb = 1e9 / per_core / 3600
    figures["core_hours_per_pb"] = core_hours_pb
    print(f"throughput per core (MB per CPU second of the units): {per_core:.1f} MB/s → 1 PB = {core_hours_pb:,.0f} core-hours "
          f"({core_hours_pb / 1000 / 24:.1f} days on 1000 cores)")
    if args.json:
        args.json.write_text(json.dumps(figures, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
