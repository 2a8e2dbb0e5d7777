"""Mutated copies of the real captures of every reader (issue 27): byte flips, truncations, damaged
length fields and zeroed runs, seeded. Each copy, through each opener (``lidarpkt.open`` and
``lidarpkt info``), may only end normally or raise a ``LidarpktError`` (``info``: exit status 0 or 2
and no traceback), within 10 s of CPU time, in bounded memory.

The copies are read in one child process per capture, so that a hang is stopped (the child's
timeout) and memory is measured apart from the test run (the child's peak resident size, copy
after copy); each copy runs under a 10 s CPU-time alarm (``ITIMER_PROF``: CPU time, so a loaded
machine does not make it fail). :data:`CASES` lists the inputs: add a row for each new reader's
captures (the total of copies stays about 240, the module about a minute).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from conftest import external, external_root

REPO = Path(__file__).resolve().parents[2]
CPU_BUDGET_S = 10.0
PEAK_RSS_BYTES = 1 << 30  # the child's resident peak, imports included (about 250 MB clean)
OPENERS = ("open", "info")


@dataclass(frozen=True)
class Case:
    name: str
    capture: str  # under the external fixtures: a file, or a rosbag2 folder
    copies: int
    metadata: str | None = None  # an Ouster metadata JSON the openers are given


CASES = [
    Case("hdl32e-pcap", "rust-lidar-utils/velodyne_vlp32.pcap", 30),  # refused today (no VLP-16 stream)
    Case("vlp32c-bag", "nebula/vlp32/1713492677464078412", 10),
    Case("vls128-bag", "nebula/vls128/1614315746471294674", 10),
    Case("pandar-xt32-bag", "nebula/hesai/xt32/1673400677802009732", 10),
    Case("pandar-qt128-bag", "nebula/hesai/qt128/1730273789074637152", 10),
    Case("ouster-fw3-shot-limiting", "ouster-sdk/shot_limiting_test.pcap", 30, "ouster-sdk/shot_limiting_test.json"),
    Case("ouster-imu-zone", "ouster-sdk/imu_zm_no_lidar.pcap", 30, "ouster-sdk/imu_zm_no_lidar_0.json"),
    Case("ouster-ros1-bag", "ouster-sdk/512x10_raw.bag", 30),
    Case("osf-v3", "ouster-sdk/OS-0-128_v3.0.1_1024x10_20241017_141645.osf", 25),
    Case("osf-fw3.2", "ouster-sdk/osf_fw_3.2_10scans.osf", 25),
    Case("osf-zone", "ouster-sdk/single_frame_zm.osf", 30),
]
assert sum(c.copies for c in CASES) == 240


# ---------------------------------------------------------------------------------------- mutations
_LENGTHS = (0, 1, 7, 0xFF, 0xFFFF, 0x7FFFFFFF, 0x80000000, 0xFFFFFFFF)


def _pcap_length_fields(data: bytes) -> list[int]:
    """Offsets of the captured/original length fields of a classic pcap's record headers."""
    if data[:4] not in (b"\xd4\xc3\xb2\xa1", b"\x4d\x3c\xb2\xa1"):
        return []
    out, off = [], 24
    while off + 16 <= len(data):
        out += [off + 8, off + 12]
        off += 16 + int.from_bytes(data[off + 8:off + 12], "little")
    return out


def _length_like_fields(data: bytes, rng: np.random.Generator) -> list[int]:
    """Offsets of little-endian uint32 that could be lengths or offsets (8 ≤ value ≤ file size),
    sampled: the record, chunk and block lengths of the containers are among them."""
    n = len(data) - len(data) % 4
    if n < 8:
        return []
    starts = rng.integers(0, 4, 1)[0]
    words = np.frombuffer(data[starts:starts + (n - starts) // 4 * 4], "<u4")
    hits = np.flatnonzero((words >= 8) & (words <= len(data)))
    return (hits * 4 + starts).tolist()


def mutate(data: bytes, kind: str, rng: np.random.Generator) -> bytes:
    """One seeded mutation of ``data``: ``flip`` (1-16 random bytes changed), ``truncate`` (cut at a
    random offset), ``length`` (1-3 length fields set to absurd or small values; a pcap's record
    lengths, else uint32 that look like lengths), ``zero`` (a run of 16-4096 bytes zeroed)."""
    b = bytearray(data)
    n = len(b)
    if n == 0:
        return bytes(b)
    if kind == "flip":
        for at in rng.integers(0, n, int(rng.integers(1, 17))):
            b[at] ^= int(rng.integers(1, 256))
    elif kind == "truncate":
        del b[int(rng.integers(0, n)):]
    elif kind == "length":
        fields = _pcap_length_fields(data) or _length_like_fields(data, rng)
        if not fields:
            return mutate(data, "flip", rng)
        for at in rng.choice(fields, size=min(len(fields), int(rng.integers(1, 4))), replace=False):
            old = int.from_bytes(b[at:at + 4], "little")
            value = int(rng.choice([*_LENGTHS, old + int(rng.integers(1, 64)), max(old - int(rng.integers(1, 64)), 0),
                                    (old * 16) & 0xFFFFFFFF]))
            b[at:at + 4] = value.to_bytes(4, "little")
    elif kind == "zero":
        at = int(rng.integers(0, n))
        k = min(int(rng.integers(16, 4097)), n - at)
        b[at:at + k] = bytes(k)
    else:
        raise ValueError(kind)
    return bytes(b)


KINDS = ("flip", "truncate", "length", "zero")


def make_copy(src: Path, dst: Path, case: str, i: int) -> str:
    """The ``i``-th mutated copy of ``src`` (a file, or a bag folder: its largest file is mutated, its
    metadata.yaml one time in five) at ``dst``; returns what was done (for failure messages)."""
    rng = np.random.default_rng([sum(case.encode()), len(case), i])
    kind = KINDS[i % len(KINDS)]
    if src.is_dir():
        shutil.copytree(src, dst)
        files = sorted((p for p in dst.iterdir() if p.is_file()), key=lambda p: p.stat().st_size)
        target = files[0] if (i % 5 == 4 and files[0].name == "metadata.yaml") else files[-1]
    else:
        target = dst
    data = (src / target.name).read_bytes() if src.is_dir() else src.read_bytes()
    target.write_bytes(mutate(data, kind, rng))
    return f"copy {i}: {kind} of {target.name}"


# ------------------------------------------------------------------------------------- the child
def _child(argv: list[str]) -> None:
    """Read every copy of one case through both openers; one JSON line per (copy, opener)."""
    import contextlib
    import io
    import resource
    import signal
    import time
    import warnings

    import lidarpkt
    from lidarpkt.cli import main
    from lidarpkt.errors import LidarpktError

    class OverBudget(BaseException):
        pass

    def alarm(*_):
        raise OverBudget

    signal.signal(signal.SIGPROF, alarm)
    case_name, workdir = argv
    case = next(c for c in CASES if c.name == case_name)
    root = Path(os.environ["LIDARPKT_EXTERNAL_FIXTURES"])
    src = root / case.capture
    kw = {"metadata": str(root / case.metadata)} if case.metadata else {}
    for i in range(case.copies):
        dst = Path(workdir) / f"copy{i}{src.suffix}"
        what = make_copy(src, dst, case.name, i)
        for opener in OPENERS:
            print(json.dumps({"copy": i, "opener": opener, "what": what, "started": True}), flush=True)
            out = {"copy": i, "opener": opener, "what": what, "error": None, "raised": None}
            cpu, wall = time.process_time(), time.monotonic()
            signal.setitimer(signal.ITIMER_PROF, CPU_BUDGET_S)
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    if opener == "open":
                        with lidarpkt.open(dst, **kw) as reader:
                            for _ in reader:
                                pass
                    else:
                        args = ["info", str(dst)] + (["--metadata", kw["metadata"]] if kw else [])
                        with contextlib.redirect_stdout(io.StringIO()), \
                                contextlib.redirect_stderr(io.StringIO()) as err:
                            rc = main(args)
                        if rc not in (0, 2) or "Traceback" in err.getvalue():
                            out["error"] = f"exit status {rc}: {err.getvalue()[-1500:]}"
            except LidarpktError as exc:
                out["raised"] = type(exc).__name__
            except OverBudget:
                out["error"] = f"over {CPU_BUDGET_S} s of CPU time"
            except BaseException as exc:  # noqa: BLE001 — what the test is looking for
                import traceback

                out["error"] = "".join(traceback.format_exception(exc))[-3000:]
            finally:
                signal.setitimer(signal.ITIMER_PROF, 0)
            out["cpu_s"] = round(time.process_time() - cpu, 3)
            out["wall_s"] = round(time.monotonic() - wall, 3)
            out["max_rss"] = _peak_rss_bytes()
            print(json.dumps(out), flush=True)
        if dst.is_dir():
            shutil.rmtree(dst)
        else:
            dst.unlink()


def _peak_rss_bytes() -> int:
    """This process's resident peak since it was started. Linux keeps ``ru_maxrss`` across fork and exec, so
    a child of a large test process would report the parent's peak: ``VmHWM`` belongs to this address space."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


# ------------------------------------------------------------------------------------- the tests
_RESULTS: dict[str, list[dict] | str] = {}


def _run_case(case: Case, tmp_path_factory) -> list[dict] | str:
    """The child's lines for a case (run once per case), or the reason it did not finish."""
    if case.name in _RESULTS:
        return _RESULTS[case.name]
    work = tmp_path_factory.mktemp(case.name)
    code = ("import sys; sys.path[:0] = ['tests', 'tests/containers']; import test_mutated_captures as m; "
            "m._child(sys.argv[1:])")
    env = dict(os.environ, LIDARPKT_EXTERNAL_FIXTURES=str(external_root()), PYTHONPATH=str(REPO))
    try:
        res = subprocess.run([sys.executable, "-c", code, case.name, str(work)], capture_output=True, text=True,
                             cwd=REPO, env=env, timeout=60 + 2 * case.copies * CPU_BUDGET_S)
        lines = [json.loads(line) for line in res.stdout.splitlines() if line.startswith("{")]
        if res.returncode != 0:
            result: list[dict] | str = f"the child exited {res.returncode}: {res.stderr[-3000:]}"
        else:
            result = [x for x in lines if not x.get("started")]
    except subprocess.TimeoutExpired as exc:
        text = exc.stdout.decode() if isinstance(exc.stdout, bytes) else (exc.stdout or "")
        started = [json.loads(line) for line in text.splitlines() if line.startswith("{")]
        result = f"the child hung: last started {started[-1] if started else 'nothing'}"
    _RESULTS[case.name] = result
    return result


@pytest.mark.parametrize("opener", OPENERS)
@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_mutated_copies_raise_only_lidarpkt_errors_quickly_in_bounded_memory(case, opener, tmp_path_factory):
    external(case.capture)
    if case.metadata:
        external(case.metadata)
    result = _run_case(case, tmp_path_factory)
    assert not isinstance(result, str), result
    mine = [r for r in result if r["opener"] == opener]
    assert len(mine) == case.copies
    bad = [f"{r['what']}: {r['error']}" for r in mine if r["error"]]
    assert not bad, "\n\n".join(bad[:3])
    slow = [f"{r['what']}: {r['cpu_s']} s CPU" for r in mine if r["cpu_s"] > CPU_BUDGET_S]
    assert not slow, slow
    heavy = [f"{r['what']}: peak {r['max_rss'] / 2**20:.0f} MiB" for r in mine if r["max_rss"] > PEAK_RSS_BYTES]
    assert not heavy, heavy[:3]


def test_the_mutations_are_seeded_and_each_changes_the_input(tmp_path):
    """The same copy twice is the same bytes; every kind changes something (and the length kind finds
    a pcap's record lengths)."""
    src = external("ouster-sdk/shot_limiting_test.pcap")
    data = src.read_bytes()
    assert len(_pcap_length_fields(data)) >= 2
    for i in range(len(KINDS)):
        a, b = tmp_path / f"a{i}.pcap", tmp_path / f"b{i}.pcap"
        make_copy(src, a, "t", i)
        make_copy(src, b, "t", i)
        assert a.read_bytes() == b.read_bytes() != data
