"""Issue 19's defects, re-introduced one at a time on a copy of the tree: each must fail a test.

Each mutant is one textual edit (the line a reviewer changed by hand) and the test files that
should catch it. For each, the tree is copied to a temporary folder, the edit applied, and the
tests run there with ``PYTHONPATH`` pointing at the copy; a mutant whose tests still pass is
reported as SURVIVED and the script exits 1. A control run of the unchanged copy must pass.

    python benchmarks/mutants.py              # all of them (about a minute)
    python benchmarks/mutants.py rot_sign     # one by name

Not part of the default test run (it runs pytest itself, repeatedly).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from mutation import copy_tree  # benchmarks/mutation.py: the tree and the built extension

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Mutant:
    name: str
    path: str
    old: str
    new: str
    tests: tuple[str, ...]
    what: str


VELODYNE_CAL_TESTS = ("tests/velodyne/test_velodyne_calibration_corrections.py",)
MUTANTS = (
    Mutant("rot_sign", "lidarpkt/vendors/velodyne/geometry.py",
           "np.cos(az[None, :] - r), -np.sin(az[None, :] - r)", "np.cos(az[None, :] + r), -np.sin(az[None, :] + r)",
           VELODYNE_CAL_TESTS, "sign of the VLP-16 azimuth rot_correction"),
    Mutant("dist_sign", "lidarpkt/vendors/velodyne/geometry.py",
           "            dxy += hit * dc_xy\n            dz += hit * dc_z",
           "            dxy -= hit * dc_xy\n            dz -= hit * dc_z",
           VELODYNE_CAL_TESTS, "sign of the VLP-16 dist_correction"),
    Mutant("horiz_sign", "lidarpkt/vendors/velodyne/geometry.py",
           "out[..., 0] -= h * neg_sin_a", "out[..., 0] += h * neg_sin_a",
           VELODYNE_CAL_TESTS, "sign of the VLP-16 horiz_offset_correction (x)"),
    Mutant("range2_shift", "lidarpkt/vendors/ouster/profiles.py",
           'BitField("RANGE2", 32, 15, 3)', 'BitField("RANGE2", 32, 15, 2)',
           ("tests/ouster/test_ouster_words.py",), "up-shift of RANGE2 in FUSA_RNG15_RFL8_NIR8_DUAL"),
    Mutant("plot_reflectivity_reversed", "lidarpkt/analysis/plots.py",
           'ax2.plot(t.range_m, ra.reflectivity, "o"', 'ax2.plot(t.range_m, ra.reflectivity[::-1], "o"',
           ("tests/analysis/test_analysis_plot_data.py",), "reflectivity points of the temporal-CDF figure reversed"),
    Mutant("fragment_offset_units", "lidarpkt/containers/trains.py",
           '"off": (fb & 0x1FFF) * 8,', '"off": (fb & 0x1FFF),',
           ("tests/containers/test_reassembly_fast_path.py",), "fast fragment path reads offsets without the × 8"),
)


def run_tests(tree: Path, tests: tuple[str, ...]) -> tuple[int, str]:
    env = dict(os.environ, PYTHONPATH=str(tree))
    env.setdefault("LIDARPKT_EXTERNAL_FIXTURES", str(ROOT.parent / "shared" / "fixtures" / "external"))
    env.pop("CI", None)  # a skip must not pass for a kill: run them as a developer would
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider", *tests],
                          cwd=tree, env=env, capture_output=True, text=True, timeout=900)
    last = (proc.stdout.strip().splitlines() or [""])[-1]
    return proc.returncode, last


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("names", nargs="*", help="mutants to run (default: all)")
    args = ap.parse_args(argv)
    chosen = [m for m in MUTANTS if not args.names or m.name in args.names]
    if not chosen:
        ap.error(f"no such mutant; known: {', '.join(m.name for m in MUTANTS)}")
    survived = []
    with tempfile.TemporaryDirectory(prefix="lidarpkt-mutants-") as tmp:
        tree = Path(tmp) / "tree"
        copy_tree(tree)
        all_tests = tuple(sorted({t for m in chosen for t in m.tests}))
        code, last = run_tests(tree, all_tests)
        print(f"control (no mutant): exit {code}: {last}")
        if code != 0:
            print("the unchanged tree fails its tests: fix that first")
            return 2
        for m in chosen:
            target = tree / m.path
            original = target.read_text()
            if original.count(m.old) != 1:
                print(f"{m.name}: the line to change is not in {m.path} once (found {original.count(m.old)}); update MUTANTS")
                survived.append(m.name)
                continue
            target.write_text(original.replace(m.old, m.new))
            try:
                code, last = run_tests(tree, m.tests)
            finally:
                target.write_text(original)
            verdict = "killed" if code == 1 else ("SURVIVED" if code == 0 else f"error (exit {code})")
            print(f"{m.name:28s} {verdict:9s} {m.what} — {last}")
            if code != 1:
                survived.append(m.name)
    if survived:
        print(f"not killed: {', '.join(survived)}")
        return 1
    print(f"all {len(chosen)} defects fail a test")
    return 0


if __name__ == "__main__":
    sys.exit(main())
