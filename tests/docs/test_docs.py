"""The documentation site (``docs/``) is built and checked with the code.

- It builds with every warning an error (a broken cross-reference, a missing page or image, a name the
  API reference cannot import), with the command README gives.
- The CLI reference holds every verb and every flag of the parser the ``lidarpkt`` command uses.
- The API reference holds every public name (``__all__``, else every public class and function defined
  there) of ``lidarpkt`` and its documented packages.
- Every example on every page runs (``doc_examples``), on the bundled fixtures or the external captures.
- No page names a file of the repository or of the external captures that does not exist.

The site is built once per test session (the first worker to need it builds it; the others wait).
"""

from __future__ import annotations

import argparse
import fcntl
import html
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import REPO_ROOT, external
from doc_examples import DOCS, clone_like, run_page

sys.path.insert(0, str(DOCS / "_ext"))
from lidarpkt_docs import _MISSING, import_name  # noqa: E402

sphinx = pytest.importorskip("sphinx", reason="the docs extra is not installed: pip install '.[docs]'")

#: the packages the API reference documents (docs/reference/api/): every name of their __all__
DOCUMENTED = ("lidarpkt", "lidarpkt.errors", "lidarpkt.containers", "lidarpkt.writers", "lidarpkt.archive",
              "lidarpkt.analysis", "lidarpkt.view", "lidarpkt.fixtures")
README = REPO_ROOT / "README.md"
#: the pages, and the other texts that name files (benchmarks/README.md says how to run the benchmarks)
PAGES = sorted({p for p in DOCS.rglob("*.md") if "_build" not in p.parts} | {README})
TEXTS = PAGES + [REPO_ROOT / "benchmarks" / "README.md"]
BUILD_COMMAND = [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html"]


@pytest.fixture(scope="session")
def site(tmp_path_factory) -> Path:
    """The built site (HTML), built once for every worker of the session; fails the test on a warning."""
    shared = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        shared = shared.parent  # the run's folder, the same for every xdist worker of the run
    out = shared / "docs-site"
    with open(shared / "docs-site.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        result = out / "result.txt"
        if not result.exists():
            done = subprocess.run(BUILD_COMMAND + ["-d", str(shared / "docs-doctrees"), str(DOCS), str(out / "html")],
                                  capture_output=True, text=True, cwd=REPO_ROOT, timeout=600)
            out.mkdir(exist_ok=True)
            result.write_text(f"{done.returncode}\n{done.stderr}")
        status, _, stderr = result.read_text().partition("\n")
    assert status == "0" and not stderr.strip(), f"the site's build failed or warned:\n{stderr}"
    return out / "html"


def test_the_site_builds_with_warnings_as_errors(site):
    for page in PAGES:
        if page == README:
            continue
        built = site / page.relative_to(DOCS).with_suffix(".html")
        assert built.is_file(), f"{page.relative_to(REPO_ROOT)} was not built"


def _text(path: Path) -> str:
    """An HTML page's text, tags removed and entities decoded (as a reader sees it, roughly)."""
    raw = re.sub(r"<[^>]+>", " ", path.read_text())
    return html.unescape(raw)


def _sub_parsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _documented_actions(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    """The actions ``--help`` shows, but ``-h/--help`` itself (every verb has it; the page says so)."""
    return [a for a in parser._actions
            if a.help is not argparse.SUPPRESS and not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction))]


def _mentions(text: str, flag: str) -> bool:
    return re.search(rf"(?<![\w-]){re.escape(flag)}(?![\w-])", text) is not None


def test_the_cli_reference_has_every_verb_and_flag_of_the_parser(site):
    from lidarpkt.cli import build_parser

    parser = build_parser("*")
    page = (site / "reference" / "cli.html").read_text()
    verbs = _sub_parsers(parser)
    assert len(verbs) >= 12
    # sphinx-argparse gives each verb a section: split the page at them and check each verb's own flags
    starts = {verb: page.find(f'id="{verb}"') for verb in verbs}
    missing_sections = sorted(v for v, i in starts.items() if i < 0)
    assert not missing_sections, f"no section for the verbs {missing_sections} in reference/cli.html"
    order = sorted(starts.items(), key=lambda kv: kv[1])
    missing = []
    for k, (verb, start) in enumerate(order):
        end = order[k + 1][1] if k + 1 < len(order) else len(page)
        section = html.unescape(re.sub(r"<[^>]+>", " ", page[start:end]))
        for action in _documented_actions(verbs[verb]):
            for flag in action.option_strings or [action.metavar or action.dest]:
                if not _mentions(section, flag):
                    missing.append(f"{verb} {flag}")
    top = _text(site / "reference" / "cli.html")
    missing += [f for a in _documented_actions(parser) for f in a.option_strings if not _mentions(top, f)]
    assert not missing, f"flags the parser has and reference/cli.html lacks: {missing}"


def test_the_api_reference_has_every_public_name(site):
    import importlib

    from sphinx.util.inventory import InventoryFile

    with open(site / "objects.inv", "rb") as fh:
        inventory = InventoryFile.load(fh, "", lambda base, uri: uri)
    entries = inventory.data if hasattr(inventory, "data") else inventory  # Sphinx 9: a dict
    documented = {name for kind, names in entries.items() if kind.startswith("py:") for name in names}
    by_identity = {}
    for name in documented:
        obj = import_name(name)
        if obj is not _MISSING:
            by_identity[id(obj)] = name
    missing = []
    for package in DOCUMENTED:
        module = importlib.import_module(package)
        names = getattr(module, "__all__", None) or [n for n, v in vars(module).items()
                                                      if not n.startswith("_") and getattr(v, "__module__", None) == package]
        for name in names:
            if f"{package}.{name}" in documented:
                continue
            obj = getattr(module, name)
            if isinstance(obj, (type, type(len))) or callable(obj):
                if id(obj) in by_identity:  # documented under its other public name
                    continue
            missing.append(f"{package}.{name}")
    assert not missing, f"public names the API reference does not document: {missing}"
    stale = sorted(n for n in documented if n.startswith("lidarpkt.") and not _exists(n))
    assert not stale, f"the API reference documents names the code does not have: {stale}"


def _exists(name: str) -> bool:
    """``name`` imports, or is a field its class declares (a dataclass field without a default)."""
    if import_name(name) is not _MISSING:
        return True
    parent, _, attr = name.rpartition(".")
    owner = import_name(parent)
    return isinstance(owner, type) and any(attr in getattr(c, "__annotations__", {}) for c in owner.__mro__)


def test_the_readme_is_short_links_into_the_site_and_keeps_the_ci_commands():
    text = README.read_text()
    assert len(text.splitlines()) <= 150
    for marker in ("<!-- main-command -->", "<!-- test-command -->"):
        command = text.split(marker, 1)[1].split("```sh\n", 1)[1].split("\n", 1)[0]
        assert command.startswith("python3 -m venv .venv && . .venv/bin/activate && pip install '.[")
    test_command = text.split("<!-- test-command -->", 1)[1]
    assert "docs]'" in test_command.split("\n```", 2)[1] or ",docs" in test_command.split("\n```", 2)[1]
    assert " ".join(BUILD_COMMAND[2:5]) in text  # the command that builds the site
    linked = set(re.findall(r"\]\((docs/[\w/.-]+\.md)\)", text))
    assert {"docs/getting-started.md", "docs/reference/cli.md", "docs/reference/api/index.md"} <= linked


@pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(REPO_ROOT)) for p in PAGES])
def test_every_example_of_the_page_runs(page, tmp_path):
    for relpath in sorted(set(re.findall(r"\.\./shared/fixtures/external/([\w./-]+\w)", page.read_text()))):
        external(relpath)  # skips (fails in CI) when the captures the page uses are absent
    run_page(page, clone_like(tmp_path))


#: a path of the repository or of the external captures, as the pages write them
PATH_PATTERN = re.compile(r"(?<![\w/.-])((?:\.\./shared/fixtures/external|lidarpkt|tests|benchmarks|docs|\.ci)/[\w./*-]*"
                          r"|README\.md|pyproject\.toml|setup\.py)")
#: named by the pages but made by a command, not kept in the repository
MADE = ("docs/_build",)


def _named_paths(text: str) -> set[str]:
    return {m.rstrip(".,:;") for m in PATH_PATTERN.findall(text)}


@pytest.mark.parametrize("page", TEXTS, ids=[str(p.relative_to(REPO_ROOT)) for p in TEXTS])
def test_the_page_names_only_files_that_exist(page):
    missing = []
    for name in sorted(_named_paths(page.read_text())):
        if name.startswith(MADE):
            continue
        if name.startswith("../shared/fixtures/external/"):
            external(name.removeprefix("../shared/fixtures/external/"))
            continue
        matches = list(REPO_ROOT.glob(name)) if "*" in name else [REPO_ROOT / name]
        if not matches or not all(m.exists() for m in matches):
            missing.append(name)
    assert not missing, f"{page.relative_to(REPO_ROOT)} names files that do not exist: {missing}"
