"""lidarpkt against hydra4 0.2.0 (PyPI, a pure-Python XT32 decoder written apart from nebula) on the XT32 bag.

hydra4 yields, for each dual-return packet, the first block of each firing (the last return): its points
must be our slot 0 ("last") of the same firing and channel, to a micrometre (both in float64 from the same
CSV), with the same intensity."""

from __future__ import annotations

import numpy as np
import pytest

from lidarpkt.vendors.hesai import HesaiDecoder, load_calibration
from lidarpkt.core.packet import PacketBatch


@pytest.mark.crosscheck
def test_hydra4_points_are_our_last_returns(ext):
    import glob

    pytest.importorskip("hydra4")
    from hydra4.decoders.pandar_xt32 import PandarXT32
    from hydra4.msgs import pandar_msgs__msg__PandarPacket

    from lidarpkt.containers.bags import BagReader

    from lidarpkt.vendors.registry import bag_messages

    batch = next(iter(BagReader(glob.glob(str(ext("nebula/hesai/xt32")) + "/*/")[0], messages=bag_messages()).batches()))
    csv = ext("nebula/hesai/PandarXT32.csv")
    theirs = PandarXT32(csv, 0.05, 120.0)
    n = 40
    dec = HesaiDecoder(calibration=load_calibration(csv))
    frames = dec.push(PacketBatch.from_payloads(batch.payload[:n], batch.timestamp_ns[:n])) + dec.finish()
    xyz = np.concatenate([f.xyz() for f in frames], axis=2)  # [2, 32, n·4]
    refl = np.concatenate([f.reflectivity for f in frames], axis=2)
    row_of = np.argsort(dec.geometry.row_channel)  # channel → row
    compared = 0
    for i in range(n):
        packet = pandar_msgs__msg__PandarPacket(stamp=None, data=batch.payload[i], size=1080)
        for k, block in enumerate(theirs(packet)):
            for x, y, z, intensity, ring, _, _ in block.points:
                col, row = i * 4 + k, row_of[ring]
                assert np.allclose(xyz[0, row, col], (x, y, z), atol=1e-6), (i, k, ring)
                assert refl[0, row, col] == intensity
                compared += 1
    assert compared > 2000
