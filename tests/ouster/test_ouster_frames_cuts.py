"""Ouster frame assembly, counted exactly (issue 19: the survivors of a mutation run over ouster/frames.py).

The packets are the real ones of ouster-sdk's OS-0-32 dual-return capture (64 packets of 16
columns, one frame, id 1453), re-sent in pieces, repeated, delayed, re-labelled or damaged through
the encoder. Each counter is derived from what was sent, written out beside the assertion. The
tests that depend on how a frame is assembled run twice: with the compiled scatter and with its
NumPy twin (``kernels.native`` set to ``None``).
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest

from conftest import under_mutmut

from lidarpkt.core import kernels
from lidarpkt.errors import SensorMismatchError, SkippedPacketWarning
from lidarpkt.vendors.ouster import OusterDecoder, decode_packets, encode_packets, load_metadata
from lidarpkt.vendors.ouster.imu import decode_imu
from lidarpkt.core.imu import ImuSamples
from lidarpkt.core.packet import PacketBatch
from test_ouster_cases import all_packets_of_size, lidar_streams

DUAL = ("ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.pcap", ["ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.json"])
LEGACY = ("ouster-sdk/OS-1-64_1024x10_fw20.pcap", ["ouster-sdk/OS-1-64_sensor_config_reduced.json"])



@pytest.fixture(params=["native", "numpy"])
def assembly(request, monkeypatch):
    """Both frame assembly paths: the compiled scatter (when built) and the NumPy twin."""
    if request.param == "numpy":
        monkeypatch.setattr(kernels, "native", None)
    return request.param


def dual():
    md, batch = lidar_streams(*DUAL)[0]
    return md, batch.payload


def relabel(md, payload, **header):
    fields = decode_packets(payload, md)
    for name, value in header.items():
        fields.header[name][:] = value
    return encode_packets(fields, md)


def with_measurement_id(md, payload, mid: int):
    """The packets with their column 3 claiming measurement id ``mid``."""
    fields = decode_packets(payload, md)
    fields.measurement_id[:, 3] = mid
    return encode_packets(fields, md)


def push_all(md, payload, **options):
    dec = OusterDecoder(md, source="test", **options)
    return dec.push(PacketBatch.from_payloads(payload)) + dec.finish(), dec


# ------------------------------------------------------------------ counters
def test_every_counter_adds_up_over_batches(assembly):
    md, p = dual()
    junk = np.zeros((3, 12608), np.uint8)
    other_init = relabel(md, p[[10, 11, 30]], init_id=md.init_id + 1)
    bad_mid = with_measurement_id(md, p[[20, 30]], md.columns_per_frame)  # 1024: one past the last column
    batches = [
        p[0:10],
        junk,  # 3 of the wrong size while frame 1453 is open
        other_init[:2],  # 2 of another init_id
        p[10:20],
        junk[:1],
        np.concatenate([bad_mid[:1], p[20:30]]),
        np.concatenate([bad_mid[1:], other_init[2:], p[30:40]]),
        p[[40, 41, 41, 42]],  # 41 twice in a row: a duplicate, not out of order
        p[[45]],
        p[[43]],  # lower than 45: out of order
        p[[44, 46, 47]],
        p[[41]],  # again, alone: a duplicate and out of order (lower than 47)
        p[[45, 48]],  # 45 again, in order after 41: a duplicate
        p[49:64],  # the frame is complete: released
        p[[5]],  # late, while no frame is open
        p[[6]],  # late
        relabel(md, p[0:4], frame_id=1454),  # frame 1454: columns 0-63 ...
        relabel(md, p[8:10], frame_id=1454),  # ... and 128-159: packets 4-7 lost
        relabel(md, p[0:2], frame_id=1455),  # frame 1455 ends 1454
    ]
    dec = OusterDecoder(md, source="test")
    frames = []
    with pytest.warns(SkippedPacketWarning):
        for b in batches:
            frames += dec.push(PacketBatch.from_payloads(b))
    frames += dec.finish()
    assert [(f.frame_id, f.partial) for f in frames] == [(1453, False), (1454, True), (1455, True)]
    st = dec.stats
    assert st.packets == sum(len(b) for b in batches) == 86
    assert st.accepted == 64 + 6 + 2
    assert (st.size_mismatch, st.id_mismatch, st.bad_measurement_id) == (4, 3, 2)
    assert (st.duplicates, st.out_of_order, st.late) == (3, 2, 2)
    assert (st.lost_packets, st.frames, st.partial_frames) == (4, 3, 2)
    full, holed, last = (f.counters for f in frames)
    assert full.malformed_packets == 3 + 2 + 1 + 1 + 2
    assert (full.duplicate_packets, full.out_of_order_packets, full.lost_packets, full.late_packets) == (3, 2, 0, 0)
    assert (holed.late_packets, holed.lost_packets, holed.malformed_packets) == (2, 4, 0)
    assert last.lost_packets == 0  # columns missing after the last one received: the edge, not a loss
    assert np.flatnonzero(frames[1].column_valid).tolist() == [*range(64), *range(128, 160)]
    # the frame put together from the pieces is the frame of the capture in one batch
    (reference,), _ = push_all(md, p)
    for attr in ("range_mm", "reflectivity", "signal", "flags", "near_ir", "column_timestamp_ns", "status"):
        assert np.array_equal(getattr(frames[0], attr), getattr(reference, attr)), attr


def test_a_packet_of_another_serial_is_skipped(assembly):
    md, p = dual()
    payload = p.copy()
    payload[20:24] = relabel(md, p[20:24], prod_sn=md.serial_int + 1)
    for soft in (False, True):  # soft_id_check forgives the init_id, never the serial
        (f,), dec = push_all(md, payload, soft_id_check=soft)
        assert dec.stats.id_mismatch == 4 and dec.stats.accepted == 60
        assert f.partial and f.counters.lost_packets == 4 and f.counters.malformed_packets == 4
        assert np.flatnonzero(~f.column_valid).tolist() == list(range(320, 384))


def test_column_status_decides_validity(assembly):
    """Non-legacy column status: bit 0 says valid. Columns 83 (status 0) and 96 (status 2) arrived
    but are not valid; the frame is still complete."""
    md, p = dual()
    fields = decode_packets(p, md)
    fields.status[5, 3] = 0
    fields.status[6, 0] = 2
    (f,), _ = push_all(md, encode_packets(fields, md))
    assert not f.partial and f.counters.lost_packets == 0
    assert np.flatnonzero(~f.column_valid).tolist() == [83, 96]
    assert (f.status[83], f.status[96], f.status[84]) == (0, 2, 1)


def test_frame_fields_keep_their_documented_types(assembly):
    md, p = dual()
    (f,), dec = push_all(md, p)
    fields = decode_packets(p, md)
    h = md.pixels_per_column
    window = fields.pixels["WINDOW"].reshape(-1, h).T  # [H, W], measurement ids in order
    assert f.extra["window"].dtype == np.uint8 and np.array_equal(f.extra["window"], window)
    assert f.column_timestamp_ns.dtype == np.int64
    assert np.array_equal(f.column_timestamp_ns, fields.timestamp_ns.ravel().astype(np.int64))
    assert f.measurement_id.dtype == np.uint16 and np.array_equal(f.measurement_id, np.arange(1024))
    assert f.status.dtype == np.uint32 and f.encoder_count is None
    assert isinstance(dec.imu_samples(), ImuSamples) and len(dec.imu_samples()) == 0
    md, batch = lidar_streams(*LEGACY)[0]
    (f,), _ = push_all(md, batch.payload)
    assert "window" not in f.extra  # LEGACY has no WINDOW field
    assert f.encoder_count.dtype == np.uint32 and np.array_equal(f.encoder_count, 88 * np.arange(1024))
    assert f.column_timestamp_ns.dtype == np.int64 and f.measurement_id.dtype == np.uint16


# ------------------------------------------------------------------ which frame a packet belongs to
def test_the_last_16_released_frames_are_remembered(assembly):
    """Frames 1-18, one packet each: when frame 1 comes back, only frames 3-18 are remembered (16):
    it starts a new frame; a packet of frame 3 is late. (Frame 1 comes back with two packets: a jump
    of 1.7 s back is a restart only when the packet after it agrees, lidarpkt.core.continuity.)"""
    md, p = dual()
    dec = OusterDecoder(md)
    frames = []
    for fid, n in [*((f, 1) for f in range(1, 19)), (1, 2), (3, 1)]:
        frames += dec.push(PacketBatch.from_payloads(relabel(md, p[:n], frame_id=fid)))
    frames += dec.finish()
    assert [f.frame_id for f in frames] == [*range(1, 19), 1]
    assert dec.stats.late == 1 and frames[-1].counters.late_packets == 1
    assert dec.stats.restarts == 1 and dec.stats.corrupted == 0


@pytest.mark.parametrize("missing,lost", [(992, 0), (1008, 1), (0, 1), (16, 0)])
def test_column_window_through_zero_counts_only_inner_holes(missing, lost, assembly):
    """Window 992-31, in window order the packets at 992, 1008, 0, 16: a missing packet at either
    end is the edge of the frame, one between them a lost packet."""
    md, p = dual()
    raw = copy.deepcopy(md.raw)
    raw["data_format"]["column_window"] = [992, 31]
    wmd = load_metadata(raw)
    mids = decode_packets(p, md).measurement_id[:, 0]
    pick = np.flatnonzero(((mids >= 992) | (mids < 32)) & (mids != missing))
    (f,), dec = push_all(wmd, p[pick])
    assert f.partial and f.counters.lost_packets == lost == dec.stats.lost_packets
    assert int(f.column_valid.sum()) == 48


# ------------------------------------------------------------------ IMU
def test_imu_keeps_the_newest_100000_samples_by_default():
    md, _ = dual()
    imu = all_packets_of_size(DUAL[0], 48)
    assert len(imu) == 10
    n = 100_001
    tiled = np.tile(imu, (n // len(imu) + 1, 1))[:n]
    dec = OusterDecoder(md)
    dec.push_auxiliary(PacketBatch.from_payloads(tiled))
    kept = dec.imu_samples()
    assert len(kept) == 100_000 and dec.stats.imu_dropped == 1 and dec.stats.imu_packets == n
    raw = decode_imu(tiled[1:])  # the oldest one went
    assert np.array_equal(kept.extra["sys_timestamp_ns"], raw["sys_timestamp_ns"].astype(np.int64))
    assert np.array_equal(kept.acceleration_mps2[:, 2], raw["accel_z_g"].astype(np.float64) * 9.80665)
    for k in (2, 3):
        dec.push_imu(PacketBatch.from_payloads(np.zeros((k, 50), np.uint8)))
    assert dec.stats.size_mismatch == 5


# ------------------------------------------------------------------ what the user reads
def test_messages_name_the_source_and_the_metadata():
    md, _ = dual()
    with pytest.raises(TypeError, match=r"^OusterDecoder: unknown options \['bogus'\]$"):
        OusterDecoder(md, bogus=1)
    junk = PacketBatch.from_payloads(np.zeros((3, 12608), np.uint8))
    dec = OusterDecoder(md, source="10.0.0.2:7502")
    with pytest.warns(SkippedPacketWarning) as caught:
        dec.push(junk)
    (w,) = caught
    assert str(w.message) == (f"Ouster 10.0.0.2:7502: skipped 3 packets of 12608 B; the metadata "
                              f"({md.profile.name}, 32 px) expects 8448 B")
    assert under_mutmut() or w.filename == __file__  # the caller's line
    with pytest.raises(SensorMismatchError) as err:
        dec.finish()
    text = str(err.value)
    assert text.startswith(f"Ouster 10.0.0.2:7502: none of 3 lidar packets matches the metadata {md.path} (")
    assert md.path.endswith("OS-0-32-U1_v2.2.0_1024x10.json")
    assert text.endswith("3 of the wrong size, 0 with another init_id/serial. Pass this sensor's metadata JSON.")
    dec = OusterDecoder(md)
    with pytest.warns(SkippedPacketWarning, match=r"^Ouster stream: skipped 3 packets of 12608 B; "):
        dec.push(junk)
    with pytest.raises(SensorMismatchError, match=r"^Ouster stream: none of 3 lidar packets"):
        dec.finish()
    # metadata given as a dict (or read from a bag) has no path: no gap is left in the message
    md_dict = load_metadata(json.loads(Path(md.path).read_text()))
    assert not md_dict.path
    dec = OusterDecoder(md_dict)
    with pytest.warns(SkippedPacketWarning):
        dec.push(junk)
    with pytest.raises(SensorMismatchError,
                       match=r"^Ouster stream: none of 3 lidar packets matches the metadata given \("):
        dec.finish()
