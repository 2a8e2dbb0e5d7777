"""lidarpkt.core.heap: after ``keep_freed_arrays`` (and after ``lidarpkt.open``), arrays freed and made again
keep their pages; without it glibc hands them back and faults them in again. Each case runs in a process of
its own, whose heap nothing else has shaped, and counts its minor page faults."""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys

import pytest

pytestmark = pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="glibc's dynamic mmap threshold")

# two 3 MiB arrays written and dropped, six times: the faults of each round
ROUNDS = """
import json, resource, sys
import numpy as np
{setup}
def faults():
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt
rounds = []
for _ in range(6):
    before = faults()
    a = np.ones(3 << 20, np.uint8)
    b = np.ones(3 << 20, np.uint8)
    del a, b
    rounds.append(faults() - before)
print(json.dumps(rounds))
"""

PAGES = 2 * (3 << 20) // 4096  # the pages of one round's two arrays


def _rounds(setup: str, **env: str) -> list[int]:
    clean = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    out = subprocess.run([sys.executable, "-c", ROUNDS.format(setup=setup)], env={**clean, **env},
                         capture_output=True, text=True, timeout=120, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_without_it_every_round_faults_its_pages_in_again():
    # the case the module exists for (if glibc ever stops doing this, the module has no job left)
    rounds = _rounds("")
    assert all(r >= PAGES * 0.9 for r in rounds), rounds


def test_after_keep_freed_arrays_the_rounds_after_the_first_take_no_new_page():
    rounds = _rounds("from lidarpkt.core.heap import keep_freed_arrays\nkeep_freed_arrays()")
    assert rounds[0] >= PAGES * 0.9, rounds  # the first round faults its pages in: nothing was kept before
    assert sum(rounds[1:]) < PAGES * 0.05, rounds


def test_opening_a_capture_keeps_freed_arrays():
    setup = ("import lidarpkt\nfrom lidarpkt import fixtures\n"
             "frames = list(lidarpkt.open(fixtures.canned('vlp16-strongest')))\nassert frames\ndel frames")
    rounds = _rounds(setup)
    assert sum(rounds[1:]) < PAGES * 0.05, rounds


def test_a_threshold_the_user_set_is_left_alone():
    rounds = _rounds("from lidarpkt.core.heap import keep_freed_arrays\nkeep_freed_arrays()",
                     MALLOC_MMAP_THRESHOLD_="131072")
    assert all(r >= PAGES * 0.9 for r in rounds), rounds
