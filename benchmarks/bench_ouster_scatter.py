"""Ouster frame assembly alone: the compiled scatter against its NumPy twin (issue 16).

The packets of one capture are read once; then each frame is assembled ``--repeat`` times by a
fresh ``OusterDecoder`` with the compiled kernels (``native``) and with the twin (``numpy``:
``kernels.native`` set to ``None`` for the decoder only; the pcap reading is not timed).

    python benchmarks/bench_ouster_scatter.py                  # CPU ms per frame, paired, both paths
    python benchmarks/bench_ouster_scatter.py --callgrind      # instructions per frame, both paths

``--callgrind`` runs this script under ``valgrind --tool=callgrind`` twice per path, with 2 and
12 repeats, and prints the difference / 10: instructions per frame net of imports and reading
(instruction counts hold on a loaded machine, where CPU times do not).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_ouster import CAPTURES as _BY_PROFILE, EXTERNAL  # noqa: E402  (the captures run_all.py uses)

_LABELS = {"single": "OS-2-128 RNG19", "dual": "OS-0-32 RNG19 dual", "legacy": "OS-1-64 legacy", "ldr": "OS-0-128 RNG15"}
CAPTURES = {_LABELS[key]: files for key, files in _BY_PROFILE.items()}


def lidar_batch(pcap: str, meta: str):
    from lidarpkt.vendors.ouster import classify, load_metadata
    from lidarpkt.core.packet import PacketBatch
    from lidarpkt.containers.pcap_reader import read_batches

    md = load_metadata(EXTERNAL / meta)
    batches = [b for b in read_batches(EXTERNAL / pcap) if (m := classify(b, [md])) and m[0] == "lidar"]
    return md, PacketBatch.concatenate(batches)


def assemble(md, batch, repeat: int, native: bool) -> int:
    """Frames assembled from ``batch``, ``repeat`` times over; returns how many."""
    from lidarpkt.core import kernels
    from lidarpkt.vendors.ouster.frames import OusterDecoder

    saved = kernels.native
    kernels.native = saved if native else None
    try:
        frames = 0
        for _ in range(repeat):
            dec = OusterDecoder(md)
            frames += len(dec.push(batch)) + len(dec.finish())
        return frames
    finally:
        kernels.native = saved


def callgrind_ir(name: str, path: str, repeat: int) -> int:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "cg.out"
        cmd = ["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}", sys.executable, __file__, "--one", name,
               "--path", path, "--repeat", str(repeat)]
        # one BLAS thread: OpenBLAS's idle threads spin, and their instructions vary from run to run
        env = dict(os.environ, PYTHONPATH=str(REPO), OPENBLAS_NUM_THREADS="1")
        subprocess.run(cmd, check=True, capture_output=True, env=env)
        return int(re.search(r"^summary: (\d+)", out.read_text(), re.M).group(1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=50, help="frames assembled per path and capture (default 50)")
    ap.add_argument("--callgrind", action="store_true", help="instructions per frame under valgrind")
    ap.add_argument("--one", help=argparse.SUPPRESS)
    ap.add_argument("--path", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:  # the child run under callgrind
        md, batch = lidar_batch(*CAPTURES[args.one])
        assemble(md, batch, args.repeat, args.path == "native")
        return
    for name, files in CAPTURES.items():
        if not (EXTERNAL / files[0]).exists():
            print(f"{name}: {files[0]} not found under {EXTERNAL}; skipped")
            continue
        if args.callgrind:
            per = {p: (callgrind_ir(name, p, 12) - callgrind_ir(name, p, 2)) / 10 for p in ("numpy", "native")}
            print(f"{name}: instructions per frame  numpy {per['numpy'] / 1e6:.2f} M  native {per['native'] / 1e6:.2f} M"
                  f"  ({per['native'] / per['numpy']:.2f}x)")
            continue
        md, batch = lidar_batch(*files)
        cpu = {"numpy": [], "native": []}
        for _ in range(max(1, args.repeat // 5)):  # paired rounds, alternating
            for p in cpu:
                t = time.process_time()
                frames = assemble(md, batch, 5, p == "native")
                cpu[p].append((time.process_time() - t) / frames * 1e3)
        med = {p: sorted(v)[len(v) // 2] for p, v in cpu.items()}
        print(f"{name}: CPU ms per frame (median of {len(cpu['numpy'])} paired rounds)  numpy {med['numpy']:.3f}"
              f"  native {med['native']:.3f}  ({med['native'] / med['numpy']:.2f}x)")


if __name__ == "__main__":
    main()
