"""What the installed package is: one import name, its version, its public names, nothing put into the
import system, and no syntax newer than the Python it says it needs. The rules of its inner structure
(layers, cycles, sizes) are in test_layers.py."""

from __future__ import annotations

import ast
import importlib.metadata
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import lidarpkt

REPO_ROOT = Path(__file__).resolve().parents[1]


def _installed() -> importlib.metadata.Distribution:
    # the installed distribution's record (a checkout's lidarpkt.egg-info on sys.path lists the sdist instead)
    installed = [d for d in importlib.metadata.distributions(name="lidarpkt") if d.read_text("RECORD")]
    assert installed, "lidarpkt is not installed (pip install . or pip install -e .)"
    return installed[0]


def _installed_files(dist: importlib.metadata.Distribution) -> tuple[set[str], list[str]]:
    """The top-level import names a distribution installs, and its files under them (``lidarpkt/py.typed``).

    A wheel's record lists its files. An editable install (``pip install -e .``) records an import hook
    instead, whose mapping names each top-level package and the folder it is imported from: its files
    are the ones in that folder, the compiled extension among them when it was built in place."""
    direct_url = json.loads(dist.read_text("direct_url.json") or "{}")
    if not direct_url.get("dir_info", {}).get("editable"):
        files = [str(f) for f in dist.files or ()]
        tops = {f.split("/")[0] for f in files if not f.startswith("..")}  # ../../bin/lidarpkt: the script
        return {t for t in tops if not t.endswith(".dist-info")}, files
    finders = [f for f in dist.files or () if re.fullmatch(r"__editable__.*_finder\.py", str(f))]
    assert finders, f"an editable install without setuptools' import hook: {[str(f) for f in dist.files or ()]}"
    tree = ast.parse(Path(dist.locate_file(finders[0])).read_text())
    mapping = next(ast.literal_eval(node.value) for node in ast.walk(tree)
                   if isinstance(node, ast.AnnAssign) and getattr(node.target, "id", None) == "MAPPING")
    files = [f"{top}/{p.relative_to(folder).as_posix()}" for top, folder in mapping.items()
             for p in Path(folder).rglob("*") if p.is_file() and "__pycache__" not in p.parts]
    assert set((dist.read_text("top_level.txt") or "").split()) == set(mapping), "top_level.txt and the hook differ"
    return set(mapping), files


def test_the_installed_distribution_holds_one_top_level_package_with_py_typed():
    tops, files = _installed_files(_installed())
    assert tops == {"lidarpkt"}, tops
    assert "lidarpkt/py.typed" in files
    assert any(re.fullmatch(r"lidarpkt/fixtures/canned/vlp16-dual\.pcap", f) for f in files)  # package data
    if os.environ.get("CI") or shutil.which("cc"):
        assert any(re.fullmatch(r"lidarpkt/_native\..*\.so", f) for f in files), "the C extension was not built"


def test_version_is_the_distributions():
    assert lidarpkt.__version__ == _installed().version


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


def _runtime_dependencies() -> list[str]:
    """The distribution names of ``[project].dependencies`` in pyproject.toml."""
    import tomllib

    with open(REPO_ROOT / "pyproject.toml", "rb") as fh:
        deps = tomllib.load(fh)["project"]["dependencies"]
    return [re.split(r"[<>=!~\[; ]", d, maxsplit=1)[0] for d in deps]


def _imported_top_level_names() -> set[str]:
    """Every top-level module name an ``import`` statement of lidarpkt/ names (inside functions too)."""
    names: set[str] = set()
    for path in (REPO_ROOT / "lidarpkt").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names |= {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                names.add(node.module.split(".")[0])
    return names


def test_every_runtime_dependency_is_imported_by_the_package():
    """A package only the tests use belongs to the ``test`` extra, not to every user's install."""
    pytest.importorskip("tomllib", reason="Python 3.11's tomllib reads pyproject.toml")
    by_distribution: dict[str, set[str]] = {}
    for module, dists in importlib.metadata.packages_distributions().items():
        for dist in dists:
            by_distribution.setdefault(re.sub(r"[-_.]+", "-", dist).lower(), set()).add(module)
    imported = _imported_top_level_names()
    unused = []
    for dep in _runtime_dependencies():
        modules = by_distribution.get(re.sub(r"[-_.]+", "-", dep).lower())
        assert modules, f"{dep}: not installed, so its modules are unknown (pip install -e .)"
        if not modules & imported:
            unused.append(f"{dep} (modules {sorted(modules)})")
    assert not unused, "runtime dependencies no module of lidarpkt/ imports: " + ", ".join(unused)
