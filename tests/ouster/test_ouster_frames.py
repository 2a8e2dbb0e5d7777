"""Ouster frame assembly on the real captures, and on real packets dropped, repeated, delayed or re-labelled."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

import lidarpkt
from conftest import external
from lidarpkt.errors import SensorMismatchError, SkippedPacketWarning
from lidarpkt.vendors.ouster import (
    OusterDecoder,
    classify,
    decode_packets,
    describe_stream,
    encode_packets,
    load_metadata,
)
from lidarpkt.core.packet import PacketBatch
from lidarpkt.containers.pcap_reader import read_batches
from test_ouster_cases import decode_frames, lidar_streams

DUAL = ("ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.pcap", ["ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.json"])


# ----------------------------------------------------------------------------- real captures


def test_crc_test_one_complete_one_partial_frame():
    frames, decoders = decode_frames("ouster-sdk/crc_test.pcap", ["ouster-sdk/crc_test.json"])
    (dec,) = decoders.values()
    assert [(f.frame_id, f.partial) for f in frames] == [(254, False), (255, True)]
    assert dec.stats.packets == 34 and dec.stats.crc_failures == 0 and dec.stats.accepted == 34
    full, part = frames
    assert full.shape == (1, 128, 512) and full.column_valid.all()
    assert np.array_equal(full.measurement_id, np.arange(512))
    assert part.column_valid.sum() == 32 and np.array_equal(np.flatnonzero(part.column_valid), np.arange(32))
    assert full.return_labels == ("strongest",) and full.signal is None
    assert full.sensor.grid_resolution_deg == 360 / 512
    assert dec.stats.imu_packets == 10 and len(dec.imu_samples()) == 10


def test_duplicate_id_exactly_one_frame_1778():
    """The orphan first fragment with a reused IP id must not be merged into the real datagram."""
    frames, decoders = decode_frames("ouster-sdk/duplicate_id.pcap", ["ouster-sdk/duplicate_id.json"])
    assert [f.frame_id for f in frames] == [1778]
    (f,) = frames
    assert f.partial
    assert np.array_equal(np.flatnonzero(f.column_valid), np.arange(432, 448))
    assert sum(d.stats.packets for d in decoders.values()) == 1


def test_empty_pcap_no_frames_no_error():
    frames, decoders = decode_frames("ouster-sdk/empty_pcap.pcap", ["ouster-sdk/empty_pcap.json"])
    assert frames == [] and decoders == {}
    assert list(lidarpkt.open(external("ouster-sdk/empty_pcap.pcap"), metadata=external("ouster-sdk/empty_pcap.json"))) == []


@pytest.mark.parametrize(
    "pcap,jsons,expected",
    [
        (
            "ouster-sdk/same_ports_legacy.pcap",
            ["ouster-sdk/same_ports_legacy.1.json", "ouster-sdk/same_ports_legacy.2.json"],
            {("169.254.92.158", 457, 128, 1, "LEGACY"), ("169.254.238.111", 185, 64, 1, "LEGACY")},
        ),
        (
            "ouster-sdk/same_ports_nonlegacy.pcap",
            ["ouster-sdk/same_ports_nonlegacy.1.json", "ouster-sdk/same_ports_nonlegacy.2.json"],
            {
                ("169.254.92.158", 1093, 128, 2, "FUSA_RNG15_RFL8_NIR8_DUAL"),
                ("169.254.238.111", 1535, 64, 2, "RNG19_RFL8_SIG16_NIR16_DUAL"),
            },
        ),
    ],
)
def test_same_ports_each_sensor_with_its_own_metadata(pcap, jsons, expected):
    frames, _ = decode_frames(pcap, jsons)
    got = {(f.sensor.source.split(":")[0], f.frame_id, f.shape[1], f.shape[0], f.sensor.profile) for f in frames}
    assert got == expected
    # metadata in the other order: same pairing
    frames_rev, _ = decode_frames(pcap, jsons[::-1])
    assert {(f.sensor.source.split(":")[0], f.frame_id, f.sensor.profile) for f in frames_rev} == {e[:2] + e[4:] for e in expected}


def test_ouster_example_partial_complete_partial():
    frames, decoders = decode_frames("rust-lidar-utils/ouster_example.pcap", ["rust-lidar-utils/ouster_example.json"])
    assert [(f.frame_id, f.partial) for f in frames] == [(12072, True), (12073, False), (12074, True)]
    first, full, last = frames
    assert np.array_equal(np.flatnonzero(first.column_valid), np.arange(800, 1024))
    assert np.array_equal(np.flatnonzero(last.column_valid), np.arange(0, 352))
    assert full.column_valid.all()
    assert np.array_equal(full.encoder_count, 88 * np.arange(1024))
    # the edges of the capture are not lost packets
    assert first.counters.lost_packets == 0 and last.counters.lost_packets == 0
    # missing columns are zero everywhere
    gone = ~first.column_valid
    assert not first.range_mm[..., gone].any() and not first.column_timestamp_ns[gone].any()
    assert not first.status[gone].any() and not first.measurement_id[gone].any()
    # reduced metadata defaults: OS1-64 gen 1 stagger
    assert first.sensor.pixel_shift_by_row[:8].tolist() == [18, 12, 6, 0, 18, 12, 6, 0]


def test_lidarpkt_open_routes_ouster_captures():
    frames = list(lidarpkt.open(external("ouster-sdk/crc_test.pcap"), metadata=external("ouster-sdk/crc_test.json")))
    assert [(f.frame_id, f.partial) for f in frames] == [(254, False), (255, True)]
    frames = list(
        lidarpkt.open(
            external("ouster-sdk/same_ports_nonlegacy.pcap"),
            metadata=[external("ouster-sdk/same_ports_nonlegacy.1.json"), external("ouster-sdk/same_ports_nonlegacy.2.json")],
        )
    )
    assert sorted(f.frame_id for f in frames) == [1093, 1535]


def test_azimuth_and_destagger_conventions():
    frames, _ = decode_frames(*DUAL)
    f = frames[0]
    w = f.shape[2]
    assert f.azimuth_deg[0] == 0.0 and f.azimuth_deg[w // 4] == 270.0 and f.azimuth_deg[w // 2] == 180.0
    assert np.all((f.azimuth_deg >= 0) & (f.azimuth_deg < 360))
    img = f.range_mm[0]
    d = f.destaggered(img)
    shift = f.sensor.pixel_shift_by_row
    for u in (0, 5, 31):
        assert np.array_equal(d[u], np.roll(img[u], shift[u]))


# ----------------------------------------------------------------------------- real packets, perturbed


def _dual():
    md, batch = lidar_streams(*DUAL)[0]
    return md, batch


def _push(md, payload, *, per_packet=False, **options):
    dec = OusterDecoder(md, source="test", **options)
    frames = []
    batch = PacketBatch.from_payloads(payload)
    if per_packet:
        for i in range(len(batch)):
            frames += dec.push(batch.select(slice(i, i + 1)))
    else:
        frames += dec.push(batch)
    frames += dec.finish()
    return frames, dec


def _same_frame(a, b, columns=slice(None)):
    for attr in ("range_mm", "reflectivity", "signal", "flags"):
        assert np.array_equal(getattr(a, attr)[..., columns], getattr(b, attr)[..., columns]), attr
    assert np.array_equal(a.near_ir[..., columns], b.near_ir[..., columns])
    assert np.array_equal(a.column_timestamp_ns[columns], b.column_timestamp_ns[columns])
    assert np.array_equal(a.status[columns], b.status[columns])


def test_batch_boundaries_do_not_matter():
    md, batch = _dual()
    (whole,), _ = _push(md, batch.payload)
    (split,), dec = _push(md, batch.payload, per_packet=True)
    assert not whole.partial and not split.partial
    _same_frame(whole, split)
    assert dec.stats.accepted == 64


def test_lost_packets_leave_invalid_zero_columns_and_are_counted():
    md, batch = _dual()
    (ref,), _ = _push(md, batch.payload)
    keep = np.setdiff1d(np.arange(64), [10, 11, 40])
    (f,), dec = _push(md, batch.payload[keep])
    assert f.partial and f.counters.lost_packets == 3 and dec.stats.lost_packets == 3
    gone = np.zeros(1024, bool)
    for p in (10, 11, 40):
        gone[16 * p : 16 * p + 16] = True
    assert np.array_equal(~f.column_valid, gone)
    assert not f.range_mm[..., gone].any() and not f.column_timestamp_ns[gone].any()
    assert not f.status[gone].any() and not f.measurement_id[gone].any()
    _same_frame(ref, f, ~gone)


def test_duplicates_counted_and_dropped():
    md, batch = _dual()
    (ref,), _ = _push(md, batch.payload)
    order = np.r_[0:7, 5, 7:64]
    (f,), dec = _push(md, batch.payload[order])
    assert f.counters.duplicate_packets == 1 and dec.stats.duplicates == 1
    assert f.counters.out_of_order_packets == 1
    assert not f.partial
    _same_frame(ref, f)


def _relabel(md, payload, frame_id=None, init_id=None):
    fields = decode_packets(payload, md)
    if frame_id is not None:
        fields.header["frame_id"][:] = frame_id
    if init_id is not None:
        fields.header["init_id"][:] = init_id
    return encode_packets(fields, md)


def test_late_packets_of_a_released_frame_are_dropped_and_counted():
    md, batch = _dual()
    nxt = _relabel(md, batch.payload[:8], frame_id=1454)
    stream = np.concatenate([batch.payload, nxt[:4], batch.payload[20:21], nxt[4:]])
    frames, dec = _push(md, stream)
    assert [(f.frame_id, f.partial) for f in frames] == [(1453, False), (1454, True)]
    assert dec.stats.late == 1 and frames[1].counters.late_packets == 1
    assert frames[1].column_valid.sum() == 8 * 16


def test_init_id_change_ends_the_frame():
    md, batch = _dual()
    other = _relabel(md, batch.payload[32:], init_id=md.init_id + 1)
    frames, dec = _push(md, np.concatenate([batch.payload[:32], other]), soft_id_check=True)
    assert [(f.frame_id, f.partial, int(f.column_valid.sum())) for f in frames] == [(1453, True, 512), (1453, True, 512)]
    # without soft_id_check the packets of another init_id are skipped and counted
    frames, dec = _push(md, np.concatenate([batch.payload[:32], other]))
    assert len(frames) == 1 and dec.stats.id_mismatch == 32 and frames[0].counters.malformed_packets == 32


def test_column_window_wrapping_through_zero():
    md, batch = _dual()
    raw = copy.deepcopy(md.raw)
    raw["data_format"]["column_window"] = [992, 31]
    wmd = load_metadata(raw)
    assert wmd.window_mask.sum() == 64
    mids = decode_packets(batch.payload, md).measurement_id[:, 0]
    pick = np.flatnonzero((mids >= 992) | (mids < 32))
    frames, dec = _push(wmd, batch.payload[pick])
    assert len(frames) == 1 and not frames[0].partial
    assert frames[0].column_valid.sum() == 64
    # window order 992, 1008, 0, 16 (capture order 0, 16, 992, 1008). The packet at 0 missing: it sits
    # between the first and the last across the wrap, so the frame is partial and one packet is lost
    assert mids[pick].tolist() == [0, 16, 992, 1008]
    frames, dec = _push(wmd, batch.payload[np.delete(pick, 0)])
    assert len(frames) == 1 and frames[0].partial
    assert frames[0].counters.lost_packets == 1 == dec.stats.lost_packets
    assert frames[0].column_valid.sum() == 48 and not frames[0].column_valid[:16].any()
    # the window's last packet (16) missing: partial, but nothing after it shows a packet was lost
    frames, dec = _push(wmd, batch.payload[np.delete(pick, 1)])
    assert frames[0].partial and frames[0].counters.lost_packets == 0 and not frames[0].column_valid[16:32].any()


def test_crc_failure_skipped_and_counted():
    md, batch = lidar_streams("ouster-sdk/crc_test.pcap", ["ouster-sdk/crc_test.json"])[0]
    bad = batch.payload.copy()
    bad[5, 2000] ^= 0xFF
    frames, dec = _push(md, bad)
    assert dec.stats.crc_failures == 1
    assert frames[0].partial and frames[0].counters.lost_packets == 1
    assert frames[0].counters.malformed_packets == 1
    frames, dec = _push(md, bad, verify_crc=False)
    assert dec.stats.crc_failures == 0 and not frames[0].partial


def test_wrong_metadata_is_reported_not_decoded():
    """An 8448-byte low-data-rate stream given the 32-channel dual metadata (same packet size)."""
    md_dual = load_metadata(external(DUAL[1][0]))
    _, ldr = lidar_streams("ouster-sdk/OS-0-128-U1_v2.3.0_1024x10.pcap", ["ouster-sdk/OS-0-128-U1_v2.3.0_1024x10.json"])[0]
    assert ldr.payload_size == md_dual.packet_size
    assert classify(ldr, [md_dual]) is None
    dec = OusterDecoder(md_dual)
    assert dec.push(ldr) == []
    assert dec.stats.id_mismatch == 64
    with pytest.raises(SensorMismatchError, match="Pass this sensor's metadata"):
        dec.finish()


def test_wrong_size_counted_with_a_warning():
    md, _ = _dual()
    dec = OusterDecoder(md)
    with pytest.warns(SkippedPacketWarning, match="12608 B"):
        assert dec.push(PacketBatch.from_payloads(np.zeros((3, 12608), np.uint8))) == []
    assert dec.stats.size_mismatch == 3
    with pytest.raises(SensorMismatchError):
        dec.finish()


def test_bad_measurement_id_skipped():
    md, batch = _dual()
    fields = decode_packets(batch.payload[:2], md)
    fields.measurement_id[1, 3] = 5000
    frames, dec = _push(md, encode_packets(fields, md))
    assert dec.stats.bad_measurement_id == 1 and frames[0].column_valid.sum() == 16


# ----------------------------------------------------------------------------- classify / describe


def test_classify_and_describe_same_ports_nonlegacy():
    mds = [load_metadata(external(j)) for j in ("ouster-sdk/same_ports_nonlegacy.1.json", "ouster-sdk/same_ports_nonlegacy.2.json")]
    seen = []
    for batch in read_batches(external("ouster-sdk/same_ports_nonlegacy.pcap")):
        kind, md = classify(batch, mds)
        seen.append((batch.src.address, kind, md.serial, md.profile.name if kind == "lidar" else None))
        d = describe_stream(batch, mds)
        if kind == "lidar":
            assert d["profile"] == md.profile.name and d["profile_source"] == "metadata"
            assert d["serial"] == md.serial
        else:
            assert d["kind"] == "Ouster IMU"
    lidar = {(a, s, p) for a, k, s, p in seen if k == "lidar"}
    assert lidar == {
        ("169.254.92.158", "122247000785", "FUSA_RNG15_RFL8_NIR8_DUAL"),
        ("169.254.238.111", "122239000672", "RNG19_RFL8_SIG16_NIR16_DUAL"),
    }


def test_describe_without_metadata_lists_every_layout_of_the_size():
    (batch,) = [b for b in read_batches(external("ouster-sdk/crc_test.pcap")) if b.payload_size == 8448]
    d = describe_stream(batch)
    assert d["kind"] == "Ouster lidar" and d["profile_source"] == "guess"
    assert "RNG15_RFL8_NIR8 (128 px)" in d["candidates"] and "RNG19_RFL8_SIG16_NIR16_DUAL (32 px)" in d["candidates"]
    assert d["crc"] == "valid" and d["frame_id"] == [254, 255] and d["columns"] == 512
    md = load_metadata(external("ouster-sdk/crc_test.json"))
    d = describe_stream(batch, [md])
    assert d["profile"] == "RNG15_RFL8_NIR8" and d["profile_source"] == "metadata" and d["crc_failures"] == 0
    # a Velodyne packet is not an Ouster stream
    (vlp,) = list(read_batches(external("ouster-sdk/VLI-16-one-packet.pcap")))
    assert describe_stream(vlp) is None and classify(vlp, [md]) is None


# ----------------------------------------------------------------------------- frames → packets

from lidarpkt.vendors.ouster import encode_frame  # noqa: E402
from test_ouster_cases import CAPTURES  # noqa: E402

# captures whose packets carry nothing a Frame does not hold (no reserved bits set, zero or CRC
# footer, no alert flags): frame → packets gives the very bytes back
BYTE_EXACT = {"OS-0-32-U1_v2.2.0_1024x10.pcap", "OS-0-32-U1_v2.2.0_1024x10-single-packet.pcap", "OS-1-32-G_v2.1.1_1024x10.pcap", "same_ports_legacy.pcap"}


@pytest.mark.parametrize("pcap,jsons,_", CAPTURES, ids=[c[0].split("/")[-1] for c in CAPTURES])
def test_frame_to_packets_gives_the_sensor_fields_back(pcap, jsons, _):
    frames, decoders = decode_frames(pcap, jsons)
    streams = lidar_streams(pcap, jsons)
    for f in frames:
        md = next(d.metadata for d in decoders.values() if d.sensor is f.sensor)
        (orig,) = [b.payload for m, b in streams if m.profile is md.profile and m.pixels_per_column == md.pixels_per_column]
        orig = orig[decode_packets(orig, md).frame_id == f.frame_id]
        mine = encode_frame(f, md)
        assert mine.shape == orig.shape
        a, b = decode_packets(mine, md), decode_packets(orig, md)
        for name in md.profile.field_names:
            assert np.array_equal(a.pixels[name], b.pixels[name]), name
        for attr in ("status", "column_frame_id", "encoder_count"):
            assert np.array_equal(getattr(a, attr), getattr(b, attr)), attr
        # a column whose status says invalid keeps no timestamp (as in ouster-sdk): the windowed captures send
        # such columns around their azimuth window
        valid = b.column_valid
        for attr in ("timestamp_ns", "measurement_id"):
            assert np.array_equal(getattr(a, attr)[valid], getattr(b, attr)[valid]), attr
            assert not getattr(a, attr)[~valid].any() or attr == "measurement_id", attr
        for key in ("frame_id", "init_id", "prod_sn", "packet_type"):
            if key in b.header:
                assert np.array_equal(a.header[key], b.header[key]), key
        if md.footer_kind == "crc":
            assert a.crc_ok.all()
        if pcap.split("/")[-1] in BYTE_EXACT:
            assert np.array_equal(mine, orig)


# ----------------------------------------------------------------------------- bad input

from hypothesis import given, settings, strategies as st  # noqa: E402

from lidarpkt.errors import LidarpktError  # noqa: E402

_MDS = {
    "legacy": ("rust-lidar-utils/ouster_example.pcap", ["rust-lidar-utils/ouster_example.json"]),
    "crc": ("ouster-sdk/crc_test.pcap", ["ouster-sdk/crc_test.json"]),
    "dual": DUAL,
}


@settings(max_examples=30, deadline=None)
@given(
    st.sampled_from(sorted(_MDS)),
    st.lists(st.tuples(st.integers(0, 63), st.integers(0, 2**31), st.integers(0, 255)), max_size=40),
    st.lists(st.integers(0, 63), min_size=1, max_size=80),
)
def test_damaged_and_shuffled_real_packets_never_crash(which, flips, order):
    """Real packets with random bytes overwritten, in random order with repeats: frames of the
    right shape come out, every packet is accounted for, and nothing but lidarpkt errors is raised."""
    md, batch = lidar_streams(*_MDS[which])[0]
    n = len(batch)
    payload = batch.payload[[i % n for i in order]].copy()
    for row, pos, value in flips:
        payload[row % len(payload), pos % payload.shape[1]] = value
    dec = OusterDecoder(md)
    frames = []
    try:
        for i in range(0, len(payload), 7):
            frames += dec.push(PacketBatch.from_payloads(payload[i : i + 7]))
        frames += dec.finish()
    except LidarpktError:
        return
    s = dec.stats
    assert s.packets == len(payload)
    assert (s.accepted + s.crc_failures + s.id_mismatch + s.bad_measurement_id + s.late + s.duplicates
            + s.corrupted) == s.packets
    for f in frames:
        assert f.range_mm.shape == (md.profile.returns, md.pixels_per_column, md.columns_per_frame)
        assert f.column_valid.shape == (md.columns_per_frame,)
        assert f.frame_id in set(decode_packets(payload, md, verify_crc=False).frame_id.tolist())


@pytest.mark.parametrize("pcap,jsons,_", [c for c in CAPTURES if "empty" not in c[0]], ids=lambda x: x.split("/")[-1] if isinstance(x, str) else None)
def test_guess_without_metadata_ranks_the_true_layout_first(pcap, jsons, _):
    """``info`` without metadata: the top guess is the profile and channel count the metadata says."""
    for md, batch in lidar_streams(pcap, jsons):
        d = describe_stream(batch)
        assert d is not None and d["profile_source"] == "guess"
        assert (d["profile"], d["pixels_per_column"]) == (md.profile.name, md.pixels_per_column)


def test_48_byte_junk_is_not_an_ouster_imu():
    md = load_metadata(external("ouster-sdk/crc_test.json"))
    junk = PacketBatch.from_payloads(np.full((3, 48), 0x7F, np.uint8))  # accelerations ~3e38 g
    assert classify(junk, [md]) is None and describe_stream(junk) is None
    (imu,) = [b for b in read_batches(external("ouster-sdk/crc_test.pcap")) if b.payload_size == 48]
    assert classify(imu, [md]) == ("imu", md)


@pytest.mark.parametrize(
    "profile,rows,mode",
    [("LEGACY", 16, "512x10"), ("LEGACY", 128, "2048x10"), ("RNG19_RFL8_SIG16_NIR16", 16, "2048x10"), ("RNG19_RFL8_SIG16_NIR16_DUAL", 128, "512x20"), ("RNG15_RFL8_NIR8", 32, "1024x20")],
)
def test_layouts_without_a_real_capture(profile, rows, mode):
    """Channel counts and modes no external capture has: every pixel lands at (row, measurement id)."""
    from lidarpkt.vendors.ouster import empty_fields

    doc = {
        "beam_altitude_angles": np.linspace(20, -20, rows).tolist(),
        "beam_azimuth_angles": [0.0] * rows,
        "lidar_mode": mode,
        "data_format": {"pixels_per_column": rows, "columns_per_packet": 16, "udp_profile_lidar": profile},
        "prod_sn": "992100000001",
        "initialization_id": 77,
        "build_rev": "v2.5.0",
    }
    md = load_metadata(doc)
    w = md.columns_per_frame
    n = w // 16
    f = empty_fields(md, n)
    mid = np.arange(w).reshape(n, 16)
    f.measurement_id[:] = mid
    f.timestamp_ns[:] = 10**15 + mid * 1000
    f.status[:] = 0xFFFFFFFF if md.profile.legacy else 1
    if md.profile.legacy:
        f.column_frame_id[:] = 9
    else:
        f.header["frame_id"][:] = 9
    u = np.arange(rows)[None, None, :]
    f.pixels["RANGE"][:] = 8 * ((mid[..., None] * rows + u) % 2**15)  # fits every profile's RANGE, 8 mm steps
    f.pixels["REFLECTIVITY"][:] = (u + mid[..., None]) % 256
    payload = encode_packets(f, md)
    assert payload.shape == (n, md.packet_size)
    frames, dec = _push(md, payload)
    assert len(frames) == 1 and not frames[0].partial and frames[0].frame_id == 9
    fr = frames[0]
    cols = np.arange(w)[None, :]
    rr = np.arange(rows)[:, None]
    assert np.array_equal(fr.range_mm[0], 8 * ((cols * rows + rr) % 2**15))
    assert np.array_equal(fr.reflectivity[0], (rr + cols) % 256)
    assert np.array_equal(fr.column_timestamp_ns, 10**15 + np.arange(w) * 1000)
    if md.footer_kind == "crc" and not md.profile.legacy:
        assert decode_packets(payload, md).crc_ok.all()
