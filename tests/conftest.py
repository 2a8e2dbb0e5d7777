"""Shared test plumbing: where the external (third-party) captures are, and the skip when they are not."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]


def external_root() -> Path:
    """The external fixtures folder: $LIDARPKT_EXTERNAL_FIXTURES, else ../shared/fixtures/external."""
    env = os.environ.get("LIDARPKT_EXTERNAL_FIXTURES")
    return Path(env) if env else (REPO_ROOT.parent / "shared" / "fixtures" / "external")


def external(relpath: str) -> Path:
    """Path of one external capture; skips the calling test with the reason when it is absent."""
    path = external_root() / relpath
    if not path.exists():
        pytest.skip(
            f"external fixture {relpath} not found under {external_root()} "
            "(set LIDARPKT_EXTERNAL_FIXTURES to the folder holding shared/fixtures/external)"
        )
    return path


@pytest.fixture
def ext():
    """``ext("ouster-sdk/crc_test.pcap")`` → Path, or skip when the external fixtures are absent."""
    return external
