"""The Pandar model table's facts: firing times, return-slot labels and the dual mark rule, calibration files.

Expected numbers are the manuals' (XT32: blocks fire 50 µs apart, the last one 5.632 µs after the packet
time, laser 0 0.368 µs into its block, the lasers 1.512 µs apart; the QT64's laser table), written out by hand."""

from __future__ import annotations

import numpy as np
import pytest

from lidarpkt.errors import CalibrationError
from lidarpkt.vendors.hesai import (
    HesaiDecoder,
    encode_packets,
    load_calibration,
    model_named,
    parse_calibration,
)
from lidarpkt.vendors.hesai.models import MODELS
from lidarpkt.vendors.hesai.timing import QT64_CHANNEL_NS, firing_offsets_ns
from lidarpkt.core.packet import PacketBatch

T0 = 1_700_000_000_000_000_000


def _frame(model, mode, distance, reflectivity, n=1, az0=10000):
    nret = {0x37: 1, 0x39: 2, 0x3B: 2, 0x3C: 2, 0x3D: 3}[mode]
    groups = model.blocks // nret
    az = np.repeat(az0 + np.arange(n * groups).reshape(n, groups) * 18, nret, axis=1).astype(np.uint16)
    p = encode_packets(model, azimuth_cdeg=az, distance=distance, reflectivity=reflectivity, return_mode=mode,
                       timestamp_ns=np.full(n, T0) + np.arange(n) * 10**6)
    dec = HesaiDecoder(model=model)
    (f,) = dec.push(PacketBatch.from_payloads(p, np.zeros(n, np.int64))) + dec.finish()
    return f


def test_xt32_firing_times_are_the_manuals():
    xt32 = model_named("PandarXT32")
    d = np.ones((1, 8, 32), np.uint16)
    single = _frame(xt32, 0x37, d, d.astype(np.uint8))
    # block b fires 50 µs·(7 − b) before the last, which starts 5.632 µs after the packet time; laser 0 +0.368 µs
    want = [T0 + 5632 + 368 - 50000 * (7 - b) for b in range(8)]
    assert single.column_timestamp_ns.tolist() == want
    assert single.pixel_time_offset_ns[:, 0].tolist() == [1512 * c for c in range(32)]
    dual = _frame(xt32, 0x39, d, d.astype(np.uint8))  # a firing's two returns are one firing
    assert dual.column_timestamp_ns.tolist() == [T0 + 5632 + 368 - 50000 * (3 - k) for k in range(4)]


def test_qt64_laser_56_fires_between_its_neighbours():
    # nebula's table has 12960 here; the manual's table climbs steadily: 127 540, 129 600, 132 050
    assert QT64_CHANNEL_NS[54:57] == (127540, 129600, 132050)
    assert np.all(np.diff(np.array(QT64_CHANNEL_NS)) > 0)


@pytest.mark.parametrize("model", MODELS, ids=[m.name for m in MODELS])
def test_every_model_has_a_firing_time_for_every_pixel(model):
    for n in model.returns:
        flags = np.array([0, 1], np.uint8)
        off = firing_offsets_ns(model, n, flags)
        assert off.shape[1:] == (model.blocks // n, model.channels)
        assert np.all(np.abs(off) < 1_000_000)  # within a packet's millisecond


def test_labels_and_the_xt_first_last_swap():
    assert model_named("PandarXT32").labels(0x3B) == ("last", "first")  # the XT sends the last return first
    assert model_named("PandarXT16").labels(0x3B) == ("last", "first")
    assert model_named("PandarQT64").labels(0x3B) == ("first", "last")
    assert model_named("PandarXT32M").labels(0x3D) == ("first", "last", "strongest")
    assert model_named("PandarQT128").labels(0x39) == ("last", "strongest")


def test_dual_mark_rule_second_strongest_where_the_first_slot_is_stronger():
    xt32 = model_named("PandarXT32")
    d = np.zeros((1, 8, 32), np.uint16)
    r = np.zeros((1, 8, 32), np.uint8)
    # firing 0: last 10 m refl 200, second block 5 m refl 50 → the last was the strongest: slot 1 is second strongest
    d[0, 0, 0], r[0, 0, 0], d[0, 1, 0], r[0, 1, 0] = 2500, 200, 1250, 50
    # firing 0, laser 1: last 10 m refl 20, strongest 5 m refl 90 → not marked
    d[0, 0, 1], r[0, 0, 1], d[0, 1, 1], r[0, 1, 1] = 2500, 20, 1250, 90
    # laser 2: one echo, sent in both blocks → not marked
    d[0, 0, 2], r[0, 0, 2], d[0, 1, 2], r[0, 1, 2] = 2500, 70, 2500, 70
    f = _frame(xt32, 0x39, d, r)
    mark = f.extra["second_strongest"]
    assert mark[:3, 0].tolist() == [True, False, False] and not mark[3:].any()
    assert f.return_labels == ("last", "strongest") and f.range_mm[:, 0, 0].tolist() == [10000, 5000]
    assert "second_strongest" not in _frame(xt32, 0x3B, d, r).extra  # First+Last has no such rule


def test_calibration_csv(tmp_path):
    cal = parse_calibration("Channel,Elevation,Azimuth\n1,15,0.5\n2,-1.5,-0.25\n", "x.csv")
    assert cal.elevation_deg.tolist() == [15.0, -1.5] and cal.azimuth_offset_deg.tolist() == [0.5, -0.25]
    for bad, why in (("Laser id,Elevation,Azimuth\n1,a,0\n", "line 2"), ("Laser id,Elevation,Azimuth\n2,1,0\n", "1..1"),
                     ("", "no channel"), ("1,95,0\n", "out of range")):
        with pytest.raises(CalibrationError, match=why):
            parse_calibration(bad, "bad.csv")
    with pytest.raises(CalibrationError, match="cannot read"):
        load_calibration(tmp_path / "missing.csv")
    path = tmp_path / "two.csv"
    path.write_text("Channel,Elevation,Azimuth\n1,15,0\n2,-15,0\n")
    with pytest.raises(CalibrationError, match="2 channels for a PandarXT32"):
        HesaiDecoder(model="PandarXT32", calibration=path)


def test_xyz_is_nebulas_frame():
    xt16 = model_named("PandarXT16")
    cal = parse_calibration("Channel,Elevation,Azimuth\n" + "".join(f"{c + 1},{15 - 2 * c},1.0\n" for c in range(16)))
    d = np.zeros((1, 8, 16), np.uint16)
    d[0, 0, 0] = 2500  # 10 m, elevation 15°, azimuth 90° − 1° + 1° (the offset)
    az = np.full((1, 8), 8900, np.uint16)
    p = encode_packets(xt16, azimuth_cdeg=az, distance=d, reflectivity=d.astype(np.uint8), return_mode=0x37,
                       timestamp_ns=np.array([T0]))
    dec = HesaiDecoder(calibration=cal)
    (f,) = dec.push(PacketBatch.from_payloads(p, np.zeros(1, np.int64))) + dec.finish()
    x, y, z = f.xyz()[0, 0, 0]
    el = np.radians(15)
    assert (x, y, z) == pytest.approx((10 * np.cos(el), 0.0, 10 * np.sin(el)), abs=1e-9)  # az 90°: +x


def test_the_decoder_is_a_decoder_and_names_its_sensor():
    from lidarpkt.core.decoder import Decoder
    from lidarpkt.errors import UnknownSensorError

    assert isinstance(HesaiDecoder(), Decoder)
    with pytest.raises(UnknownSensorError, match="no packet yet"):
        HesaiDecoder().sensor_info()
    info = HesaiDecoder(model="XT32M").sensor_info("first_last_strongest")
    assert (info.vendor, info.model, info.return_labels, info.rows) == ("hesai", "PandarXT32M",
                                                                        ("first", "last", "strongest"), 32)
