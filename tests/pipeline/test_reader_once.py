"""A reader of ``lidarpkt.open`` gives its frames once: a second loop over a consumed reader, or a loop
after ``close()``, raises a UsageError that says so, whatever reader it is (one thread, decoded ahead,
segments, an OSF file); a loop left early goes on where it stopped."""

from __future__ import annotations

import pytest

import lidarpkt
from lidarpkt.errors import UsageError

from conftest import external

VLP10 = "rust-lidar-utils/velodyne_example.pcap"
OSF = "ouster-sdk/osf_fw_3.2_10scans.osf"


@pytest.mark.parametrize("capture,workers", [(VLP10, 1), (VLP10, 2), (OSF, 1)])
def test_a_second_loop_over_a_consumed_reader_raises(capture, workers):
    reader = lidarpkt.open(external(capture), workers=workers)
    first = list(reader)
    assert first
    with pytest.raises(UsageError, match=r"gives its frames once, and its frames were all taken; call lidarpkt.open"):
        list(reader)
    with pytest.raises(StopIteration):  # next() keeps the iterator protocol
        next(reader)


@pytest.mark.parametrize("capture,workers", [(VLP10, 1), (VLP10, 2), (OSF, 1)])
def test_a_loop_after_close_raises(capture, workers):
    reader = lidarpkt.open(external(capture), workers=workers)
    reader.close()
    with pytest.raises(UsageError, match="it was closed"):
        for _ in reader:
            pass


def test_a_loop_left_early_goes_on_where_it_stopped():
    with lidarpkt.open(external(VLP10)) as reader:
        for first in reader:
            break
        rest = list(reader)
    assert [f.frame_id for f in [first] + rest] == [f.frame_id for f in lidarpkt.open(external(VLP10))]
