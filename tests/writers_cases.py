"""The captures every writer test writes in every format: each external capture lidarpkt decodes
and each canned fixture, with its metadata. ``load(case)`` decodes it with ``lidarpkt.open`` (the
expectation every format's own reader is compared with), skipping when the capture is absent."""

from __future__ import annotations

import warnings
from functools import lru_cache
from pathlib import Path

import pytest

import lidarpkt
from conftest import REPO_ROOT, external

CANNED = REPO_ROOT / "lidarpkt" / "fixtures" / "canned"

# (id, capture, metadata): "ext:" paths are external captures, the others canned fixtures
CASES = [
    ("veloview-vlp16", "ext:veloview/vlp-16-test-90deg-1-50-frames.pcap", None),
    ("rust-velodyne", "ext:rust-lidar-utils/velodyne_example.pcap", None),
    ("rust-vlp16", "ext:rust-lidar-utils/velodyne_vlp16.pcap", None),
    ("nebula-rosbag2-dual", "ext:nebula/vlp16/1673400471837873222", None),
    ("rust-ouster", "ext:rust-lidar-utils/ouster_example.pcap", ["ext:rust-lidar-utils/ouster_example.json"]),
    ("os0-128", "ext:ouster-sdk/OS-0-128-U1_v2.3.0_1024x10.pcap", ["ext:ouster-sdk/OS-0-128-U1_v2.3.0_1024x10.json"]),
    ("os0-32-dual", "ext:ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.pcap", ["ext:ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.json"]),
    ("os1-32-g", "ext:ouster-sdk/OS-1-32-G_v2.1.1_1024x10.pcap", ["ext:ouster-sdk/OS-1-32-G_v2.1.1_1024x10.json"]),
    ("os2-128", "ext:ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.pcap", ["ext:ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.json"]),
    ("os2-32", "ext:ouster-sdk/OS-2-32-U0_v2.0.0_1024x10.pcap", ["ext:ouster-sdk/OS-2-32-U0_v2.0.0_1024x10.json"]),
    ("os1-64-fw20", "ext:ouster-sdk/OS-1-64_1024x10_fw20.pcap", ["ext:ouster-sdk/OS-1-64_sensor_config_reduced.json"]),
    ("crc-test", "ext:ouster-sdk/crc_test.pcap", ["ext:ouster-sdk/crc_test.json"]),
    ("duplicate-id", "ext:ouster-sdk/duplicate_id.pcap", ["ext:ouster-sdk/duplicate_id.json"]),
    ("two-sensors-legacy", "ext:ouster-sdk/same_ports_legacy.pcap",
     ["ext:ouster-sdk/same_ports_legacy.1.json", "ext:ouster-sdk/same_ports_legacy.2.json"]),
    ("two-sensors-dual", "ext:ouster-sdk/same_ports_nonlegacy.pcap",
     ["ext:ouster-sdk/same_ports_nonlegacy.1.json", "ext:ouster-sdk/same_ports_nonlegacy.2.json"]),
    ("canned-os1-dual", "os1-64-dual.pcap", ["os1-64-dual.json"]),
    ("canned-os1-legacy", "os1-64-legacy.pcap", ["os1-64-legacy.json"]),
    ("canned-vlp16-dual", "vlp16-dual.pcap", None),
    ("canned-vlp16-last", "vlp16-last.pcap", None),
    ("canned-vlp16-strongest", "vlp16-strongest.pcap", None),
]
IDS = [c[0] for c in CASES]
MAX_FRAMES = 12  # enough for every capture here but the 52-frame VeloView one, which is subsampled


def _resolve(name: str) -> Path:
    return external(name[4:]) if name.startswith("ext:") else CANNED / name


def capture(case) -> tuple[Path, list[Path] | None]:
    """(capture path, metadata paths) of a case; skips when an external file is absent."""
    _, cap, md = case
    return _resolve(cap), None if md is None else [_resolve(m) for m in md]


@lru_cache(maxsize=None)
def _frames(cap: str, md: tuple | None) -> list:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        frames = list(lidarpkt.open(cap, metadata=list(md) if md else None))
    if len(frames) > MAX_FRAMES:  # the first, one from the middle, the last
        frames = [frames[0], frames[len(frames) // 2], frames[-1]]
    return frames


def load(case) -> tuple[Path, list[Path] | None, list]:
    """(capture, metadata, frames as ``lidarpkt.open`` gives them, subsampled to at most 12)."""
    cap, md = capture(case)
    return cap, md, _frames(str(cap), None if md is None else tuple(str(m) for m in md))


@pytest.fixture(params=CASES, ids=IDS)
def case(request):
    return request.param
