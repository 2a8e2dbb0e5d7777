"""Runs the examples of a documentation page as a reader would, with Sybil: the page's ``python`` blocks in
one namespace, in order, and its ``console`` blocks as shell commands.

Both run in a folder laid out like a clone of the repository beside ``shared/`` (the paths the pages
name, ``lidarpkt/fixtures/canned/...`` and ``../shared/fixtures/external/...``, resolve as they do for a
reader), so that what the examples write lands in the test's temporary folder.

``console`` blocks: each line that starts with ``$ `` is a command, run by bash in that folder with this
interpreter's ``bin`` first on ``PATH`` (other lines are the output a reader would see, not checked);
it must exit 0. A command that ends with `` &`` runs in the background (a recorder waiting for a
replay, say): the next command starts once it has had :data:`BACKGROUND_START_S` to start. It is
stopped with Ctrl-C (SIGINT), as a reader stops it, and must then exit 0 (or 130, "interrupted"): at
the end of its block when a command ran after it there (the recorder, once the replay is done), else at
the end of the page (a server the next examples use).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import unittest
from pathlib import Path

from sybil import Example, Sybil
from sybil.parsers.myst import CodeBlockParser, PythonCodeBlockParser, SkipParser

from conftest import REPO_ROOT, end_process, external_root, start_process

DOCS = REPO_ROOT / "docs"
#: the folders and files of the repository the pages name, linked into the clone-like folder
CLONE_ENTRIES = ("lidarpkt", "docs", "tests", "benchmarks", "README.md", "pyproject.toml", "setup.py", ".ci")
BACKGROUND_START_S = 5.0
COMMAND_TIMEOUT_S = 300.0
STOP_TIMEOUT_S = 60.0


def clone_like(root: Path) -> Path:
    """``root/repo`` (the repository's entries linked in) beside ``root/shared/fixtures/external``."""
    repo = root / "repo"
    repo.mkdir()
    for name in CLONE_ENTRIES:
        if (REPO_ROOT / name).exists():
            (repo / name).symlink_to(REPO_ROOT / name)
    if external_root().is_dir():
        (root / "shared" / "fixtures").mkdir(parents=True)
        (root / "shared" / "fixtures" / "external").symlink_to(external_root().resolve())
    return repo


def _environment() -> dict[str, str]:
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env["MPLBACKEND"] = "Agg"
    return env


class ConsoleBlockParser(CodeBlockParser):
    """``console`` blocks: ``$ command`` lines run by bash in the example's folder (see the module)."""

    language = "console"

    def __init__(self, cwd: Path) -> None:
        super().__init__()
        self.cwd = cwd
        self.serving: list[tuple[str, subprocess.Popen, Path]] = []  # started last in a block: run on

    def evaluate(self, example: Example) -> str | None:
        background: list[tuple[str, subprocess.Popen, Path]] = []
        env = _environment()
        started_last = False
        try:
            for number, line in enumerate(str(example.parsed).splitlines()):
                if not line.startswith("$ "):
                    continue
                command = line[2:].strip()
                where = f"{example.path}:{example.line + number + 1}: $ {command}"
                if command.endswith("&"):
                    log = self.cwd / f".background-{len(background) + len(self.serving)}.log"
                    with open(log, "wb") as out:
                        proc = start_process(["bash", "-c", command[:-1].strip()], cwd=self.cwd, env=env,
                                             stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
                    background.append((where, proc, log))
                    started_last = True
                    time.sleep(BACKGROUND_START_S)
                    if proc.poll() not in (None, 0):
                        return f"{where}\nended with status {proc.returncode}:\n{log.read_text(errors='replace')}"
                    continue
                started_last = False
                done = subprocess.run(["bash", "-c", command], cwd=self.cwd, env=env, capture_output=True,
                                      stdin=subprocess.DEVNULL, timeout=COMMAND_TIMEOUT_S)
                if done.returncode != 0:
                    return (f"{where}\nexit status {done.returncode}\nstdout:\n{done.stdout.decode(errors='replace')}"
                            f"\nstderr:\n{done.stderr.decode(errors='replace')}")
            if started_last:  # a server for the examples after this block: stopped when the page ends
                self.serving.append(background.pop())
            return stop(background)
        finally:
            for _, proc, _ in background:
                end_process(proc)


def stop(background: list[tuple[str, subprocess.Popen, Path]]) -> str | None:
    """Ctrl-C to each background command, as a reader stops it; what went wrong, or None. A command
    stopped by Ctrl-C exits 0, or 130 (the CLI's status for "interrupted")."""
    failure = None
    for where, proc, log in background:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(timeout=STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            failure = failure or f"{where}\ndid not stop within {STOP_TIMEOUT_S:.0f} s of Ctrl-C"
            continue
        if proc.returncode not in (0, 130):
            failure = failure or f"{where}\nexit status {proc.returncode}:\n{log.read_text(errors='replace')}"
    return failure


def planned_features() -> dict[str, bool]:
    """Names the pages' ``% skip: next if(not NAME, ...)`` comments test: what the code has of a change
    the pages are written for but that has not landed everywhere (the example runs once it has)."""
    import inspect

    import lidarpkt

    return {
        # one set of sensor options: metadata= takes any vendor's file, model= where packets cannot tell
        "UNIFORM_SENSOR_OPTIONS": "model" in inspect.signature(lidarpkt.open).parameters,
    }


def run_page(page: Path, workdir: Path) -> int:
    """Evaluate every example of ``page`` in order with ``workdir`` as the current folder; returns how
    many ran. Raises (an AssertionError or the example's exception) at the first that fails."""
    console = ConsoleBlockParser(workdir)
    sybil = Sybil(parsers=[PythonCodeBlockParser(), console, SkipParser()], path=str(DOCS))
    document = sybil.parse(page)
    document.namespace.update(planned_features())
    previous = Path.cwd()
    os.chdir(workdir)
    ran = 0
    try:
        for example in document.examples():
            try:
                example.evaluate()
            except unittest.SkipTest as planned:  # a `% skip: next if(...)`: only that example waits
                print(f"{page.name}:{example.line}: not run yet: {planned}")
                continue
            ran += 1
    finally:
        os.chdir(previous)
        try:
            failure = stop(console.serving)
        finally:
            for _, proc, _ in console.serving:
                end_process(proc)
    assert failure is None, failure
    return ran
