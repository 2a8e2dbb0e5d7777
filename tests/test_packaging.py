"""What the installed package is: one import name, its version, its public names, nothing put into the
import system, and no syntax newer than the Python it says it needs."""

from __future__ import annotations

import importlib.metadata
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import lidarpkt

REPO_ROOT = Path(__file__).resolve().parents[1]


def test_the_installed_distribution_holds_one_top_level_package_with_py_typed():
    # the installed wheel's record (a checkout's lidarpkt.egg-info on sys.path lists the sdist instead)
    installed = [d for d in importlib.metadata.distributions(name="lidarpkt") if d.read_text("RECORD")]
    assert installed, "lidarpkt is not installed (pip install .)"
    files = [str(f) for f in installed[0].files or ()]
    tops = {f.split("/")[0] for f in files if not f.startswith("..")}  # ../../bin/lidarpkt: the script
    tops = {t for t in tops if not t.endswith(".dist-info")}
    assert tops == {"lidarpkt"}, tops
    assert "lidarpkt/py.typed" in files
    assert any(re.fullmatch(r"lidarpkt/fixtures/canned/vlp16-dual\.pcap", f) for f in files)  # package data
    if os.environ.get("CI") or shutil.which("cc"):
        assert any(re.fullmatch(r"lidarpkt/_native\..*\.so", f) for f in files), "the C extension was not built"


def test_version_is_the_distributions():
    installed = [d for d in importlib.metadata.distributions(name="lidarpkt") if d.read_text("RECORD")]
    assert installed and lidarpkt.__version__ == installed[0].version


def test_public_names_are_listed_and_resolve():
    names = dir(lidarpkt)
    for name in lidarpkt.__all__:
        assert name in names
        assert getattr(lidarpkt, name) is not None
    assert "open" in names and lidarpkt.open.__name__ == "open_frames"
    with pytest.raises(AttributeError):
        lidarpkt.no_such_name  # noqa: B018


def test_importing_lidarpkt_changes_no_import_machinery():
    code = ("import sys\nbefore = list(sys.meta_path), list(sys.path_hooks)\nimport lidarpkt, lidarpkt.pipeline.reader\n"
            "print(before == (list(sys.meta_path), list(sys.path_hooks)))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO_ROOT, timeout=60)
    assert r.returncode == 0 and r.stdout.strip() == "True", r.stderr


def test_the_old_module_paths_are_gone():
    for path in ("lidarpkt/pcap.py", "lidarpkt/bags.py", "lidarpkt/reassembly.py", "lidarpkt/_moved.py",
                 "recorder", "analysis", "fixtures"):
        assert not (REPO_ROOT / path).exists(), path


def test_no_syntax_or_library_newer_than_requires_python():
    vermin = shutil.which("vermin") or str(Path(sys.executable).with_name("vermin"))
    if not Path(vermin).exists():
        if os.environ.get("CI"):
            pytest.fail("vermin is missing: pip install '.[test]'")
        pytest.skip("vermin is not installed (pip install '.[test]')")
    text = (REPO_ROOT / "pyproject.toml").read_text()
    wanted = re.search(r'requires-python = ">=(3\.\d+)"', text).group(1)
    r = subprocess.run([vermin, "--no-tips", "--violations", "--eval-annotations", f"-t={wanted}-",
                        str(REPO_ROOT / "lidarpkt")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr


# The floors: the core (sources, vendor packages, frames, open) and the writers import no application.
CORE = ("core", "containers", "vendors", "pipeline", "writers", "errors.py")
APPLICATIONS = ("recorder", "analysis", "view", "archive", "cli", "fixtures")


def _imports(path: Path) -> set[str]:
    import ast

    tree = ast.parse(path.read_text())
    package = ".".join(path.relative_to(REPO_ROOT).with_suffix("").parts[:-1])
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1] + ([base] if base else []))
            out |= {base} | {f"{base}.{a.name}" for a in node.names}
    return out


def test_no_core_module_imports_an_application():
    offenders = []
    for name in CORE:
        target = REPO_ROOT / "lidarpkt" / name
        for path in ([target] if target.suffix == ".py" else sorted(target.rglob("*.py"))):
            if not path.exists():
                continue
            bad = sorted(m for m in _imports(path)
                         if m.split(".")[:2] in (["lidarpkt", a] for a in APPLICATIONS))
            if bad:
                offenders.append(f"{path.relative_to(REPO_ROOT)}: {', '.join(bad)}")
    assert not offenders, "\n".join(offenders)


def test_no_vendor_package_imports_another_vendor():
    vendors = ("velodyne", "ouster", "hesai")
    offenders = []
    for vendor in vendors:
        for path in sorted((REPO_ROOT / "lidarpkt" / "vendors" / vendor).rglob("*.py")):
            bad = sorted(m for m in _imports(path)
                         if m.split(".")[:3] in (["lidarpkt", "vendors", v] for v in vendors if v != vendor))
            if bad:
                offenders.append(f"{path.relative_to(REPO_ROOT)}: {', '.join(bad)}")
    assert not offenders, "\n".join(offenders)
