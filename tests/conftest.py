"""Shared test plumbing: where the external (third-party) captures are, and the skip when they are not.

In CI (environment variable ``CI`` set to a true value, as CI services do) nothing may be skipped
for want of data or tools: a missing external-fixtures folder or capture, or a missing reference
decoder (velodyne_decoder, ouster-sdk) or other test extra, fails the test with the reason. Only
the skips of :data:`ENVIRONMENT_SKIPS` (what this machine cannot do, not what is missing) stay skips;
known limits of the reference tools are ``xfail(strict=True)`` in the tests themselves.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]

# the test folders mirror the packages, and some modules share helpers across them (test_ouster_cases,
# test_replay_record): every folder is importable whichever tests are selected (module names are unique)
for _folder in sorted(p for p in Path(__file__).resolve().parent.iterdir()
                      if p.is_dir() and p.name not in ("data", "__pycache__")):
    if str(_folder) not in sys.path:
        sys.path.append(str(_folder))


def external_root() -> Path:
    """The external fixtures folder: $LIDARPKT_EXTERNAL_FIXTURES, else ../shared/fixtures/external."""
    env = os.environ.get("LIDARPKT_EXTERNAL_FIXTURES")
    return Path(env) if env else (REPO_ROOT.parent / "shared" / "fixtures" / "external")


def in_ci() -> bool:
    """``CI`` is set to a true value (``true``, ``1``, ``yes``): skips for missing data are failures."""
    return os.environ.get("CI", "").strip().lower() in ("1", "true", "yes", "on")


#: Skip reasons that stay skips in CI: what the machine cannot do (root, multicast on loopback,
#: /proc) or a combination a parametrised test does not apply to, never missing data or tools.
ENVIRONMENT_SKIPS = (
    "needs root",
    "needs root to be absent",
    "cannot join a multicast group",
    "needs /proc/self/fd",
    "LIDARPKT_NATIVE=0",
    "window taller than the neighbourhood",
)


def external(relpath: str) -> Path:
    """Path of one external capture; skips the calling test with the reason when it is absent
    (fails it in CI)."""
    path = external_root() / relpath
    if not path.exists():
        reason = (
            f"external fixture {relpath} not found under {external_root()} "
            "(set LIDARPKT_EXTERNAL_FIXTURES to the folder holding shared/fixtures/external)"
        )
        if in_ci():
            pytest.fail(f"CI: {reason}", pytrace=False)
        pytest.skip(reason)
    return path


def _skip_reason(report) -> str:
    longrepr = report.longrepr
    if isinstance(longrepr, tuple) and len(longrepr) == 3:
        return str(longrepr[2])
    return str(longrepr)


def _fail_skip_in_ci(report) -> None:
    """In CI, turn a skip (an importorskip of a missing reference decoder or extra, a missing
    fixture) into a failure that says what is missing; xfails and :data:`ENVIRONMENT_SKIPS` stay."""
    if not (in_ci() and report.skipped) or hasattr(report, "wasxfail"):
        return
    reason = _skip_reason(report)
    if any(allowed in reason for allowed in ENVIRONMENT_SKIPS):
        return
    report.outcome = "failed"
    report.longrepr = (
        f"CI: this would have been skipped ({reason}); in CI every reference decoder, test extra and "
        "external fixture must be present (pip install -e '.[test,crosscheck]', LIDARPKT_EXTERNAL_FIXTURES)"
    )


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item, call):
    report = yield
    _fail_skip_in_ci(report)
    return report


@pytest.hookimpl(wrapper=True)
def pytest_make_collect_report(collector):
    report = yield  # a module-level importorskip skips the whole module at collection
    _fail_skip_in_ci(report)
    return report


def pytest_report_header(config):
    mode = "CI: skips for missing data or tools fail" if in_ci() else "not CI: missing data or tools skip"
    return f"lidarpkt external fixtures: {external_root()} ({'present' if external_root().is_dir() else 'ABSENT'}); {mode}"


@pytest.fixture
def ext():
    """``ext("ouster-sdk/crc_test.pcap")`` → Path, or skip when the external fixtures are absent."""
    return external

def under_mutmut() -> bool:
    """mutmut 3 wraps every function in a trampoline, one frame more between the caller and the
    warning: a stacklevel check cannot hold there (benchmarks/mutation.py)."""
    import os

    return "MUTANT_UNDER_TEST" in os.environ


# ------------------------------------------------------------------ processes a test starts
_STARTED: list = []  # (Popen, owner): every process started through start_process, until reaped


def _default_signals() -> None:
    """In the child, before exec: SIGINT and SIGQUIT back to their defaults. A test run as a background
    job of a non-interactive shell (or by some CI runners) inherits them ignored, and a Python program
    started with SIGINT ignored never raises KeyboardInterrupt: a test's Ctrl-C would not reach it."""
    import signal

    for sig in (signal.SIGINT, signal.SIGQUIT):
        signal.signal(sig, signal.SIG_DFL)


def start_process(args, *, owner: str = "test", **kwargs):
    """``subprocess.Popen(args, **kwargs)`` for tests: signals at their defaults whatever this process
    inherited, its own process group (so that its own children can be ended with it), and remembered
    so that :func:`end_process` (called by the autouse fixture after each test, pass or fail, for
    ``owner="test"``; by the fixture that started it otherwise) leaves nothing running."""
    import subprocess

    kwargs.setdefault("start_new_session", True)
    proc = subprocess.Popen(args, preexec_fn=_default_signals, **kwargs)
    _STARTED.append((proc, owner))
    return proc


def end_process(proc, timeout: float = 30.0) -> None:
    """Kill ``proc`` and its process group if anything of it still runs, and reap it."""
    import os
    import signal
    import subprocess

    try:
        os.killpg(proc.pid, signal.SIGKILL)  # the group: also what it started
    except (ProcessLookupError, PermissionError):
        pass
    if proc.poll() is None:
        proc.kill()
    try:
        proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        pass
    for stream in (proc.stdin, proc.stdout, proc.stderr):
        if stream is not None:
            stream.close()
    _STARTED[:] = [(p, o) for p, o in _STARTED if p is not proc]


@pytest.fixture(autouse=True)
def _no_process_left_behind():
    """Every process a test started with :func:`start_process` is ended when the test ends, pass or fail."""
    yield
    for proc, owner in list(_STARTED):
        if owner == "test":
            end_process(proc)
