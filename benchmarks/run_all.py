"""Every throughput/memory comparison of issues 8 and 16 in one run, with the ratio table.

    python benchmarks/run_all.py [--repeat 3] [--ouster-frames 300] [--vlp-seconds 60]
                                 [--workdir DIR] [--memory-gb 1.5] [--memory-factor 10]
                                 [--only ouster,velodyne,workers,pcap,memory,analysis,record,start]

Each comparison runs lidarpkt and the reference tool alternately ``--repeat`` times in this
process (captures built once, so the page cache is warm) and reports the median wall time and
the median CPU time (``time.process_time``: less sensitive to the other processes on a shared
machine). Ratios are reference time / lidarpkt time (> 1 = lidarpkt faster), except for the
pcap reader (lidarpkt time / ``cat`` time) and XYZ (decode+XYZ time / decode time). After the
median ratio come the CPU-time ratio and the ratio of each paired run; a target is "met" only when
every run meets it (issue 16).

- Ouster: ``bench_ouster.build_capture`` (one real frame repeated, re-encoded with new frame
  ids and times) for the OS-2-128 single (RNG19), OS-0-32 dual, OS-1-64 legacy and OS-0-128
  low-data-rate (RNG15) captures;
  ``lidarpkt.open`` → frames (every field) vs ouster-sdk ``PcapFrameSetSource``; and the same
  with ``frame.xyz(numpy.float32)`` of every frame (ouster-sdk's ``XYZLutFloat`` values; the
  issue's ≤ 1.3 target) and ``frame.xyz()`` (float64, "(info)"); then frames and float32 XYZ again
  with ``read_ahead=False`` (no reader thread; "(info)"). CPU time counts every thread of the process.
- VLP-16: 60 s strongest and dual captures (``bench_velodyne.build``);
  ``lidarpkt.open`` + ``xyz()`` of every frame vs velodyne_decoder ``read_pcap``; the same for VLP-32C
  and VLS-128 strongest captures (``bench_velodyne.build_model``), the ratio per model.
- workers: ``lidarpkt.open(path, workers=2)`` (the pipeline: a decode thread beside the read-ahead)
  vs ``workers=1`` in one thread (``read_ahead=False``: one core; the ≥ 1.7 target), and for
  information vs the default ``workers=1`` (which reads ahead on a second core) and vs the
  single-threaded reference of the same run; VLP-16 frames + XYZ, Ouster frames and frames + float32 XYZ.
- pcap: ``PcapReader.batches()`` vs ``cat FILE > /dev/null`` on the largest captures.
- memory: peak RSS (VmHWM) of a child process decoding an Ouster capture of ``--memory-gb``, one
  ``--memory-factor`` times longer, and a VLP-16 dual capture of ``--memory-gb``, with workers=1, 2 and 3 (generated under
  ``--workdir`` and deleted afterwards; needs that much free disk).
- analysis: ``image_statistics`` of a 64 × 1024 × 30 stack (``bench_analysis.synthetic_stack``).
- record: ``bench_record.run_one`` at 10× real time (VLP-16, OS1-64), loss counters and the
  recorder's CPU use.
- start: ``lidarpkt --help``, ``--version`` and ``info`` on a 100-packet capture as whole processes
  (``bench_cli_start.time_command``), each at most 0.3 s wall (issue 16); the CPU time beside it.

The work directory keeps the built captures between runs (``--workdir``); by default a
temporary directory is used and removed.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(REPO))

from lidarpkt.core import kernels  # noqa: E402

ROWS: list[tuple] = []  # (name, ours, reference, ratio, target, met)


def machine() -> str:
    cpu = next((l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name")), platform.processor())
    mem_kb = next(int(l.split()[1]) for l in open("/proc/meminfo") if l.startswith("MemTotal"))
    return f"{os.cpu_count()} CPUs ({cpu}), {mem_kb / 1e6:.0f} GB RAM, Python {platform.python_version()}, NumPy {np.__version__}"


def load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def timed(fn, *args):
    w, c = time.perf_counter(), time.process_time()
    out = fn(*args)
    return time.perf_counter() - w, time.process_time() - c, out


def alternate(repeat: int, *fns):
    """Run each function once untimed, then the functions one after the other ``repeat`` times; per
    function (median wall, median CPU, last result, the wall time of every run)."""
    runs = [[] for _ in fns]
    for fn in fns:  # one untimed round: the first call pays imports, page faults and caches for both sides
        fn()
    for _ in range(repeat):
        for i, fn in enumerate(fns):
            runs[i].append(timed(fn))
    return [(statistics.median(r[0] for r in rs), statistics.median(r[1] for r in rs), rs[-1][2], [r[0] for r in rs])
            for rs in runs]


def ratio_row(pair, target):
    """(ratio text, target, met): ``row``'s last three arguments from a ``paired`` result."""
    return pair[0], target, pair[1]


def paired(num, den, at_least: float | None = None, at_most: float | None = None):
    """Ratio ``num / den`` of two ``alternate`` results: text (median wall ratio, CPU ratio, the ratio of each
    paired run) and whether every run meets the target (issue 16: "in every one of three runs")."""
    each = [a / b for a, b in zip(num[3], den[3])]
    text = f"{num[0] / den[0]:.2f} (cpu {num[1] / den[1]:.2f}; runs {'/'.join(f'{r:.2f}' for r in each)})"
    met = all((at_least is None or r >= at_least) and (at_most is None or r <= at_most) for r in each)
    return text, met


def row(name, ours, ref, ratio, target, met):
    ROWS.append((name, ours, ref, ratio, target, met))
    print(f"  {name:<44} {ours:>22} {ref:>22} {ratio:>14}  {target:<10} {'met' if met else 'NOT met'}", flush=True)


def fmt(wall, cpu):
    return f"{wall:.3f}s (cpu {cpu:.3f})"


# ------------------------------------------------------------------------------------ Ouster
OUSTER_CAPTURES = (("single", "OS-2-128 single"), ("dual", "OS-0-32 dual"), ("legacy", "OS-1-64 legacy"),
                   ("ldr", "OS-0-128 RNG15"))


def ouster_capture(args, work: Path, name: str):
    import bench_ouster as bo

    pcap, meta = (bo.EXTERNAL / p for p in bo.CAPTURES[name])
    if not pcap.exists():
        return None, meta
    path = work / f"ouster_{name}_{args.ouster_frames}.pcap"
    if not path.exists():
        bo.build_capture(pcap, meta, args.ouster_frames, path)
    return path, meta


def ouster_lidarpkt(path, meta, xyz=None, read_ahead=None, workers=1):
    """Frames of the capture; ``xyz``: None, or the dtype of the points computed for every frame."""
    import lidarpkt

    n = 0
    for f in lidarpkt.open(path, metadata=meta, read_ahead=read_ahead, workers=workers):
        if xyz is not None:
            f.xyz(xyz)
        n += 1
    return n


def ouster_sdk(path, meta):
    from ouster.sdk import pcap as sdk_pcap

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        src = sdk_pcap.PcapFrameSetSource(str(path), meta=[str(meta)])
        return sum(1 for fs in src if fs[0] is not None)


def ouster(args, work: Path) -> None:
    print(f"\nOuster, {args.ouster_frames} frames per capture (load {load()})")
    for name, label in OUSTER_CAPTURES:
        path, meta = ouster_capture(args, work, name)
        if path is None:
            print(f"  {label}: external fixtures missing ({meta.parent})")
            continue
        ours, sdk, xyz32, xyz64, ours_nr, xyz32_nr = alternate(
            args.repeat, lambda: ouster_lidarpkt(path, meta), lambda: ouster_sdk(path, meta),
            lambda: ouster_lidarpkt(path, meta, np.float32), lambda: ouster_lidarpkt(path, meta, np.float64),
            lambda: ouster_lidarpkt(path, meta, read_ahead=False), lambda: ouster_lidarpkt(path, meta, np.float32, False))
        note = "" if ours[2] == sdk[2] else f" (frames differ: {ours[2]} vs {sdk[2]})"
        row(f"{label}: pcap→frames vs ouster-sdk{note}", fmt(*ours[:2]), fmt(*sdk[:2]),
            *ratio_row(paired(sdk, ours, at_least=1.3), "≥ 1.3"))
        # XYZ in float32 (ouster-sdk's XYZLutFloat, bit for bit) and, for information, float64 (its XYZLut)
        row(f"{label}: decode+XYZ float32 / decode", fmt(*xyz32[:2]), fmt(*ours[:2]),
            *ratio_row(paired(xyz32, ours, at_most=1.3), "≤ 1.3"))
        text, met = paired(xyz64, ours, at_most=1.3)
        row(f"{label}: decode+XYZ float64 / decode", fmt(*xyz64[:2]), fmt(*ours[:2]), text, "(info)", met)
        # the same without the read-ahead thread (lidarpkt.open(..., read_ahead=False)): what the thread buys
        text, met = paired(sdk, ours_nr, at_least=1.3)
        row(f"{label}: no read-ahead, pcap→frames vs ouster-sdk", fmt(*ours_nr[:2]), fmt(*sdk[:2]), text, "(info)", met)
        text, met = paired(xyz32_nr, ours_nr, at_most=1.3)
        row(f"{label}: no read-ahead, decode+XYZ float32 / decode", fmt(*xyz32_nr[:2]), fmt(*ours_nr[:2]), text, "(info)", met)


# ------------------------------------------------------------------------------------ VLP-16
def vlp_capture(args, work: Path, mode: str) -> Path:
    import bench_velodyne as bv

    path = work / f"vlp16_{mode}_{int(args.vlp_seconds)}s.pcap"
    if not path.exists():
        bv.build(path, args.vlp_seconds, mode=mode)
    return path


def velodyne(args, work: Path) -> None:
    import bench_velodyne as bv

    print(f"\nVLP-16, {args.vlp_seconds:.0f} s captures, XYZ of every frame (load {load()})")
    for mode in ("strongest", "dual"):
        path = vlp_capture(args, work, mode)
        ours, ref = alternate(args.repeat, lambda: bv.run_lidarpkt(path), lambda: bv.run_velodyne_decoder(path))
        row(f"VLP-16 {mode}: pcap→frames+XYZ vs velodyne_decoder", fmt(*ours[:2]), fmt(*ref[:2]),
            *ratio_row(paired(ref, ours, at_least=4.0), "≥ 4"))
    for model in ("VLP-32C", "VLS-128"):  # the model from the factory byte on both sides
        path = work / f"{model.lower()}_strongest_{int(args.vlp_seconds)}s.pcap"
        if not path.exists():
            bv.build_model(path, model, args.vlp_seconds)
        ours, ref = alternate(args.repeat, lambda: bv.run_lidarpkt(path),
                              lambda: bv.run_velodyne_decoder(path, vlp16=False))
        row(f"{model} strongest: pcap→frames+XYZ vs velodyne_decoder", fmt(*ours[:2]), fmt(*ref[:2]),
            *ratio_row(paired(ref, ours, at_least=4.0), "≥ 4"))


# ------------------------------------------------------------------------------------ both cores
def workers(args, work: Path) -> None:
    """lidarpkt.open(path, workers=2) against workers=1 in one thread (read_ahead=False: one core), and, for
    information, against the default workers=1 (which reads ahead on a second core) and beside the
    single-threaded reference of the same run. VLP-16: frames, XYZ and a count of returns per frame;
    Ouster: frames, and frames with float32 XYZ."""
    import bench_velodyne as bv

    print(f"\nboth cores: lidarpkt.open(workers=2) vs workers=1 (load {load()}; {os.cpu_count()} CPUs)")

    def rows(label, one, default, two, ref, ref_name, ref_target):
        row(f"{label}: workers=2 vs 1 thread", fmt(*two[:2]), fmt(*one[:2]), *ratio_row(paired(one, two, at_least=1.7), "≥ 1.7"))
        text, met = paired(default, two, at_least=1.7)
        row(f"{label}: workers=2 vs default workers=1", fmt(*two[:2]), fmt(*default[:2]), text, "(info)", met)
        text, met = paired(ref, two, at_least=ref_target)
        row(f"{label}: workers=2 vs {ref_name}", fmt(*two[:2]), fmt(*ref[:2]), text, "(info)", met)

    for mode in ("strongest", "dual"):
        path = vlp_capture(args, work, mode)
        one, default, two, ref = alternate(
            args.repeat, lambda: bv.run_lidarpkt(path, read_ahead=False), lambda: bv.run_lidarpkt(path),
            lambda: bv.run_lidarpkt(path, workers=2), lambda: bv.run_velodyne_decoder(path))
        rows(f"VLP-16 {mode} frames+XYZ", one, default, two, ref, "velodyne_decoder", 4.0)
    for name, label in OUSTER_CAPTURES:
        path, meta = ouster_capture(args, work, name)
        if path is None:
            continue
        for xyz, what in ((None, "frames"), (np.float32, "frames+XYZ32")):
            one, default, two, ref = alternate(
                args.repeat, lambda: ouster_lidarpkt(path, meta, xyz, read_ahead=False),
                lambda: ouster_lidarpkt(path, meta, xyz), lambda: ouster_lidarpkt(path, meta, xyz, workers=2),
                lambda: ouster_sdk(path, meta))
            rows(f"{label} {what}", one, default, two, ref, "ouster-sdk (frames)", 1.3)


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
        (lw, lc, *_), (cw, cc, *_) = alternate(args.repeat, lambda: bp.run_batches(path), lambda: bp.run_cat(path))
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


def memory(args, work: Path) -> None:
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
    ((w, c, *_),) = alternate(args.repeat, lambda: image_statistics(stack))
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
    ap.add_argument("--memory-gb", type=float, default=1.5)
    ap.add_argument("--memory-factor", type=int, default=10)
    ap.add_argument("--keep-memory-files", action="store_true")
    ap.add_argument("--record-seconds", type=float, default=2.0)
    ap.add_argument("--workdir", type=Path, help="keep the built captures here (default: a temporary directory)")
    ap.add_argument("--only", default="ouster,velodyne,workers,pcap,memory,analysis,record,start")
    args = ap.parse_args(argv)
    steps = {"ouster": ouster, "velodyne": velodyne, "workers": workers, "pcap": pcap, "memory": memory, "analysis": analysis, "record": record,
             "start": start}
    only = [s.strip() for s in args.only.split(",") if s.strip()]
    unknown = set(only) - set(steps)
    if unknown:
        ap.error(f"unknown steps {sorted(unknown)}")
    work = args.workdir or Path(tempfile.mkdtemp(prefix="lidarpkt_bench_"))
    work.mkdir(parents=True, exist_ok=True)
    print(f"machine: {machine()}")
    print(f"lidarpkt kernels: {kernels.describe()}")
    print(f"start: {time.strftime('%Y-%m-%d %H:%M:%S UTC', time.gmtime())}, load average {load()}, repeat {args.repeat} (medians)")
    try:
        for s in only:
            steps[s](args, work)
    finally:
        if args.workdir is None:
            shutil.rmtree(work, ignore_errors=True)
    print(f"\nsummary (load average at the end {load()})")
    print(f"| comparison | lidarpkt | reference | ratio | target | |\n|---|---|---|---|---|---|")
    for name, ours, ref, ratio, target, met in ROWS:
        print(f"| {name} | {ours} | {ref} | {ratio} | {target} | {'met' if met else '**not met**'} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
