"""Ouster packet decoding against the real captures and the digests published with ouster-sdk."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import external
from lidarpkt.errors import PacketFormatError, SensorMismatchError
from lidarpkt.vendors.ouster import decode_packets, empty_fields, encode_packets, load_metadata
from lidarpkt.vendors.ouster.digest import PacketDigest, compare_digest, frame_digest
from test_ouster_cases import CAPTURES, DIGESTED, IDS, all_packets_of_size, decode_frames, load_digest, lidar_streams


@pytest.mark.parametrize("pcap,jsons,_", CAPTURES, ids=IDS)
def test_round_trip_every_real_packet(pcap, jsons, _):
    """encode(decode(packet)) == packet, footer and CRC included, for every lidar packet."""
    for md, batch in lidar_streams(pcap, jsons):
        fields = decode_packets(batch.payload, md)
        again = encode_packets(fields, md)
        assert again.dtype == np.uint8 and again.shape == batch.payload.shape
        assert np.array_equal(again, batch.payload), f"{pcap}: re-encoded packets differ"


@pytest.mark.parametrize("pcap,jsons,digest", DIGESTED, ids=[c[0].split("/")[-1] for c in DIGESTED])
def test_published_digest_packet_and_frame_parts(pcap, jsons, digest):
    """Every key of the ouster-sdk digest file, recomputed from our decode, bit for bit."""
    md = load_metadata(external(jsons[0]))
    payload = all_packets_of_size(pcap, md.packet_size)
    assert len(payload) == 64
    pd = PacketDigest()
    pd.update(decode_packets(payload, md), raw_payload=payload)
    frames, _ = decode_frames(pcap, jsons)
    expected = load_digest(digest)
    assert compare_digest(expected, pd.hexdigests(), frames) == []
    # the keys the SDK checks are all there (not silently skipped)
    assert set(expected["packet_hash"]) - {"ENCODER_COUNT"} <= set(pd.hexdigests())
    assert set(expected["scans"][0]) - {"ENCODER_COUNT"} <= set(frame_digest(frames[0]))
    # the public path gives the same frames
    import lidarpkt

    opened = list(lidarpkt.open(external(pcap), metadata=external(jsons[0])))
    assert [frame_digest(f) for f in opened] == [frame_digest(f) for f in frames]


def test_digest_detects_a_single_flipped_bit():
    pcap, jsons, digest = DIGESTED[0]
    md = load_metadata(external(jsons[0]))
    payload = all_packets_of_size(pcap, md.packet_size).copy()
    payload[10, md.profile.header_bytes + 12 + 5] ^= 0x01  # one bit of one pixel of packet 10
    pd = PacketDigest()
    pd.update(decode_packets(payload, md), raw_payload=payload)
    problems = compare_digest({"packet_hash": load_digest(digest)["packet_hash"]}, pd.hexdigests(), [])
    assert problems and all(p.startswith("packet ") for p in problems)


def test_manual_facts_legacy_os1_64():
    """Column header and status facts of the legacy OS1-64 capture (SOURCES.md, manual)."""
    md, batch = lidar_streams("rust-lidar-utils/ouster_example.pcap", ["rust-lidar-utils/ouster_example.json"])[0]
    f = decode_packets(batch.payload, md)
    assert batch.payload_size == 12608 == 16 * (16 + 64 * 12 + 4)
    assert np.all(f.status == 0xFFFFFFFF)
    # encoder counts: 90112 per turn over 1024 columns = 88 per measurement id
    assert np.array_equal(f.encoder_count, 88 * f.measurement_id.astype(np.uint32))
    assert np.all(np.diff(f.measurement_id.astype(int), axis=1) == 1)
    assert sorted(set(f.frame_id.tolist())) == [12072, 12073, 12074]
    assert np.all(f.column_frame_id == f.column_frame_id[:, :1])
    assert f.pixels["RANGE"].max() < 2**20 and f.pixels["FLAGS"].max() < 16
    # this 2019 firmware sets some of the bits the manual reserves (20-27): they are kept apart
    # from RANGE and FLAGS, and the round trip carries them
    assert f.pixels["_reserved_20"].any()
    assert np.array_equal(encode_packets(f, md), batch.payload)


def test_manual_facts_low_data_rate():
    """RNG15_RFL8_NIR8: RANGE comes in 8 mm steps, NEAR_IR in steps of 16 (up-shifts 3 and 4)."""
    md, batch = lidar_streams("ouster-sdk/OS-0-128-U1_v2.3.0_1024x10.pcap", ["ouster-sdk/OS-0-128-U1_v2.3.0_1024x10.json"])[0]
    f = decode_packets(batch.payload, md)
    rng, nir = f.pixels["RANGE"], f.pixels["NEAR_IR"]
    assert rng.dtype == np.uint32 and nir.dtype == np.uint16
    assert np.all(rng % 8 == 0) and rng.max() > 0 and rng.max() <= (2**15 - 1) * 8
    assert np.all(nir % 16 == 0) and nir.max() > 0
    # the raw word agrees with the fields
    word = batch.payload[:, 32 + 12 : 32 + 12 + 4].view("<u4")[:, 0]  # packet n, column 0, pixel 0
    assert np.array_equal(rng[:, 0, 0], (word & 0x7FFF) * 8)
    assert np.array_equal(nir[:, 0, 0], (word >> 24) * 16)
    # header identity is the metadata's
    assert np.all(f.header["init_id"] == md.init_id)
    assert np.all(f.header["prod_sn"] == int(md.serial))
    assert np.all(f.header["packet_type"] == 1)
    assert np.all(f.status == 1)


def test_manual_facts_dual_profile():
    md, batch = lidar_streams("ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.pcap", ["ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.json"])[0]
    f = decode_packets(batch.payload, md)
    assert batch.payload_size == 8448 == 32 + 16 * (12 + 32 * 16) + 32
    assert np.all(f.footer == 0)  # firmware 2.2: zero footer
    assert f.crc_ok is None and md.footer_kind == "zero"
    # second return: never nearer-than-nothing; where both exist, the strongest has ≥ signal
    r1, r2 = f.pixels["RANGE"], f.pixels["RANGE2"]
    s1, s2 = f.pixels["SIGNAL"], f.pixels["SIGNAL2"]
    both = (r1 > 0) & (r2 > 0)
    assert both.any()
    assert np.all(s1[both] >= s2[both])


def test_crc_valid_on_every_crc_test_packet_and_catches_damage():
    md, batch = lidar_streams("ouster-sdk/crc_test.pcap", ["ouster-sdk/crc_test.json"])[0]
    assert md.footer_kind == "crc" and len(batch) == 34
    f = decode_packets(batch.payload, md)
    assert f.crc_ok.tolist() == [True] * 34
    damaged = batch.payload.copy()
    damaged[3, 1000] ^= 0x40
    damaged[7, -1] ^= 0x01  # the CRC itself
    ok = decode_packets(damaged, md).crc_ok
    assert ok.sum() == 32 and not ok[3] and not ok[7]


def test_crc_of_the_dual_packet_of_same_ports_nonlegacy():
    streams = lidar_streams("ouster-sdk/same_ports_nonlegacy.pcap", ["ouster-sdk/same_ports_nonlegacy.1.json", "ouster-sdk/same_ports_nonlegacy.2.json"])
    by_profile = {md.profile.name: (md, b) for md, b in streams}
    md, b = by_profile["RNG19_RFL8_SIG16_NIR16_DUAL"]
    assert decode_packets(b.payload, md).crc_ok.tolist() == [True]
    md, b = by_profile["FUSA_RNG15_RFL8_NIR8_DUAL"]
    f = decode_packets(b.payload, md)
    assert f.crc_ok is None and np.all(f.footer == 0)
    assert int(f.header["init_id"][0]) == md.init_id == 390078
    assert int(f.header["prod_sn"][0]) == int(md.serial)


def test_wrong_size_raises_sensor_mismatch():
    md = load_metadata(external("ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.json"))
    with pytest.raises(SensorMismatchError, match="8448"):
        decode_packets(np.zeros((2, 6464), np.uint8), md)
    with pytest.raises(PacketFormatError):
        decode_packets(np.zeros((2, 8448), np.float32), md)


def test_encoder_rejects_values_that_do_not_fit():
    md = load_metadata(external("ouster-sdk/OS-0-128-U1_v2.3.0_1024x10.json"))
    f = empty_fields(md, 1)
    f.pixels["RANGE"][0, 0, 0] = 12  # not a multiple of the 8 mm wire unit
    with pytest.raises(PacketFormatError, match="multiples of 8"):
        encode_packets(f, md)
    f.pixels["RANGE"][0, 0, 0] = 8 * 2**15  # one step beyond 15 bits
    with pytest.raises(PacketFormatError, match="15 bits"):
        encode_packets(f, md)
    f.pixels["RANGE"][0, 0, 0] = 8 * (2**15 - 1)
    assert decode_packets(encode_packets(f, md), md).pixels["RANGE"][0, 0, 0] == 8 * (2**15 - 1)


def test_synthetic_packets_get_a_valid_crc_for_firmware_that_writes_one():
    md = load_metadata(external("ouster-sdk/crc_test.json"))
    f = empty_fields(md, 3)
    f.measurement_id[:] = np.arange(16)
    f.status[:] = 1
    f.header["frame_id"][:] = [5, 5, 6]
    pk = encode_packets(f, md)
    g = decode_packets(pk, md)
    assert g.crc_ok.all()
    assert g.frame_id.tolist() == [5, 5, 6]
    assert np.all(g.header["init_id"] == md.init_id)


# ----------------------------------------------------------------------------- properties

from hypothesis import given, settings, strategies as st  # noqa: E402

from lidarpkt.vendors.ouster.profiles import PROFILES  # noqa: E402

_PROFILE_ROWS = [(name, rows) for name in PROFILES for rows in (16, 32)]


class _Md:
    """Just enough metadata for decode/encode of a given layout."""

    def __init__(self, name: str, rows: int) -> None:
        self.profile = PROFILES[name]
        self.pixels_per_column = rows
        self.columns_per_packet = 16
        self.footer_kind = "unknown"
        self.init_id = 0x123456
        self.serial_int = 992210000957


@settings(max_examples=40, deadline=None)
@given(st.sampled_from(_PROFILE_ROWS), st.integers(1, 3), st.randoms(use_true_random=False))
def test_any_bytes_round_trip(layout, n, rnd):
    """decode then encode gives back any packet bytes at all (every bit belongs to a field)."""
    md = _Md(*layout)
    size = md.profile.packet_size(md.pixels_per_column)
    payload = np.frombuffer(rnd.randbytes(n * size), np.uint8).reshape(n, size)
    assert np.array_equal(encode_packets(decode_packets(payload, md), md, crc=False), payload)


@settings(max_examples=40, deadline=None)
@given(st.sampled_from(_PROFILE_ROWS), st.randoms(use_true_random=False))
def test_fields_survive_encode_then_decode(layout, rnd):
    """Random in-range field values (wire units respected) come back unchanged."""
    md = _Md(*layout)
    f = empty_fields(md, 2)
    rng = np.random.default_rng(rnd.getrandbits(32))
    for bf in md.profile.pixel_fields:
        if bf.reserved:
            continue
        raw = rng.integers(0, 1 << bf.width, size=(2, 16, md.pixels_per_column), dtype=np.uint64)
        f.pixels[bf.name] = (raw << np.uint64(bf.upshift)).astype(bf.dtype)
    f.timestamp_ns[:] = rng.integers(0, 2**63, size=(2, 16), dtype=np.uint64)
    f.measurement_id[:] = rng.integers(0, 2**16, size=(2, 16))
    f.status[:] = rng.integers(0, 2**32 if md.profile.legacy else 2**16, size=(2, 16))
    g = decode_packets(encode_packets(f, md), md)
    for name, arr in f.pixels.items():
        assert np.array_equal(g.pixels[name], arr) and g.pixels[name].dtype == arr.dtype, name
    assert np.array_equal(g.timestamp_ns, f.timestamp_ns)
    assert np.array_equal(g.measurement_id, f.measurement_id)
    assert np.array_equal(g.status, f.status)


# ----------------------------------------------------------------------------- IMU

from lidarpkt.vendors.ouster import decode_imu, encode_imu  # noqa: E402
from lidarpkt.containers.pcap_reader import read_batches  # noqa: E402


IMU_CAPTURES = [  # SOURCES.md: the captures that hold 48-byte IMU packets
    "ouster-sdk/OS-1-64_1024x10_fw20.pcap",
    "ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.pcap",
    "ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.pcap",
    "ouster-sdk/OS-0-128-U1_v2.3.0_1024x10.pcap",
    "ouster-sdk/crc_test.pcap",
    "ouster-sdk/same_ports_nonlegacy.pcap",
]


@pytest.mark.parametrize("pcap", IMU_CAPTURES)
def test_imu_round_trip_and_plausibility(pcap):
    rows = [b.payload for b in read_batches(external(pcap)) if b.payload_size == 48]
    assert rows
    payload = np.concatenate(rows)
    imu = decode_imu(payload)
    assert np.array_equal(encode_imu(imu), payload)
    assert np.array_equal(encode_imu({k: imu[k] for k in imu.dtype.names}), payload)
    # a sensor at rest: |a| ≈ 1 g; timestamps in ns, non-decreasing within a stream
    g = np.sqrt(imu["accel_x_g"] ** 2 + imu["accel_y_g"] ** 2 + imu["accel_z_g"] ** 2)
    assert np.all(np.abs(g - 1.0) < 0.1)
    assert np.all(np.abs(imu["gyro_x_deg_per_s"]) < 5)
    for r in rows:
        ts = decode_imu(r)["sys_timestamp_ns"].astype(np.int64)
        assert np.all(np.diff(ts) >= 0)


def test_imu_bad_input():
    with pytest.raises(PacketFormatError, match="48 bytes"):
        decode_imu(np.zeros((2, 47), np.uint8))
    with pytest.raises(PacketFormatError, match="missing"):
        encode_imu({"sys_timestamp_ns": np.zeros(1)})
    assert len(decode_imu(bytes(48))) == 1
