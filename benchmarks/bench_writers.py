"""Export speed: the frames of a capture written in every format of ``lidarpkt.writers``.

Decodes the frames once (VLP-16 dual from ``bench_velodyne.build``, ``--seconds`` of sensor time, and
the canned OS1-64 dual-return frames repeated ``--ouster-frames`` times), then times each writer alone
(XYZ included, since every point format computes it) and prints seconds, frames/s, points/s and the
output size. Run it briefly to check it works; the figures depend on the machine's load.

    python benchmarks/bench_writers.py [--seconds 5] [--ouster-frames 20] [--formats parquet,las,...]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

import lidarpkt  # noqa: E402
from lidarpkt.writers import FORMATS, open_writer  # noqa: E402

CANNED = REPO / "lidarpkt" / "fixtures" / "canned"


def _size(paths: list[Path]) -> int:
    """Bytes of the files written: a folder (a rosbag2 bag, a dataset) counts every file under it."""
    return sum(sum(f.stat().st_size for f in p.rglob("*") if f.is_file()) if p.is_dir() else p.stat().st_size
               for p in paths)


def bench(frames: list, fmt: str, folder: Path, **options) -> dict:
    out = folder / (f"{fmt}-{options.get('layout', '')}" if FORMATS[fmt].directory else f"out.{fmt}")
    t0 = time.perf_counter()
    with open_writer(fmt, out, capture="bench.pcap", **options) as w:
        for f in frames:
            w.write(f)
    paths = w.close()
    seconds = time.perf_counter() - t0
    points = sum(f.n_returns for f in frames)
    return {"format": fmt + (f"/{options['layout']}" if "layout" in options else ""), "seconds": seconds,
            "frames_per_s": len(frames) / seconds, "returns_per_s": points / seconds, "mb": _size(paths) / 1e6}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=5.0, help="VLP-16 capture length (sensor seconds)")
    ap.add_argument("--ouster-frames", type=int, default=20, help="OS1-64 dual frames (the canned ones repeated)")
    ap.add_argument("--formats", default=",".join(FORMATS), help="comma-separated formats")
    args = ap.parse_args(argv)
    import bench_velodyne

    with tempfile.TemporaryDirectory(prefix="bench-writers-") as tmp:
        tmp = Path(tmp)
        pcap = tmp / "vlp16.pcap"
        bench_velodyne.build(pcap, args.seconds, mode="dual")
        vlp = list(lidarpkt.open(pcap))
        os1 = list(lidarpkt.open(CANNED / "os1-64-dual.pcap", metadata=CANNED / "os1-64-dual.json"))
        os1 = (os1 * (args.ouster_frames // len(os1) + 1))[:args.ouster_frames]
        for name, frames in (("VLP-16 dual", vlp), ("OS1-64 dual", os1)):
            print(f"{name}: {len(frames)} frames, {sum(f.n_returns for f in frames)} returns")
            for fmt in args.formats.split(","):
                runs = [{}] if fmt != "parquet" else [{"layout": "points"}, {"layout": "frames"}]
                for options in runs:
                    folder = tmp / f"{name[:3]}-{fmt}-{options.get('layout', '')}"
                    folder.mkdir()
                    r = bench(frames, fmt, folder, **options)
                    print(f"  {r['format']:16s} {r['seconds']:7.2f} s  {r['frames_per_s']:7.1f} frames/s  "
                          f"{r['returns_per_s'] / 1e6:6.2f} M returns/s  {r['mb']:8.1f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
