"""Every row of the performance table (issue 34) in one run: lidarpkt against its reference, as whole processes.

    python benchmarks/run_all.py [--repeat 3] [--workdir DIR] [--only velodyne,ouster,xyz,workers,memory,mcap,osf]
                                 [--ouster-frames 300] [--vlp-seconds 60]
    python benchmarks/run_all.py --only pcap,analysis,record,start,memory-large     # the other steps

Each measurement is a whole process (``python benchmarks/workloads.py KIND ...``: interpreter start, imports
and the work, as a user runs it), lidarpkt and the reference alternately: one untimed round of each (page
cache, ``.pyc`` files), then ``--repeat`` timed rounds; the median wall time of each side, their ratio, and
the ratio of each paired round ("runs"). The CPU time of the processes (and of their worker processes) is
printed beside it: steadier on a shared machine, but a parallel run spends more CPU to take less wall time.
``lidarpkt``'s ``.pyc`` files are compiled first (the environment may forbid writing them), as the reference's
were at installation. Every point or field is touched on both sides (``workloads.py`` says how). A target is
"met" when the median ratio meets it; the runs show how steady it is.

Rows (captures built once in ``--workdir``):

- velodyne: VLP-16 60 s strongest and dual (``bench_velodyne.build``), and the real VLP-32C and VLS-128 bags of
  nebula and HDL-32E pcap of rust-lidar-utils repeated (``bench_velodyne.REAL_CAPTURES``: × 150, × 25, × 300,
  device times moved on by the stream's span): frames + XYZ vs velodyne_decoder, ≥ 4×.
- ouster: OS-2-128 single (RNG19), OS-0-32 dual, OS-0-128 low data rate (RNG15), OS-1-64 legacy × 300 and
  OS-1-128 low data rate × 100 (``bench_ouster.build_capture``): frames, every field, vs ouster-sdk, ≥ 1.5×.
- xyz: the same Ouster captures, frames + ``xyz(float32)`` (ouster-sdk's ``XYZLutFloat`` values) over frames
  alone, ≤ 1.2× (float64 for information).
- workers: OS-2-128 × 300 (every field) and VLP-16 60 s dual (frames + XYZ) with the default ``workers``
  against ``workers=1``, ≥ 1.7× where the capture is large (and ``workers=2`` against ``workers=1``, for information).
- memory: peak RSS decoding VLP-16 60 s with XYZ (strongest and dual): the default ``workers`` (the process,
  and its largest worker) and ``workers=1``, ≤ 80 MB (velodyne_decoder's for scale).
- mcap: ``lidarpkt decode`` of VLP-16 60 s dual to MCAP ``--topics packets,points`` over the same to NPZ, ≤ 1.5×.
- osf: the OSF files of the ouster-sdk fixtures, every field, vs ouster-sdk's ``OsfFrameSetSource``, ≥ 1×.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(REPO))

from lidarpkt.core import kernels  # noqa: E402

EXTERNAL = Path(os.environ.get("LIDARPKT_EXTERNAL_FIXTURES", REPO.parent / "shared" / "fixtures" / "external"))
ROWS: list[tuple] = []  # (name, ours, reference, ratio, target, met)
ARGS = argparse.Namespace(repeat=3)  # the command line's, set by main


def machine() -> str:
    cpu = next((x.split(":", 1)[1].strip() for x in open("/proc/cpuinfo") if x.startswith("model name")),
               platform.processor())
    mem_kb = next(int(x.split()[1]) for x in open("/proc/meminfo") if x.startswith("MemTotal"))
    return f"{os.cpu_count()} CPUs ({cpu}), {mem_kb / 1e6:.0f} GB RAM, Python {platform.python_version()}, NumPy {np.__version__}"


def load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def row(name, ours, ref, ratio, target, met):
    ROWS.append((name, ours, ref, ratio, target, met))
    print(f"  {name:<52} {ours:>24} {ref:>24} {ratio:>30}  {target:<8} {'met' if met else 'NOT met'}", flush=True)


# ------------------------------------------------------------------------------------ whole processes
class Run:
    """One workload as a whole process: ``python benchmarks/workloads.py ARGV``."""

    def __init__(self, label: str, *argv: object, before=None) -> None:
        self.label = label
        self.argv = [str(a) for a in argv]
        self.before = before  # called before each run (e.g. removing an output file)
        self.walls: list[float] = []
        self.cpus: list[float] = []
        self.result: dict = {}

    def __call__(self, timed: bool = True) -> None:
        if self.before is not None:
            self.before()
        env = dict(os.environ, PYTHONPATH=str(REPO))
        start = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        out = subprocess.run([sys.executable, str(HERE / "workloads.py"), *self.argv], capture_output=True, text=True,
                             env=env, cwd=REPO)
        wall = time.perf_counter() - t0
        end = resource.getrusage(resource.RUSAGE_CHILDREN)
        if out.returncode != 0:
            raise RuntimeError(f"{self.label}: {' '.join(self.argv)} failed:\n{out.stderr[-3000:]}")
        self.result = json.loads(out.stdout.strip().splitlines()[-1])
        if timed:
            self.walls.append(wall)
            self.cpus.append((end.ru_utime - start.ru_utime) + (end.ru_stime - start.ru_stime))

    @property
    def wall(self) -> float:
        return statistics.median(self.walls)

    @property
    def cpu(self) -> float:
        return statistics.median(self.cpus)

    def text(self) -> str:
        return f"{self.wall:.3f}s (cpu {self.cpu:.3f})"


def alternate(repeat: int, *runs: Run) -> None:
    """Each run once untimed, then all of them in turn ``repeat`` times."""
    for r in runs:
        r(timed=False)
    for _ in range(repeat):
        for r in runs:
            r()


def ratio(num: Run, den: Run) -> tuple[float, str]:
    """(median wall ratio num / den, its text with the CPU ratio and each paired round's ratio)."""
    value = num.wall / den.wall
    each = "/".join(f"{a / b:.2f}" for a, b in zip(num.walls, den.walls))
    return value, f"{value:.2f} (cpu {num.cpu / den.cpu:.2f}; runs {each})"


def compare(name: str, ours: Run, ref: Run, *, at_least: float | None = None, at_most: float | None = None,
            reference_over_ours: bool = True) -> None:
    """A table row: ``ref / ours`` (how many times faster) or ``ours / ref`` (``reference_over_ours=False``)."""
    value, text = ratio(ref, ours) if reference_over_ours else ratio(ours, ref)
    target = f"≥ {at_least}" if at_least is not None else f"≤ {at_most}" if at_most is not None else "(info)"
    met = (at_least is None or value >= at_least) and (at_most is None or value <= at_most)
    row(name, ours.text(), ref.text(), text, target, met)


def same_work(ours: Run, ref: Run, keys=("frames", "points")) -> str:
    """A note when the two sides did not produce the same frames / points (each reference cuts its own edges)."""
    differ = [f"{k} {ours.result.get(k)} vs {ref.result.get(k)}" for k in keys
              if k in ref.result and ours.result.get(k) != ref.result.get(k)]
    return f" [{', '.join(differ)}]" if differ else ""


def versus(label: str, path: Path, ours: tuple, ref: tuple, at_least: float, keys=("frames", "points")) -> None:
    """lidarpkt's workload ``ours`` against the reference's ``ref`` (``workloads.py`` arguments) on ``path``."""
    a, b = Run("lidarpkt", *ours), Run("reference", *ref)
    alternate(ARGS.repeat, a, b)
    compare(f"{label} ({path.stat().st_size / 1e6:.0f} MB){same_work(a, b, keys)}", a, b, at_least=at_least)


# ------------------------------------------------------------------------------------ captures
def vlp_capture(args, work: Path, mode: str) -> Path:
    import bench_velodyne as bv

    path = work / f"vlp16_{mode}_{int(args.vlp_seconds)}s.pcap"
    if not path.exists():
        bv.build(path, args.vlp_seconds, mode=mode)
    return path


OUSTER_CAPTURES = (("single", "OS-2-128 single (RNG19)", 1), ("dual", "OS-0-32 dual", 1), ("ldr", "OS-0-128 RNG15", 1),
                   ("legacy", "OS-1-64 legacy", 1), ("ldr128", "OS-1-128 RNG15", 3))  # frames per copy of the source


def ouster_capture(args, work: Path, name: str, per_copy: int) -> tuple[Path | None, Path]:
    import bench_ouster as bo

    pcap, meta = (EXTERNAL / p for p in bo.CAPTURES[name])
    if not pcap.exists():
        return None, meta
    copies = max(1, args.ouster_frames // per_copy)
    path = work / f"ouster_{name}_x{copies}.pcap"
    if not path.exists():
        bo.build_capture(pcap, meta, copies, path)
    return path, meta


# ------------------------------------------------------------------------------------ the table's steps
def velodyne(args, work: Path) -> None:
    import bench_velodyne as bv

    print(f"\nVelodyne: frames + XYZ vs velodyne_decoder (load {load()})")
    for mode in ("strongest", "dual"):
        path = vlp_capture(args, work, mode)
        versus(f"VLP-16 {mode} {args.vlp_seconds:.0f} s", path, ("velodyne", path),
               ("velodyne_decoder", path, "vlp16"), 4.0)
    for model, _, copies in bv.REAL_CAPTURES:
        path = bv.real_capture(work, model, EXTERNAL)
        if path is None:
            print(f"  {model}: external fixtures missing ({EXTERNAL})")
            continue
        versus(f"{model} real × {copies}", path, ("velodyne", path), ("velodyne_decoder", path, "auto"), 4.0)


def ouster(args, work: Path) -> None:
    print(f"\nOuster: frames, every field, vs ouster-sdk (load {load()})")
    for name, label, per_copy in OUSTER_CAPTURES:
        path, meta = ouster_capture(args, work, name, per_copy)
        if path is None:
            print(f"  {label}: external fixtures missing ({meta.parent})")
            continue
        versus(label, path, ("ouster", path, meta), ("ouster_sdk", path, meta), 1.5, ("frames",))


def xyz(args, work: Path) -> None:
    print(f"\nXYZ on top of decoding, Ouster (load {load()})")
    for name, label, per_copy in OUSTER_CAPTURES:
        path, meta = ouster_capture(args, work, name, per_copy)
        if path is None:
            continue
        frames = Run("frames", "ouster", path, meta)
        xyz32, xyz64 = Run("xyz32", "ouster", path, meta, "xyz32"), Run("xyz64", "ouster", path, meta, "xyz64")
        alternate(args.repeat, frames, xyz32, xyz64)
        compare(f"{label}: frames + XYZ float32 / frames", xyz32, frames, at_most=1.2, reference_over_ours=False)
        compare(f"{label}: frames + XYZ float64 / frames", xyz64, frames, reference_over_ours=False)


def workers(args, work: Path) -> None:
    print(f"\nBoth cores: the default workers vs workers=1 (load {load()}; {os.cpu_count()} CPUs)")
    path, meta = ouster_capture(args, work, "single", 1)
    cases = [(f"VLP-16 dual {args.vlp_seconds:.0f} s, frames + XYZ", ("velodyne", vlp_capture(args, work, "dual")))]
    if path is not None:
        cases.insert(0, ("OS-2-128 × 300, every field", ("ouster", path, meta, "none")))
    for label, argv in cases:
        default, one, two = Run("default", *argv, "default"), Run("workers=1", *argv, "1"), Run("workers=2", *argv, "2")
        alternate(args.repeat, default, one, two)
        compare(f"{label}: default workers vs workers=1", default, one, at_least=1.7)
        # what the second core gives where the default declines it (a load average over CPUs - 2)
        compare(f"{label}: workers=2 vs workers=1", two, one)


def memory(args, work: Path) -> None:
    print(f"\nPeak memory decoding VLP-16 {args.vlp_seconds:.0f} s with XYZ (load {load()})")
    for mode in ("strongest", "dual"):
        path = vlp_capture(args, work, mode)
        ref = Run("velodyne_decoder", "velodyne_decoder", path, "vlp16")
        ref()
        for w in ("default", "1"):
            run = Run(f"workers={w}", "velodyne", path, w)
            run()
            main, child = run.result["hwm_mb"], run.result["children_hwm_mb"]
            workers_text = f", largest worker {child:.0f} MB" if child else ""
            row(f"peak RSS, VLP-16 {mode}, workers={w}", f"{main:.0f} MB{workers_text}",
                f"velodyne_decoder {ref.result['hwm_mb']:.0f} MB", "", "≤ 80 MB", max(main, child) <= 80)


def mcap(args, work: Path) -> None:
    print(f"\nDecode to MCAP (packets, points) vs to NPZ, VLP-16 {args.vlp_seconds:.0f} s dual (load {load()})")
    path = vlp_capture(args, work, "dual")
    out_mcap, out_npz = work / "out.mcap", work / "out.npz"

    def clear(p: Path):
        return lambda: p.unlink(missing_ok=True)  # a new file each time, as a user's first run writes it

    ours = Run("mcap", "decode", path, "-o", out_mcap, "--topics", "packets,points", "-q", before=clear(out_mcap))
    ref = Run("npz", "decode", path, "-o", out_npz, "-q", before=clear(out_npz))
    alternate(args.repeat, ours, ref)
    sizes = f"MCAP {out_mcap.stat().st_size / 1e6:.0f} MB, NPZ {out_npz.stat().st_size / 1e6:.0f} MB"
    compare(f"decode to MCAP packets,points / to NPZ ({sizes})", ours, ref, at_most=1.5, reference_over_ours=False)
    for p in (out_mcap, out_npz):
        p.unlink(missing_ok=True)


OSF_FILES = ("OS-1-128_v2.3.0_1024x10_lb_n3.osf", "OS-0-128_v3.0.1_1024x10_20241017_141645.osf", "osf_fw_3.2_10scans.osf")


def osf(args, work: Path) -> None:
    print(f"\nOSF files, every field, vs ouster-sdk's OsfFrameSetSource (load {load()})")
    for name in OSF_FILES:
        path = EXTERNAL / "ouster-sdk" / name
        if not path.exists():
            continue
        versus(name, path, ("osf", path), ("osf_sdk", path), 1.0, ("frames",))


# ------------------------------------------------------------------------------------ the other steps (in process)
def alternate_in_process(repeat: int, *fns):
    """Each function once untimed, then in turn ``repeat`` times, in this process; per function (median wall,
    median CPU, last result, the wall time of every run)."""
    runs = [[] for _ in fns]
    for fn in fns:
        fn()
    for _ in range(repeat):
        for i, fn in enumerate(fns):
            w, c = time.perf_counter(), time.process_time()
            out = fn()
            runs[i].append((time.perf_counter() - w, time.process_time() - c, out))
    return [(statistics.median(r[0] for r in rs), statistics.median(r[1] for r in rs), rs[-1][2], [r[0] for r in rs])
            for rs in runs]


def fmt(wall, cpu):
    return f"{wall:.3f}s (cpu {cpu:.3f})"


# ------------------------------------------------------------------------------------ pcap
def pcap(args, work: Path) -> None:
    import bench_pcap as bp

    print(f"\npcap reading alone, warm page cache (load {load()})")
    # real VLP-16 data interleaved with position packets (VeloView's capture repeated): record sizes
    # alternate every 3 records on average, so no run of equal strides can be checked at once
    velo = bp.EXTERNAL / "veloview" / "vlp-16-test-90deg-1-50-frames.pcap"
    mixed = work / "mixed_vlp16_veloview_100mb.pcap"
    if velo.exists() and not mixed.exists():
        bp.build(mixed, velo, 100_000_000)
    mixed_ng = mixed.with_suffix(".pcapng")  # the same records as pcapng (Wireshark's default format)
    if velo.exists() and not mixed_ng.exists():
        bp.build(mixed_ng, velo, 100_000_000, pcapng=True)
    files = sorted((p for p in [*work.glob("*.pcap"), *work.glob("*.pcapng")] if not p.name.startswith("mem_")),
                   key=lambda p: -p.stat().st_size)
    for path in files:
        bp.run_cat(path)  # warm the page cache
        (lw, lc, *_), (cw, cc, *_) = alternate_in_process(args.repeat, lambda p=path: bp.run_batches(p), lambda p=path: bp.run_cat(p))
        mb = path.stat().st_size / 1e6
        row(f"read_batches {path.name} ({mb:.0f} MB)", f"{lw:.3f}s {mb / lw:.0f} MB/s", f"cat {cw:.3f}s {mb / cw:.0f} MB/s",
            f"{lw / cw:.2f}x cat", "≤ 5x", lw / cw <= 5)


# ------------------------------------------------------------------------------------ memory
_CHILD = r"""
import sys, lidarpkt
n = 0
meta = sys.argv[3] if len(sys.argv) > 3 else None
for f in lidarpkt.open(sys.argv[1], metadata=meta, workers=int(sys.argv[2])):
    n += 1
hwm = next(l.split()[1] for l in open('/proc/self/status') if l.startswith('VmHWM'))
print(n, hwm)
"""


def _peak_rss(path: Path, n_workers: int, meta: Path | None = None) -> tuple[int, float, float]:
    """(frames, peak RSS in MB, seconds) of a child process decoding ``path`` with ``n_workers``."""
    t = time.perf_counter()
    argv = [sys.executable, "-c", _CHILD, str(path), str(n_workers)] + ([str(meta)] if meta else [])
    out = subprocess.run(argv, capture_output=True, text=True, cwd=REPO, check=True).stdout.split()
    return int(out[0]), int(out[1]) / 1024, time.perf_counter() - t


def memory_large(args, work: Path) -> None:
    import bench_ouster as bo

    pcap, meta = (bo.EXTERNAL / p for p in bo.CAPTURES["single"])
    frame_bytes = 64 * (16 + 42 + 24832)  # 64 records per OS-2-128 frame: record + Ethernet/IPv4/UDP headers + payload
    frames = max(1, int(args.memory_gb * 1e9 / frame_bytes))
    small = work / f"mem_{frames}.pcap"
    big = work / f"mem_{frames}x{args.memory_factor}.pcap"
    vlp = work / f"mem_vlp16_{args.memory_gb}gb.pcap"
    need = (args.memory_gb * (2 + args.memory_factor)) * 1e9
    free = shutil.disk_usage(work).free
    print(f"\nmemory: peak RSS decoding {args.memory_gb} GB and {args.memory_factor}x that (load {load()}; "
          f"{free / 1e9:.0f} GB free under {work})")
    if free < need * 1.1:
        print(f"  not enough disk for {need / 1e9:.0f} GB: skipped")
        return
    try:
        if not small.exists():
            bo.build_capture(pcap, meta, frames, small)
        if not big.exists():
            with open(small, "rb") as src, open(big, "wb") as dst:
                head = src.read(24)
                dst.write(head)
                for _ in range(args.memory_factor):  # records repeated: frame ids wrap, times repeat
                    src.seek(24)
                    shutil.copyfileobj(src, dst, 16 << 20)
        for path in (small, big):
            for n_workers in (1, 2, 3):
                n, hwm_mb, dt = _peak_rss(path, n_workers, meta)
                row(f"peak RSS, {path.stat().st_size / 1e9:.1f} GB Ouster capture, workers={n_workers} ({n} frames, "
                    f"{dt:.0f} s)", f"{hwm_mb:.0f} MB", "", "", "< 400 MB", hwm_mb < 400)
        # VLP-16: a dual-return capture of the same size (generated sensor time; no 10x copy, whose
        # repeated device times would be dropped as late packets)
        import bench_velodyne as bv

        seconds = args.memory_gb * 1e9 / (90422 * 1264 / 60)  # bytes per second of bench_velodyne's dual capture
        if not vlp.exists():
            bv.build(vlp, seconds)
        for n_workers in (1, 2, 3):
            n, hwm_mb, dt = _peak_rss(vlp, n_workers)
            row(f"peak RSS, {vlp.stat().st_size / 1e9:.1f} GB VLP-16 dual capture, workers={n_workers} ({n} frames, "
                f"{dt:.0f} s)", f"{hwm_mb:.0f} MB", "", "", "< 400 MB", hwm_mb < 400)
    finally:
        if not args.keep_memory_files:
            for p in (small, big, vlp):
                p.unlink(missing_ok=True)


# ------------------------------------------------------------------------------------ analysis
def analysis(args, work: Path) -> None:
    import bench_analysis as ba
    from lidarpkt.analysis.multireturn import image_statistics

    print(f"\nanalysis (load {load()})")
    stack = ba.synthetic_stack(30, 1, 64, 1024)
    ((w, c, *_),) = alternate_in_process(args.repeat, lambda: image_statistics(stack))
    row("image_statistics 64x1024x30", fmt(w, c), "", "", "< 2 s", w < 2)


# ------------------------------------------------------------------------------------ record
def record(args, work: Path) -> None:
    import bench_record as br

    print(f"\nrecording at 10x real time (load {load()})")
    for name in br.CAPTURES:
        r = br.run_one(name, 10.0, args.record_seconds, work)
        lost = r["sent"] - r["received"]
        cpu = r.get("recorder_cpu_pct")
        row(f"record {name} at 10x", f"{r['received']}/{r['sent']} received", f"cpu {cpu}%" if cpu is not None else "",
            f"lost {lost}", "0 lost", lost == 0 and not r["kernel_drops"] and not r["queue_overflow"])


def start(args, work: Path) -> None:
    import bench_cli_start as bc

    capture = bc._external("rust-lidar-utils/velodyne_vlp16.pcap")
    print(f"\nCLI start, whole processes (load {load()})")
    for argv in (["--help"], ["--version"], ["info", str(capture)]):
        wall, cpu = bc.time_command(argv, max(3, args.repeat))
        name = "lidarpkt " + (argv[0] if argv[0] != "info" else f"info {capture.name}")
        row(name, f"{wall:.3f} s (cpu {cpu:.3f} s)", "", f"{wall:.3f} s", f"<= {bc.TARGET_S} s", wall <= bc.TARGET_S)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--ouster-frames", type=int, default=300)
    ap.add_argument("--vlp-seconds", type=float, default=60.0)
    ap.add_argument("--memory-gb", type=float, default=1.5, help="memory-large: the size of the generated captures")
    ap.add_argument("--memory-factor", type=int, default=10)
    ap.add_argument("--keep-memory-files", action="store_true")
    ap.add_argument("--record-seconds", type=float, default=2.0)
    ap.add_argument("--workdir", type=Path, help="keep the built captures here (default: a temporary directory)")
    ap.add_argument("--only", default=",".join(TABLE))
    args = ap.parse_args(argv)
    global ARGS
    ARGS = args
    steps = {**TABLE, "pcap": pcap, "memory-large": memory_large, "analysis": analysis, "record": record, "start": start}
    only = [s.strip() for s in args.only.split(",") if s.strip()]
    unknown = set(only) - set(steps)
    if unknown:
        ap.error(f"unknown steps {sorted(unknown)}")
    work = args.workdir or Path(tempfile.mkdtemp(prefix="lidarpkt_bench_"))
    work.mkdir(parents=True, exist_ok=True)
    subprocess.run([sys.executable, "-m", "compileall", "-q", str(REPO / "lidarpkt")], check=True,
                   stdout=subprocess.DEVNULL)
    print(f"machine: {machine()}")
    print(f"lidarpkt kernels: {kernels.describe()}")
    print(f"start: {time.strftime('%Y-%m-%d %H:%M:%S UTC', time.gmtime())}, load average {load()}, repeat {args.repeat} "
          "(medians of whole processes)")
    try:
        for s in only:
            steps[s](args, work)
    finally:
        if args.workdir is None:
            shutil.rmtree(work, ignore_errors=True)
    print(f"\nsummary (load average at the end {load()})")
    print("| comparison | lidarpkt | reference | ratio | target | |\n|---|---|---|---|---|---|")
    for name, ours, ref, ratio_text, target, met in ROWS:
        print(f"| {name} | {ours} | {ref} | {ratio_text} | {target} | {'met' if met else '**not met**'} |")
    return 0


TABLE = {"velodyne": velodyne, "ouster": ouster, "xyz": xyz, "workers": workers, "memory": memory, "mcap": mcap,
         "osf": osf}

if __name__ == "__main__":
    sys.exit(main())
