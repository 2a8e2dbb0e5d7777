"""Ctrl-C stops every verb, also one started with SIGINT ignored (as a shell's ``&`` in a script starts it):
``lidarpkt.cli.main`` puts the default handler back for the verb's run and restores the caller's after.

A real process and a real signal: the process ignores SIGINT as a backgrounded job does, then runs
``main`` on a verb whose work is replaced by a wait (the handling under test is main's, the same for every
verb; ``record``, ``view`` and ``replay`` install their own stop handlers on top)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
CANNED = REPO / "lidarpkt" / "fixtures" / "canned"

CHILD = """
import os, signal, sys, time
signal.signal(signal.SIGINT, signal.SIG_IGN)
from lidarpkt import cli
from lidarpkt.cli import info

def run(args):  # the verb's work: interrupted by Ctrl-C while it runs
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(30)
    return 0

info.run = run
status = cli.main(["info", sys.argv[1]])
print(status, signal.getsignal(signal.SIGINT) is signal.SIG_IGN)
"""


def test_a_verb_started_with_sigint_ignored_stops_on_ctrl_c():
    run = subprocess.run([sys.executable, "-c", CHILD, str(CANNED / "vlp16-dual.pcap")], capture_output=True,
                         text=True, timeout=25, cwd=REPO, env=dict(os.environ, PYTHONPATH=str(REPO)))
    # exit 130 with one line, and the caller's disposition (ignored) back after main
    assert run.stdout.split() == ["130", "True"], (run.stdout, run.stderr)
    assert run.stderr.strip() == "lidarpkt: interrupted"
