"""VLP-16 packet layout, decoding, encoding and round trips, checked against the manual and real payloads.

Expected values come from the manual's byte layout (written here with ``struct``, not with
our dtypes) and from the real third-party captures; round trips must give the exact bytes.
"""

from __future__ import annotations

import struct

import numpy as np
import pytest

from lidarpkt.errors import LidarpktError, NMEAError, PacketFormatError
from lidarpkt.core.packet import PacketBatch
from lidarpkt.vendors.velodyne import (
    DATA_PACKET_SIZE,
    POSITION_PACKET_SIZE,
    decode_packets,
    decode_position_packets,
    encode_data_packets,
    encode_position_packets,
)
from lidarpkt.vendors.velodyne.timing import FIRING_OFFSET_NS, firing_azimuth_cdeg, firing_offset_ns


def manual_data_packet(azimuths, dist, refl, timestamp_us, mode_byte, product_byte) -> bytes:
    """A data packet written from the manual's table: 12 × (FF EE, azimuth, 32 × (distance, reflectivity))."""
    out = bytearray()
    for b in range(12):
        out += b"\xff\xee" + struct.pack("<H", azimuths[b])
        for j in range(32):
            out += struct.pack("<HB", dist[b][j], refl[b][j])
    out += struct.pack("<IBB", timestamp_us, mode_byte, product_byte)
    assert len(out) == 1206
    return bytes(out)


def _real_payloads(ext, name: str, size: int) -> np.ndarray:
    from lidarpkt.containers.pcap_reader import PcapReader

    rows = [b.payload for b in PcapReader(ext(name)).batches() if b.payload_size == size]
    return np.concatenate(rows)


# ------------------------------------------------------------------ layout
def test_hand_built_packet_decodes_field_by_field():
    rng = np.random.default_rng(7)
    az = [0x7133, 0, 35999, 36000, 100, 200, 300, 400, 500, 600, 700, 800]
    dist = rng.integers(0, 65536, size=(12, 32)).tolist()
    refl = rng.integers(0, 256, size=(12, 32)).tolist()
    dist[0][0] = 0x0594  # 1428 × 2 mm
    raw = manual_data_packet(az, dist, refl, 0x12345678, 0x38, 0x22)
    d = decode_packets(np.frombuffer(raw, np.uint8)[None, :])
    assert d.azimuth_cdeg[0].tolist() == az
    assert d.azimuth_cdeg[0, 0] / 100 == pytest.approx(289.79)
    assert d.distance_2mm[0].tolist() == dist
    assert d.reflectivity[0].tolist() == refl
    assert d.range_mm[0, 0, 0] == 2856
    assert int(d.timestamp_us[0]) == 0x12345678
    assert int(d.return_mode[0]) == 0x38 and int(d.product_id[0]) == 0x22
    assert d.flag_ok.tolist() == [True]
    # and the encoder writes exactly those bytes
    enc = encode_data_packets(d.azimuth_cdeg, d.distance_2mm, d.reflectivity, d.timestamp_us, "last")
    assert enc[0].tobytes() == raw


def test_bad_flag_is_reported_not_hidden():
    raw = bytearray(manual_data_packet([0] * 12, [[1] * 32] * 12, [[1] * 32] * 12, 5, 0x37, 0x22))
    raw[701] = 0xDD  # block 7 (bytes 700–701): FF EE → FF DD
    d = decode_packets(np.frombuffer(bytes(raw), np.uint8)[None, :])
    assert d.flag[0, 7] == 0xDDFF
    assert d.flag_ok.tolist() == [False]


def test_wrong_size_raises_library_error():
    with pytest.raises(PacketFormatError, match="1206"):
        decode_packets(np.zeros((2, 1212), np.uint8))
    with pytest.raises(PacketFormatError, match="512"):
        decode_position_packets(np.zeros((1, 1206), np.uint8))
    assert issubclass(PacketFormatError, LidarpktError)


def test_encoder_rejects_values_that_do_not_fit():
    ok = dict(azimuth_cdeg=np.zeros((1, 12)), distance_2mm=np.zeros((1, 12, 32)), reflectivity=np.zeros((1, 12, 32)),
              timestamp_us=[0], return_mode="strongest")
    encode_data_packets(**ok)
    with pytest.raises(PacketFormatError):
        encode_data_packets(**{**ok, "distance_2mm": np.full((1, 12, 32), 70000)})
    with pytest.raises(PacketFormatError):
        encode_data_packets(**{**ok, "azimuth_cdeg": np.zeros((1, 11))})
    with pytest.raises(PacketFormatError, match="return mode"):
        encode_data_packets(**{**ok, "return_mode": "third"})
    with pytest.raises(NMEAError):
        encode_position_packets(0, 0, "$" + "X" * 200)


def test_position_packet_layout_and_nmea():
    sentence = "$GPRMC,214616,A,3708.3443,N,12139.4299,W,009.7,040.6,111212,013.8,E,D*0E"
    p = encode_position_packets([123456789], 2, sentence)
    assert p.shape == (1, POSITION_PACKET_SIZE)
    raw = p[0].tobytes()
    assert raw[:198] == bytes(198)
    assert struct.unpack_from("<I", raw, 198)[0] == 123456789
    assert raw[202] == 2
    assert raw[206:206 + len(sentence) + 2] == sentence.encode() + b"\r\n"
    pos = decode_position_packets(p)
    assert pos.sentences() == [sentence]
    assert int(pos.pps_status[0]) == 2 and int(pos.timestamp_us[0]) == 123456789


# ------------------------------------------------------------------ round trips on real payloads
def _roundtrip_data(payload: np.ndarray) -> None:
    d = decode_packets(payload)
    enc = encode_data_packets(d.azimuth_cdeg, d.distance_2mm, d.reflectivity, d.timestamp_us, d.return_mode,
                              d.product_id, flag=d.flag)
    assert enc.shape == payload.shape
    np.testing.assert_array_equal(enc, payload)


def _roundtrip_position(payload: np.ndarray) -> None:
    p = decode_position_packets(payload)
    enc = encode_position_packets(p.timestamp_us, p.pps_status, p.nmea, thermal_status=p.thermal_status,
                                  last_shutdown_temperature=p.last_shutdown_temperature,
                                  powerup_temperature=p.powerup_temperature, unused_head=p.unused_head,
                                  unused_tail=p.unused_tail)
    np.testing.assert_array_equal(enc, payload)


def test_roundtrip_einride_payload_files(ext):
    one = np.fromfile(ext("einride-vlp16-go/packet.bin"), np.uint8).reshape(1, DATA_PACKET_SIZE)
    many = np.fromfile(ext("einride-vlp16-go/recording.bin"), np.uint8).reshape(-1, DATA_PACKET_SIZE)
    assert many.shape[0] == 1000
    _roundtrip_data(one)
    _roundtrip_data(many)


@pytest.mark.parametrize("name", ["rust-lidar-utils/velodyne_example.pcap", "rust-lidar-utils/velodyne_vlp16.pcap",
                                  "veloview/vlp-16-test-90deg-1-50-frames.pcap"])
def test_roundtrip_pcap_payloads(ext, name):
    data = _real_payloads(ext, name, DATA_PACKET_SIZE)
    assert data.shape[0] >= 84
    _roundtrip_data(data)
    if "example" not in name:  # velodyne_example has no position packets
        pos = _real_payloads(ext, name, POSITION_PACKET_SIZE)
        assert pos.shape[0] >= 16
        _roundtrip_position(pos)


def test_roundtrip_dual_bag_payloads(ext):
    from lidarpkt.containers.bags import BagReader
    from lidarpkt.vendors.registry import bag_messages

    batch = PacketBatch.concatenate(list(BagReader(ext("nebula/vlp16/1673400471837873222"), messages=bag_messages()).batches()))
    assert batch.payload.shape == (603, DATA_PACKET_SIZE)
    _roundtrip_data(batch.payload)


# ------------------------------------------------------------------ what the real captures say
def test_factory_bytes_of_real_captures(ext):
    from lidarpkt.containers.bags import BagReader
    from lidarpkt.vendors.registry import bag_messages

    ex = decode_packets(_real_payloads(ext, "rust-lidar-utils/velodyne_example.pcap", DATA_PACKET_SIZE))
    assert set(ex.return_mode.tolist()) == {0x37} and set(ex.product_id.tolist()) == {0x22}
    early = decode_packets(_real_payloads(ext, "rust-lidar-utils/velodyne_vlp16.pcap", DATA_PACKET_SIZE))
    assert set(early.product_id.tolist()) == {0x21}
    # VLP-16 timing: a packet every 12 × 110.592 µs (integer µs stamps: 1327 or 1328)
    assert set(np.diff(early.timestamp_us.astype(np.int64)).tolist()) <= {1327, 1328}
    dual = decode_packets(PacketBatch.concatenate(list(BagReader(ext("nebula/vlp16/1673400471837873222"), messages=bag_messages()).batches())).payload)
    assert set(dual.return_mode.tolist()) == {0x39}
    # dual mode: both blocks of a pair carry the same azimuth
    np.testing.assert_array_equal(dual.azimuth_cdeg[:, 0::2], dual.azimuth_cdeg[:, 1::2])


# ------------------------------------------------------------------ timing (manual formulas)
def test_firing_offsets_follow_the_manual():
    # 55.296 µs per firing sequence, 2.304 µs per laser; block b holds sequences 2b and 2b+1
    assert FIRING_OFFSET_NS[0, 0] == 0
    assert FIRING_OFFSET_NS[0, 1] == 2304
    assert FIRING_OFFSET_NS[0, 16] == 55296
    assert FIRING_OFFSET_NS[11, 31] == 23 * 55296 + 15 * 2304 == 1_306_368  # last entry of the manual's table
    dual = firing_offset_ns(np.array([True]))[0]
    # einride/vlp16-go's timing test expects the same: 2.304, 34.560, 89.856 µs for channels 1, 15, 31
    # of block 0, and 642.816 µs (dual) / 1306.37 µs (single) for the packet's last firing
    assert [FIRING_OFFSET_NS[0, j] for j in (1, 15, 31)] == [2304, 34560, 89856]
    assert dual[11, 31] == 642_816
    # dual: blocks 2k and 2k+1 are the same firings, with the times of single-mode block k
    np.testing.assert_array_equal(dual[4], FIRING_OFFSET_NS[2])
    np.testing.assert_array_equal(dual[5], FIRING_OFFSET_NS[2])


def test_azimuth_interpolation_within_a_block():
    az = (np.arange(12) * 40 + 35990) % 36000  # 40 × 0.01° per block, wrapping after block 0
    fa = firing_azimuth_cdeg(az[None, :], np.array([False]))[0]
    # rate = 440 cdeg over 22 firing sequences = 20 cdeg per sequence
    assert fa[0, 0] == 35990
    assert fa[0, 16] == 10  # 35990 + 20, wrapped
    assert fa[1, 16] == 50
    assert fa[1, 8] == 30 + 7  # laser 8: 8 × 2.304 / 55.296 × 20 = 6.67 → 7
    # dual: 6 block pairs over 10 sequences; both blocks of a pair get the same firing azimuths
    dual_az = np.repeat(np.arange(6) * 40, 2)
    fd = firing_azimuth_cdeg(dual_az[None, :], np.array([True]))[0]
    np.testing.assert_array_equal(fd[0], fd[1])
    assert fd[2, 16] == 60  # 40 + 200/10


# ------------------------------------------------------------------ frames → packets
def test_frames_encode_back_to_the_real_payloads(ext):
    """decode → frames → encode_frames gives every byte back (einride strongest, nebula dual)."""
    from lidarpkt.containers.bags import BagReader
    from lidarpkt.vendors.registry import bag_messages
    from lidarpkt.vendors.velodyne import VelodyneDecoder, encode_frames

    payload = np.fromfile(ext("einride-vlp16-go/recording.bin"), np.uint8).reshape(-1, DATA_PACKET_SIZE)
    host = 1_525_349_000_000_000_000 + np.arange(1000, dtype=np.int64) * 1_327_104
    dec = VelodyneDecoder()
    frames = dec.push(PacketBatch.from_payloads(payload, host)) + dec.finish()
    np.testing.assert_array_equal(encode_frames(frames), payload)
    batch = PacketBatch.concatenate(list(BagReader(ext("nebula/vlp16/1673400471837873222"), messages=bag_messages()).batches()))
    dec = VelodyneDecoder()
    frames = dec.push(batch) + dec.finish()
    np.testing.assert_array_equal(encode_frames(frames), batch.payload)
    with pytest.raises(PacketFormatError, match="whole"):
        encode_frames(frames[1:2])  # a frame alone starts mid-packet


def test_position_timestamps_run_on_the_data_packets_clock(ext):
    """Byte 198 of a position packet is the sensor's µs past the hour: in the VeloView capture each
    position packet's stamp lies within 3 ms of the data packets captured next to it."""
    from lidarpkt.containers.pcap_reader import PcapReader

    batches = list(PcapReader(ext("veloview/vlp-16-test-90deg-1-50-frames.pcap")).batches())
    data = PacketBatch.concatenate([b for b in batches if b.payload_size == DATA_PACKET_SIZE])
    pos = PacketBatch.concatenate([b for b in batches if b.payload_size == POSITION_PACKET_SIZE])
    assert len(pos) == 367
    t_data = decode_packets(data.payload).timestamp_us.astype(np.int64)
    p = decode_position_packets(pos.payload)
    k = np.searchsorted(data.index, pos.index)
    before = t_data[np.clip(k - 1, 0, None)]
    assert np.all(np.abs(p.timestamp_us.astype(np.int64) - before) < 3000)
    assert set(p.pps_status.tolist()) == {0}  # no GPS attached in that recording
    assert p.sentences() == [""] * 367
