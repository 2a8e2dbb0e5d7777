"""What lidarpkt makes of every external capture and canned fixture stays what it was, field for field
and file for file (``tests/golden_outputs.py``, digests in ``tests/data/golden_digests.json``).

A difference names the case and the outputs that changed; a deliberate change is re-recorded with
``python tests/golden_outputs.py --update CASE`` and named in its commit message."""

from __future__ import annotations

import pytest

import golden_outputs
from conftest import external

STORED = golden_outputs.load()


@pytest.mark.parametrize("case", sorted(golden_outputs.CASES))
def test_outputs_equal_their_recorded_digests(case):
    name, files = golden_outputs.CASES[case]
    for path in (name, *files):
        if path.startswith("ext:"):
            external(path[4:])  # skips (fails in CI) when the external captures are absent
    assert case in STORED, f"{case}: no digest recorded (python tests/golden_outputs.py --update {case})"
    got = golden_outputs.case_digests(case)
    changed = sorted(k for k in set(got) | set(STORED[case]) if got.get(k) != STORED[case].get(k))
    assert not changed, f"{case}: {', '.join(changed)} differ from the recorded digests"
