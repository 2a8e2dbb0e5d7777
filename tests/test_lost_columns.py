"""Columns standing for lost packets (:mod:`lidarpkt.core.lost_columns`), against the rule written out packet by
packet: received columns keep their order, each lost packet leaves ``per_packet`` invalid columns just before
the packet after it, and those columns' azimuths lie evenly between their neighbours, across the wrap too."""

from __future__ import annotations

import numpy as np

from lidarpkt.core.lost_columns import interpolated_azimuth, received_places, spread


def _places_by_packet(lost, per_packet):
    places, at = [], 0
    for k in lost:
        at += int(k) * per_packet
        places.extend(range(at, at + per_packet))
        at += per_packet
    return places, at


def test_places_and_spread_follow_the_packets():
    gen = np.random.default_rng(2)
    for _ in range(50):
        n, per = int(gen.integers(1, 30)), int(gen.integers(1, 25))
        lost = gen.integers(0, 3, n) * (gen.random(n) < 0.3)
        places, width = received_places(lost, per)
        want, want_width = _places_by_packet(lost, per)
        assert places.tolist() == want and width == want_width
        values = gen.integers(1, 100, (2, n * per)).astype(np.uint16)
        out = spread(values, places, width, fill=7)
        assert out.dtype == values.dtype and out.shape == (2, width)
        assert np.array_equal(out[:, places], values)
        assert (np.delete(out, places, axis=1) == 7).all()


def test_lost_columns_lie_evenly_between_their_neighbours_across_the_wrap():
    # received 35980, 35990 | three packets of two columns lost | 30, 40: the six lost columns cross 0°
    places, width = received_places(np.array([0, 3]), 2)
    az = interpolated_azimuth(np.array([35980.0, 35990.0, 30.0, 40.0]), places, width)
    assert width == 10
    step = (30.0 - 35990.0) % 36000.0 / 7  # 40 (0.01°) over the 7 steps from column 1 to column 8
    want = [35980.0, 35990.0] + [(35990.0 + k * step) % 36000.0 for k in range(1, 7)] + [30.0, 40.0]
    np.testing.assert_allclose(az, want, rtol=0, atol=1e-9)
    # a loss before the first packet: put in after the anchor (the column before these)
    places, width = received_places(np.array([1, 0]), 1)
    az = interpolated_azimuth(np.array([100.0, 110.0]), places, width, before_cdeg=80.0)
    np.testing.assert_allclose(az, [90.0, 100.0, 110.0], rtol=0, atol=1e-9)
