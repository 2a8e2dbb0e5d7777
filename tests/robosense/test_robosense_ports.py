"""nebula's ``RobosenseScan`` carries the DIFOP among the MSOP packets, and a bag keeps no UDP ports: the vendor
record parts a scan by kind, so that each kind can go to its factory port (MSOP 6699, DIFOP 7788, rs_driver's
``msop_port`` and ``difop_port``). Packets are told apart by their identifiers here, not by lidarpkt."""

from __future__ import annotations

import numpy as np

from robosense_bag import batches

DIFOP_ID = bytes.fromhex("a5ff005a11115555")  # a DIFOP packet's first 8 bytes (the manuals' identifier)
MSOP_PORT, DIFOP_PORT = 6699, 7788  # the manuals' factory ports, rs_driver's defaults


def test_the_record_parts_a_scan_by_kind():
    """The vendor record's ``split``, through the registry: each message of the bag (one batch, as rosbags reads
    it) parted into its MSOP and its DIFOP, every packet once, the parts in the order of their first packet."""
    from lidarpkt.vendors import registry

    kinds = []
    for batch in batches():
        match = registry.classify(batch)
        parts = registry.by_kind(batch, match)
        np.testing.assert_array_equal(np.sort(np.concatenate([p.index for _, p in parts])), batch.index)
        assert [int(p.index[0]) for _, p in parts] == sorted(int(p.index[0]) for _, p in parts)
        for m, p in parts:
            difop = [row[:8].tobytes() == DIFOP_ID for row in p.payload]
            assert all(difop) if m.kind == "difop" else not any(difop)
            assert registry.vendor(m.vendor).endpoints(m)[1].port == (DIFOP_PORT if m.kind == "difop" else MSOP_PORT)
        kinds.append([m.kind for m, _ in parts])
    assert sorted(kinds) == [["msop"]] * 4 + [["msop", "difop"]]  # one message carries the DIFOP among its MSOP
