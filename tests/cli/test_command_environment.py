"""The ``lidarpkt`` command's own process runs NumPy's BLAS in one thread unless told otherwise; ``main``
called from Python leaves the caller's environment alone."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from lidarpkt.cli import COMMAND_ENVIRONMENT, main

# the command, then NumPy imported in the same process: its BLAS threads are the process's threads
PROBE = """
import os, sys
from lidarpkt.cli import command
sys.argv = ["lidarpkt", "--version"]
try:
    command()
except SystemExit:
    pass
import numpy
print(os.environ.get("OPENBLAS_NUM_THREADS"), len(os.listdir("/proc/self/task")))
"""


def probe(env: dict[str, str]) -> tuple[str, int]:
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, timeout=120,
                         check=True).stdout.split()
    return out[-2], int(out[-1])


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="needs Linux's /proc to count threads")
def test_the_command_runs_numpy_blas_in_one_thread():
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    value, threads = probe(env)
    assert value == COMMAND_ENVIRONMENT["OPENBLAS_NUM_THREADS"] == "1"
    assert threads == 1  # OpenBLAS started no thread of its own


def test_a_value_the_user_set_is_kept():
    env = dict(os.environ, OPENBLAS_NUM_THREADS="2")
    assert probe(env)[0] == "2"


def test_main_in_process_leaves_the_environment_alone(monkeypatch, capsys):
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    with pytest.raises(SystemExit):
        main(["--version"])
    assert "OPENBLAS_NUM_THREADS" not in os.environ
