"""Shared plumbing of the archive tests: a small archive folder of real captures (each Ouster one
with its metadata JSON beside it, as an archive keeps them), the CLI as a subprocess, and the
comparison of two export folders."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

from conftest import REPO_ROOT, external

CANNED = REPO_ROOT / "lidarpkt" / "fixtures" / "canned"

# (external capture, its metadata or None): copied into the archive under these names
ARCHIVE_EXTERNAL = [
    ("rust-lidar-utils/velodyne_example.pcap", None),
    ("rust-lidar-utils/ouster_example.pcap", "rust-lidar-utils/ouster_example.json"),
    ("ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.pcap", "ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.json"),
    ("ouster-sdk/crc_test.pcap", "ouster-sdk/crc_test.json"),
]
ARCHIVE_CANNED = ["vlp16-dual.pcap", "vlp16-strongest.pcap", "os1-64-dual.pcap", "os1-64-dual.json"]


def build_archive(root: Path, *, nested: bool = True) -> Path:
    """A folder of captures: canned fixtures at the top, external captures in a sub-folder."""
    root.mkdir(parents=True, exist_ok=True)
    for name in ARCHIVE_CANNED:
        shutil.copy(CANNED / name, root / name)
    sub = root / "drive2" if nested else root
    sub.mkdir(exist_ok=True)
    for cap, md in ARCHIVE_EXTERNAL:
        src = external(cap)
        shutil.copy(src, sub / src.name)
        if md:
            shutil.copy(external(md), (sub / src.name).with_suffix(".json"))
    return root


def lidarpkt_cli(*args: str, timeout: float = 240, env: dict | None = None) -> subprocess.CompletedProcess:
    """``python -m lidarpkt ARGS`` (this checkout, through PYTHONPATH)."""
    return subprocess.run([sys.executable, "-m", "lidarpkt", *args], capture_output=True, text=True,
                          timeout=timeout, env=env)


def manifest_rows(outdir: Path) -> list[dict]:
    lines = (outdir / "_manifest.jsonl").read_text().splitlines()
    return [json.loads(line) for line in lines if line.strip()]


def output_files(outdir: Path) -> dict[str, Path]:
    """Every output file under OUTDIR by relative path (the manifest and lock excluded)."""
    out = {}
    for path in sorted(outdir.rglob("*")):
        rel = path.relative_to(outdir).as_posix()
        if path.is_file() and not rel.startswith("_"):
            out[rel] = path
    return out


def assert_same_outputs(a: Path, b: Path) -> None:
    """Two export folders hold the same files with the same content: byte for byte, except NPZ
    (zip members carry their write time), compared array for array."""
    fa, fb = output_files(a), output_files(b)
    assert sorted(fa) == sorted(fb)
    for rel in fa:
        if rel.endswith(".npz"):
            with np.load(fa[rel]) as x, np.load(fb[rel]) as y:
                assert sorted(x.files) == sorted(y.files), rel
                for k in x.files:
                    np.testing.assert_array_equal(x[k], y[k], err_msg=f"{rel}:{k}")
        else:
            assert fa[rel].read_bytes() == fb[rel].read_bytes(), rel


def no_partial_files(outdir: Path) -> list[str]:
    """Names under OUTDIR that are temporaries or staging leftovers (should be none)."""
    return [p.relative_to(outdir).as_posix() for p in outdir.rglob("*")
            if p.name.endswith(".tmp") or ".staging" in p.parts]


def cli_env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO_ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env
