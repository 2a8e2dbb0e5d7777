"""Mutation score of the decode modules with mutmut 3 (a dev tool, not in CI: it takes hours).

mutmut changes one operator, constant or call at a time in the modules named below and reruns
the tests that reach the changed function; a mutant no test notices "survives". The run works
on a copy of the tree (mutmut writes a ``mutants/`` folder beside the sources), so the checkout
is never touched.

mutmut 3 needs a click newer than ouster-sdk allows: install it in its own venv that also sees
the project's packages (the ``.pth`` line puts them after mutmut's own)::

    python -m venv /work/venv-mut && /work/venv-mut/bin/pip install "mutmut>=3"
    echo /work/venv/lib/python3.11/site-packages > /work/venv-mut/lib/python3.11/site-packages/zz.pth
    nice -n 19 python benchmarks/mutation.py --mutmut /work/venv-mut/bin/mutmut \\
        --modules lidarpkt/reassembly.py lidarpkt/vendors/velodyne/geometry.py

It prints, and writes to ``<workdir>/summary.json``, the count of killed, surviving, timed-out and
skipped mutants per module and the names of the survivors (``mutmut show NAME`` in the work
folder prints a survivor's diff).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
from collections import Counter, defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# the decode modules, smallest first (a run that is stopped early has covered the small ones)
DECODE_MODULES = [
    "lidarpkt/vendors/velodyne/geometry.py", "lidarpkt/vendors/velodyne/calibration.py", "lidarpkt/vendors/velodyne/timing.py",
    "lidarpkt/vendors/velodyne/decode.py", "lidarpkt/vendors/velodyne/packet.py", "lidarpkt/vendors/ouster/geometry.py",
    "lidarpkt/vendors/ouster/crc.py", "lidarpkt/vendors/ouster/decode.py", "lidarpkt/containers/reassembly.py",
    "lidarpkt/vendors/ouster/profiles.py", "lidarpkt/vendors/ouster/frames.py", "lidarpkt/vendors/velodyne/frames.py",
]
# the tests that exercise them (the others reach the decoders only through these paths)
DECODE_TESTS = [
    "tests/velodyne/test_velodyne_calibration.py", "tests/velodyne/test_velodyne_calibration_corrections.py",
    "tests/velodyne/test_velodyne_crosscheck.py", "tests/velodyne/test_velodyne_frames.py", "tests/velodyne/test_velodyne_packet.py",
    "tests/velodyne/test_velodyne_properties.py", "tests/velodyne/test_velodyne_nebula.py", "tests/ouster/test_ouster_decode.py",
    "tests/ouster/test_ouster_crosscheck.py", "tests/ouster/test_ouster_frames.py", "tests/ouster/test_ouster_geometry.py",
    "tests/ouster/test_ouster_metadata.py", "tests/ouster/test_ouster_words.py", "tests/ouster/test_ouster_profile_tables.py",
    "tests/containers/test_reassembly.py", "tests/containers/test_reassembly_fast_path.py", "tests/containers/test_pcap_formats.py",
    "tests/test_decode_edges.py", "tests/containers/test_reassembly_edges.py",
    "tests/velodyne/test_velodyne_frames_cuts.py", "tests/ouster/test_ouster_frames_cuts.py",
]

# mutmut's result names: killed (a test failed), survived, timeout, suspicious, no tests, skipped, ...
KILLED = {"killed", "timeout", "segfault"}


def copy_tree(workdir: Path) -> None:
    """The tracked files and the built C extension, into ``workdir`` (named ``lidarpkt`` for mutmut)."""
    if workdir.exists():
        shutil.rmtree(workdir)
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=ROOT, check=True,
                           capture_output=True, text=True).stdout.split()
    files += [str(p.relative_to(ROOT)) for p in list(ROOT.glob("*.so")) + list((ROOT / "lidarpkt").glob("*.so"))]
    for rel in files:
        src = ROOT / rel
        if src.is_file():
            dst = workdir / rel
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dst)


FRESH_CACHES = '''

# added by benchmarks/mutation.py: mutmut forks each mutant's test run from a process that already
# ran the tests, so lru_cache'd tables (CRC, trig, dtypes) would be the unmutated ones: clear them
def pytest_configure(config):
    import sys
    for name, mod in list(sys.modules.items()):
        if name.startswith("lidarpkt") and mod is not None:
            for obj in list(vars(mod).values()):
                if callable(getattr(obj, "cache_clear", None)):
                    obj.cache_clear()
'''


def write_config(workdir: Path, modules: list[str], tests: list[str]) -> None:
    with (workdir / "tests" / "conftest.py").open("a") as f:
        f.write(FRESH_CACHES)
    # pyproject.toml has no [tool.mutmut], so mutmut reads setup.cfg
    lines = ["[mutmut]", "source_paths=lidarpkt/", "only_mutate="]
    lines += [f"    {m}" for m in modules]
    lines += ["pytest_add_cli_args_test_selection="] + [f"    {t}" for t in tests if (workdir / t).exists()]
    # -x: a mutant is killed by its first failing test; running the rest only costs time
    lines += ["pytest_add_cli_args=", "    -p", "    no:cacheprovider", "    -q", "    -x", "also_copy=", "    tests/data/"]
    (workdir / "setup.cfg").write_text("\n".join(lines) + "\n")


def results(mutmut: str, workdir: Path) -> dict:
    """Parses ``mutmut results --all true`` (lines ``    name: status``)."""
    out = subprocess.run([mutmut, "results", "--all", "true"], cwd=workdir, capture_output=True, text=True).stdout
    per_module: dict[str, Counter] = defaultdict(Counter)
    survivors: list[str] = []
    for line in out.splitlines():
        name, sep, status = line.strip().rpartition(": ")
        if not sep or "__mutmut_" not in name:
            continue
        module = name.split(".x")[0].split(".xǁ")[0]
        per_module[module][status] += 1
        if status in ("survived", "no tests"):
            survivors.append(name)
    total = Counter()
    for c in per_module.values():
        total.update(c)
    killed = sum(total[s] for s in KILLED)
    # a mutant no selected test reaches counts as surviving: the score is the share the tests catch
    decided = killed + total["survived"] + total["no tests"]
    return {
        "score": round(killed / decided, 4) if decided else None,
        "totals": dict(total),
        "per_module": {m: dict(c) for m, c in sorted(per_module.items())},
        "survivors": survivors,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mutmut", default=shutil.which("mutmut") or "mutmut", help="mutmut 3 executable")
    ap.add_argument("--modules", nargs="+", default=DECODE_MODULES, help="files to mutate")
    ap.add_argument("--tests", nargs="+", default=DECODE_TESTS, help="test files run against each mutant")
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/lidarpkt-mutation/lidarpkt"))
    ap.add_argument("--max-children", type=int, default=1)
    ap.add_argument("--results-only", action="store_true", help="summarise an earlier run in --workdir")
    ap.add_argument("--only", nargs="+", default=(), metavar="GLOB",
                    help="mutant names to run, e.g. 'lidarpkt.containers.reassembly*' (the rest stay 'not checked')")
    args = ap.parse_args(argv)
    if args.workdir.name != "lidarpkt":
        ap.error("--workdir must end in /lidarpkt (mutmut finds the package by the folder name)")
    if not args.results_only:
        copy_tree(args.workdir)
        write_config(args.workdir, args.modules, args.tests)
        env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "CI")}  # the mutants, not the checkout
        # the NumPy paths are the ones mutmut can change: with the C kernels loaded they would not run
        env["LIDARPKT_NATIVE"] = "0"
        env.setdefault("LIDARPKT_EXTERNAL_FIXTURES", str(ROOT.parent / "shared" / "fixtures" / "external"))
        subprocess.run([args.mutmut, "run", "--max-children", str(args.max_children), *args.only], cwd=args.workdir, env=env)
    summary = results(args.mutmut, args.workdir)
    (args.workdir / "summary.json").write_text(json.dumps(summary, indent=1))
    json.dump({k: summary[k] for k in ("score", "totals", "per_module")}, sys.stdout, indent=1)
    print(f"\n{len(summary['survivors'])} survivors (list in {args.workdir / 'summary.json'})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
