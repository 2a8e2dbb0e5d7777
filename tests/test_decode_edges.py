"""Edges of the decode modules the capture tests do not reach: CRC-64/XZ against a bit-by-bit
reference over block boundaries, the bounded IMU buffer, the decoder's statistics, the NMEA text
of position packets, and the corrected VLP-16 distance."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lidarpkt.vendors.ouster import OusterDecoder, load_metadata
from lidarpkt.vendors.ouster.crc import crc64_xz, footer_crc_ok
from lidarpkt.core.packet import PacketBatch

CAL = Path(__file__).parent / "data" / "calibration" / "vlp16_corrected.yaml"


def crc64_xz_bitwise(data: bytes) -> int:
    """CRC-64/XZ one bit at a time (reflected ECMA-182 polynomial, init and xorout all ones)."""
    reg = 0xFFFFFFFFFFFFFFFF
    for byte in data:
        reg ^= byte
        for _ in range(8):
            reg = (reg >> 1) ^ (0xC96C5795D7870F42 if reg & 1 else 0)
    return reg ^ 0xFFFFFFFFFFFFFFFF


def test_crc_check_value_and_block_boundaries():
    assert int(crc64_xz(np.frombuffer(b"123456789", np.uint8))) == 0x995DC9BBDF1939FA
    rng = np.random.default_rng(7)
    for length in (0, 1, 7, 8, 255, 256, 257, 511, 512, 513, 1000):
        rows = rng.integers(0, 256, size=(3, length), dtype=np.uint8)
        got = crc64_xz(rows)
        assert got.dtype == np.uint64 and got.shape == (3,)
        assert [int(x) for x in got] == [crc64_xz_bitwise(r.tobytes()) for r in rows], length


def test_crc_of_more_rows_than_two_gather_chunks():
    rows = np.random.default_rng(8).integers(0, 256, size=(8300, 12), dtype=np.uint8)  # chunks of 4096 rows
    got = crc64_xz(rows)
    for i in (0, 4095, 4096, 8191, 8192, 8299):
        assert int(got[i]) == crc64_xz_bitwise(rows[i].tobytes())


def test_footer_crc_ok_reads_the_last_8_bytes_little_endian():
    body = np.random.default_rng(9).integers(0, 256, size=(2, 300), dtype=np.uint8)
    crc = [crc64_xz_bitwise(r.tobytes()) for r in body]
    packets = np.concatenate([body, np.array([list(c.to_bytes(8, "little")) for c in crc], np.uint8)], 1)
    assert footer_crc_ok(packets).tolist() == [True, True]
    packets[1, -1] ^= 1
    packets[0, 5] ^= 0x80
    assert footer_crc_ok(packets).tolist() == [False, False]


def _imu_payloads(n: int) -> np.ndarray:
    out = np.zeros((n, 48), np.uint8)
    out[:, :8] = np.arange(n, dtype="<u8").view(np.uint8).reshape(n, 8)  # sys_timestamp_ns = i
    return out


def test_imu_buffer_keeps_the_newest_samples_and_counts_the_dropped(ext):
    md = load_metadata(ext("ouster-sdk/OS-1-64_sensor_config_reduced.json"))
    dec = OusterDecoder(md, max_imu_samples=5)
    assert len(dec.imu_samples()) == 0
    payloads = _imu_payloads(11)
    for lo, hi in ((0, 3), (3, 4), (4, 10), (10, 11)):
        dec.push_imu(PacketBatch.from_payloads(payloads[lo:hi]))
    kept = dec.imu_samples()
    assert kept.extra["sys_timestamp_ns"].tolist() == [6, 7, 8, 9, 10]
    assert dec.stats.imu_packets == 11 and dec.stats.imu_dropped == 6
    dec.push_imu(PacketBatch.from_payloads(np.zeros((2, 40), np.uint8)))
    assert dec.stats.size_mismatch == 2 and len(dec.imu_samples()) == 5
    stats = dec.stats.as_dict()
    assert stats["imu_packets"] == 11 and stats["imu_dropped"] == 6 and stats["size_mismatch"] == 2
    assert set(stats) >= {"packets", "accepted", "lost_packets", "frames", "crc_failures"}


def test_wrong_size_lidar_packets_are_counted_and_skipped(ext):
    md = load_metadata(ext("ouster-sdk/OS-1-64_sensor_config_reduced.json"))
    dec = OusterDecoder(md)
    with pytest.warns(Warning, match="skipped 3 packets of 100 B"):
        assert dec.push(PacketBatch.from_payloads(np.zeros((3, 100), np.uint8))) == []
    assert dec.stats.size_mismatch == 3 and dec.stats.packets == 3


def test_position_packet_sentences():
    from lidarpkt.vendors.velodyne import decode_position_packets

    payload = np.zeros((4, 512), np.uint8)
    nmea = [b"$GPRMC,1*00 \r\n", b"", b"$GPTXT,FIX\x00junk after the NUL\x00more", b"$GP\xc3\xa9\r\n"]
    for row, text in zip(payload, nmea):
        row[206 : 206 + len(text)] = np.frombuffer(text, np.uint8)
    pk = decode_position_packets(payload)
    assert len(pk) == 4
    # only CR LF goes (a space before it stays); each non-ASCII byte becomes U+FFFD
    assert pk.sentences() == ["$GPRMC,1*00 ", "", "$GPTXT,FIX", "$GP\ufffd\ufffd"]


def test_corrected_distance_of_a_vlp16_frame():
    from lidarpkt.vendors.velodyne import VelodyneDecoder, encode_data_packets, load_calibration

    cal = load_calibration(CAL)
    n = 3
    az = (np.arange(n)[:, None] * 480 + np.arange(12)[None, :] * 40) % 36000
    dist = np.random.default_rng(2).integers(0, 40000, size=(n, 12, 32))
    payload = encode_data_packets(az, dist, np.full((n, 12, 32), 9), 1000 + np.arange(n) * 1327, "strongest")
    dec = VelodyneDecoder(calibration=CAL)
    (f,) = dec.push(PacketBatch.from_payloads(payload)) + dec.finish()
    d = f.sensor.geometry.distance_m(f)
    laser = cal.rows_to_laser
    expected = np.where(f.range_mm > 0, f.range_mm / 1000.0 + cal.dist_correction_m[laser][None, :, None], 0.0)
    np.testing.assert_allclose(d, expected, atol=1e-12)
    assert np.count_nonzero(d) == np.count_nonzero(dist)


def test_firing_azimuths_per_packet_mode_and_the_general_path():
    """firing_azimuth_cdeg with a per-packet dual flag equals the one-mode results row by row, and a
    batch holding an invalid block azimuth (> 36000, the general integer path) gives the other
    packets the same azimuths as the fast path."""
    from lidarpkt.vendors.velodyne.timing import firing_azimuth_cdeg

    n = 40
    az = ((np.arange(n)[:, None] * 480 + np.arange(12)[None, :] * 40 + 35000) % 36000).astype(np.uint16)
    single, dual = firing_azimuth_cdeg(az, False), firing_azimuth_cdeg(az, True)
    assert single.dtype == np.uint16 and single.shape == (n, 12, 32) and int(single.max()) < 36000
    mixed = np.arange(n) % 3 == 0
    got = firing_azimuth_cdeg(az, mixed)
    np.testing.assert_array_equal(got[mixed], dual[mixed])
    np.testing.assert_array_equal(got[~mixed], single[~mixed])
    bad = np.concatenate([az, np.full((1, 12), 40000, np.uint16)])
    general = firing_azimuth_cdeg(bad, False)
    np.testing.assert_array_equal(general[:n], single)
    assert general.dtype == np.uint16 and int(general[n].max()) < 36000
    # the invalid packet: rate 0, so every firing sits at 40000 mod 36000
    assert np.all(general[n] == 4000)


def test_vlp16_packet_fields_have_their_documented_types():
    from lidarpkt.vendors.velodyne import decode_packets, encode_data_packets

    payload = encode_data_packets(np.zeros((2, 12), np.int64), np.full((2, 12, 32), 500), np.full((2, 12, 32), 3),
                                  np.array([1000, 2327]), "strongest")
    for copy in (True, False):
        p = decode_packets(payload, copy=copy)
        types = {name: getattr(p, name).dtype for name in ("flag", "azimuth_cdeg", "distance_2mm", "reflectivity",
                                                           "timestamp_us", "return_mode", "product_id")}
        assert types == {"flag": np.uint16, "azimuth_cdeg": np.uint16, "distance_2mm": np.uint16,
                         "reflectivity": np.uint8, "timestamp_us": np.uint32, "return_mode": np.uint8,
                         "product_id": np.uint8}
        assert p.timestamp_us.tolist() == [1000, 2327]


def test_reassembler_limits_must_be_positive():
    from lidarpkt.containers.reassembly import Reassembler

    Reassembler(timeout_ns=1, max_datagrams=1, max_bytes=1)
    for bad in ({"timeout_ns": 0}, {"max_datagrams": 0}, {"max_bytes": 0}):
        with pytest.raises(ValueError, match="timeout_ns, max_datagrams and max_bytes must be positive"):
            Reassembler(**bad)
    r = Reassembler()
    assert (r.timeout_ns, r.max_datagrams) == (30_000_000_000, 1024)
