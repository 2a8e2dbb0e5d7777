"""lidarpkt as a user's type checker sees it: ``lidarpkt.open``'s options are typed keywords, its frames
are :class:`lidarpkt.core.frame.Frame`; and the typed keywords are the options ``lidarpkt.open`` takes."""

from __future__ import annotations

import dataclasses
import os
import re
import subprocess
import sys
import typing
from pathlib import Path

from lidarpkt.pipeline.options import OpenKeywords, OpenOptions
from lidarpkt.containers.segments import Segment

REPO = Path(__file__).resolve().parents[1]

USER_SCRIPT = '''\
import lidarpkt

path = "capture.pcap"
lidarpkt.open(path, no_such_option=1)
lidarpkt.open(path, workers="two")
for frame in lidarpkt.open(path, workers=2, ports=[2368]):
    reveal_type(frame)
'''


def test_open_keywords_are_the_open_options_name_for_name_and_type_for_type():
    ns = {"Segment": Segment}  # imported by options.py for type checkers only
    keywords = typing.get_type_hints(OpenKeywords, localns=ns)
    options = typing.get_type_hints(OpenOptions, localns=ns)
    assert list(keywords) == [f.name for f in dataclasses.fields(OpenOptions)]
    assert keywords == options
    assert not OpenKeywords.__required_keys__  # every option may be left out


def test_mypy_flags_a_misspelt_option_and_sees_frames(tmp_path):
    script = tmp_path / "user_script.py"
    script.write_text(USER_SCRIPT)
    env = dict(os.environ, MYPYPATH=str(REPO))  # this checkout's lidarpkt, not an installed copy
    # run from tmp_path: the repository's [tool.mypy] (files = lidarpkt) is not this user's configuration;
    # silent: lidarpkt's modules are read for their types, their own findings are not this test's
    proc = subprocess.run(
        [sys.executable, "-m", "mypy", "--cache-dir", str(tmp_path / "mypy_cache"), "--follow-imports=silent",
         "--no-error-summary", "--python-version", "3.10", script.name],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300,
    )
    out = proc.stdout
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert re.search(r'user_script\.py:4: error: Unexpected keyword argument "no_such_option"', out), out
    assert re.search(r'user_script\.py:5: error: Argument "workers" .* incompatible type "str"; expected "int \| None"', out), out
    assert 'user_script.py:7: note: Revealed type is "lidarpkt.core.frame.Frame"' in out, out
    assert len(re.findall(r": error:", out)) == 2, out  # the well-typed call passes


def test_ruff_passes_on_lidarpkt():
    # the repository's [tool.ruff]; CI runs this through README's test command
    proc = subprocess.run([sys.executable, "-m", "ruff", "check", "lidarpkt"], cwd=REPO, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_mypy_passes_on_lidarpkt():
    # the repository's [tool.mypy] (files = lidarpkt); its cache is the repository's .mypy_cache (warm after a
    # first run; a cold run takes about 30 s of CPU)
    proc = subprocess.run([sys.executable, "-m", "mypy"], cwd=REPO, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0 and "Success: no issues found" in proc.stdout, proc.stdout + proc.stderr
