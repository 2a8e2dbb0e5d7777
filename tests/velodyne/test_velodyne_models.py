"""The Velodyne model table against the manual's numbers (../shared/REFERENCE.md), the real
captures and velodyne_decoder 3.1.0's own model constants."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import lidarpkt
from lidarpkt.errors import PacketFormatError, UnknownSensorError
from lidarpkt.core.packet import PacketBatch
from lidarpkt.containers.pcap_reader import read_batches
from lidarpkt.vendors.velodyne import VelodyneDecoder, stock_calibration
from lidarpkt.vendors.velodyne.detect import describe_stream
from lidarpkt.vendors.velodyne.models import MODELS, VLP16, model_for_product, model_named


def test_vlp16_row_has_the_manuals_numbers():
    # REFERENCE.md, "Velodyne VLP-16"
    assert VLP16.name == "VLP-16" and VLP16.product_ids == (0x22, 0x21)
    assert VLP16.lasers == 16
    assert VLP16.elevation_deg == (-15, 1, -13, 3, -11, 5, -9, 7, -7, 9, -5, 11, -3, 13, -1, 15)
    assert (VLP16.sequence_ns, VLP16.firing_ns) == (55_296, 2_304)
    assert (VLP16.blocks_per_packet, VLP16.sequences_per_block, VLP16.sequences_per_packet) == (12, 2, 24)
    assert VLP16.columns_per_packet("strongest") == VLP16.columns_per_packet("last") == 24
    assert VLP16.columns_per_packet("dual") == 12
    # "VLP-16 packets come every 12 × 110.592 µs = 1327 µs in single mode"; dual twice as often
    assert VLP16.packet_period_us("strongest") == pytest.approx(12 * 110.592)
    assert VLP16.packet_period_ns("dual") * 2 == VLP16.packet_period_ns("last") == 1_327_104
    assert VLP16.distance_resolution_m == 0.002
    assert VLP16.columns_per_rotation(10) == 1808 and VLP16.columns_per_rotation(None) == 1808


def test_table_lookups():
    assert MODELS[0] is VLP16
    assert model_for_product(0x22) is VLP16 and model_for_product(0x21) is VLP16  # detection tells an HDL-32E
    assert model_for_product(0x28).name == "VLP-32C" and model_for_product(0xA1).name == "VLS-128"
    assert model_for_product(0x24).name == "Puck Hi-Res"
    assert model_for_product(0x23) is None  # VLP-32A or B: the option picks one
    assert model_for_product(0x99) is None
    assert model_named("VLP-16") is VLP16 and model_named("vls128").name == "VLS-128"
    with pytest.raises(UnknownSensorError, match="VLP-64X"):
        model_named("VLP-64X")


def test_a_row_that_does_not_fill_the_packet_is_refused():
    with pytest.raises(PacketFormatError, match="do not fill"):
        dataclasses.replace(VLP16, lasers=32, elevation_deg=tuple(range(32)))  # 32 lasers × 2 sequences
    with pytest.raises(PacketFormatError, match="elevations"):
        dataclasses.replace(VLP16, elevation_deg=(0.0,) * 15)
    with pytest.raises(PacketFormatError, match="exceed"):
        dataclasses.replace(VLP16, firing_ns=4_000)
    with pytest.raises(dataclasses.FrozenInstanceError):
        VLP16.lasers = 32  # type: ignore[misc]


def _data_batch(ext, rel: str) -> PacketBatch:
    return next(b for b in read_batches(ext(rel)) if b.payload_size == 1206)


@pytest.mark.parametrize("rel, product", [("rust-lidar-utils/velodyne_example.pcap", 0x22),
                                          ("veloview/vlp-16-test-90deg-1-50-frames.pcap", 0x21)])
def test_real_captures_have_the_tables_product_ids_and_packet_period(ext, rel, product):
    batch = _data_batch(ext, rel)
    desc = describe_stream(batch)
    assert desc["kind"] == "VLP-16 data" and desc["product_id"] == product
    assert model_for_product(product) is VLP16
    # µs timestamps: the median step is the period rounded to a whole µs
    assert abs(desc["packet_period_us"] - VLP16.packet_period_us("strongest")) <= 1


def test_real_dual_capture_has_the_dual_period(ext):
    frames = list(lidarpkt.open(ext("nebula/vlp16/1673400471837873222")))
    f = frames[1]
    assert f.sensor.model == VLP16.name and f.sensor.rows == VLP16.lasers
    per = VLP16.columns_per_packet("dual")
    packet_ns = f.column_timestamp_ns[f.column_valid][::per]
    steps = np.diff(packet_ns)
    assert np.all(np.abs(steps - VLP16.packet_period_ns("dual")) < 1000)  # the capture's µs stamps


def test_veloview_20hz_capture_gives_the_rotation_width(ext):
    frames = list(lidarpkt.open(ext("veloview/vlp-16-test-90deg-1-50-frames.pcap")))
    sensor = frames[1].sensor
    assert sensor.frequency_hz == pytest.approx(20, abs=0.2)
    assert sensor.columns_per_frame == VLP16.columns_per_rotation(sensor.frequency_hz)
    assert abs(frames[1].shape[2] - sensor.columns_per_frame) <= 2


def test_velodyne_decoder_names_the_model_by_its_product_id(ext):
    vd = pytest.importorskip("velodyne_decoder")
    raw = np.fromfile(ext("einride-vlp16-go/recording.bin"), np.uint8).reshape(-1, 1206)[:20]
    assert set(raw[:, 1205].tolist()) == {VLP16.product_ids[0]}
    cfg = vd.Config()
    cfg.min_range, cfg.max_range = 0.0, 1e4
    packets = vd.PacketVector()
    for i, row in enumerate(raw):
        packets.append(vd.VelodynePacket(1.0 + i * VLP16.packet_period_ns("strongest") * 1e-9, row.tobytes()))
    dec = vd.ScanDecoder(cfg)
    _, points = dec.decode(packets, True)
    assert dec.model_id == vd.Model.VLP16
    # its firing times: laser l fires l × 2.304 µs after laser 0 of its sequence, and the sequences
    # of a packet are 55.296 µs apart (packets start at their µs timestamps)
    laser_of_ring = np.argsort(VLP16.elevation_deg, kind="stable")
    t_ns = points["time"].astype(np.float64) * 1e9
    base = np.sort(t_ns - laser_of_ring[points["ring"]] * VLP16.firing_ns)  # laser 0's firing time
    starts = np.concatenate([[True], np.diff(base) > 20])  # float32 seconds: a few ns of rounding
    groups = np.cumsum(starts) - 1
    first = base[starts]
    assert np.abs(base - first[groups]).max() < 20  # every point of a sequence back at one laser-0 time
    steps = np.diff(first)
    on_grid = np.abs(steps - VLP16.sequence_ns) < 20
    assert steps.size > 300 and on_grid.mean() > 0.9  # the rest: packet boundaries (µs stamps)
    # and its rings are ours: ring = rank of elevation
    ring_elev = np.sort(np.asarray(VLP16.elevation_deg))
    z_sign = np.sign(points["z"][np.abs(points["z"]) > 0.5])
    ring = points["ring"][np.abs(points["z"]) > 0.5]
    assert np.all(z_sign == np.sign(ring_elev[ring]))


def test_velodyne_decoder_stock_calibration_is_the_tables():
    vd = pytest.importorskip("velodyne_decoder")
    from ruamel.yaml import YAML

    doc = YAML(typ="safe", pure=True).load(vd.Calibration.default_calibs[vd.Model.VLP16].to_string())
    lasers = sorted(doc["lasers"], key=lambda e: e["laser_id"])
    assert len(lasers) == VLP16.lasers
    ours = stock_calibration(VLP16)
    np.testing.assert_allclose([e["vert_correction"] for e in lasers], ours.vert_correction_rad, atol=1e-7)
    np.testing.assert_allclose([e.get("vert_offset_correction", 0) for e in lasers], ours.vert_offset_m, atol=1e-7)
    assert doc["distance_resolution"] == pytest.approx(VLP16.distance_resolution_m)


def test_decoder_reads_the_table():
    dec = VelodyneDecoder()
    assert dec.model is VLP16
    info = dec.sensor_info("dual")
    assert (info.model, info.rows, info.grid_resolution_deg) == ("VLP-16", 16, VLP16.grid_resolution_deg)


def test_decoder_takes_a_model_by_row_or_name_and_checks_the_calibration():
    from lidarpkt.errors import CalibrationError
    from lidarpkt.vendors.velodyne import VelodyneCalibration

    assert VelodyneDecoder(model="VLP-16").model is VLP16
    assert VelodyneDecoder(model="VLP-32C").model.lasers == 32
    with pytest.raises(UnknownSensorError, match="VLP-64X"):
        VelodyneDecoder(model="VLP-64X")
    with pytest.raises(CalibrationError, match="32 lasers"):
        VelodyneDecoder(model="VLP-16", calibration=VelodyneCalibration(vert_correction_rad=np.zeros(32)))
