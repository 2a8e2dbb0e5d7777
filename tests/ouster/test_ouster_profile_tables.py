"""The bit-field table helpers of lidarpkt.vendors.ouster.profiles, called directly (they run at import,
where only a direct call can show a broken one): reserved-bit splitting, the cover check, the
field types and lookups."""

from __future__ import annotations

import numpy as np
import pytest

from lidarpkt.errors import MetadataError, PacketFormatError
from lidarpkt.vendors.ouster import bitfield as B
from lidarpkt.vendors.ouster import profiles as P


def pieces(fields):
    return [(f.name, f.start_bit, f.width) for f in fields]


def test_reserved_bits_split_at_32_bit_words():
    assert pieces(B.reserved_bits(104, 24)) == [("_reserved_104", 104, 24)]
    assert pieces(B.reserved_bits(156, 100)) == [("_reserved_156", 156, 4), ("_reserved_160", 160, 32),
                                             ("_reserved_192", 192, 32), ("_reserved_224", 224, 32)]
    assert pieces(B.reserved_bits(0, 64)) == [("_reserved_0", 0, 32), ("_reserved_32", 32, 32)]
    assert pieces(B.reserved_bits(40, 8)) == [("_reserved_40", 40, 8)]
    assert pieces(B.reserved_bits(30, 5)) == [("_reserved_30", 30, 2), ("_reserved_32", 32, 3)]
    assert B.reserved_bits(8, 0) == ()
    assert all(f.reserved for f in B.reserved_bits(156, 100))


def test_cover_check_accepts_an_exact_cover_and_names_the_bad_bits():
    ok = (B.BitField("A", 0, 3), B.BitField("B", 3, 5))
    B.check_cover(ok, 8, "t")
    with pytest.raises(PacketFormatError, match=r"t: bits \[7\] not covered exactly once"):
        B.check_cover((B.BitField("A", 0, 7),), 8, "t")
    with pytest.raises(PacketFormatError, match=r"bits \[2\] not covered exactly once"):
        B.check_cover((B.BitField("A", 0, 3), B.BitField("B", 2, 1), B.BitField("C", 3, 5)), 8, "t")
    with pytest.raises(PacketFormatError, match="field B outside the record"):
        B.check_cover((B.BitField("A", 0, 4), B.BitField("B", 4, 5)), 8, "t")
    with pytest.raises(PacketFormatError, match="field Z outside the record"):
        B.check_cover((B.BitField("A", 0, 8), B.BitField("Z", 8, 0)), 8, "t")


def test_bit_field_types_masks_and_lookups():
    assert B.BitField("R", 0, 15, 3).dtype == np.uint32  # 18 bits
    assert B.BitField("R", 0, 13, 3).dtype == np.uint16  # exactly 16
    assert B.BitField("N", 0, 8, 4).dtype == np.uint16
    assert B.BitField("F", 0, 8).dtype == np.uint8
    assert B.BitField("S", 0, 40).dtype == np.uint64
    with pytest.raises(ValueError, match="wider than 64 bits"):
        _ = B.BitField("X", 0, 64, 1).dtype
    assert B.BitField("F", 0, 5).mask == 0b11111 and B.BitField("W", 0, 32).mask == 0xFFFFFFFF
    assert P.RNG15_RFL8_NIR8.field("NEAR_IR") == B.BitField("NEAR_IR", 24, 8, 4)
    with pytest.raises(KeyError, match="RNG15_RFL8_NIR8 has no pixel field 'SIGNAL'"):
        P.RNG15_RFL8_NIR8.field("SIGNAL")
    assert P.get_profile("LEGACY") is P.LEGACY
    with pytest.raises(MetadataError, match="'RNG99_BOGUS' is not supported"):
        P.get_profile("RNG99_BOGUS")


@pytest.mark.parametrize("profile,h,size", [
    (P.LEGACY, 64, 16 * (16 + 64 * 12 + 4)),  # 12608: no packet header or footer
    (P.RNG19_RFL8_SIG16_NIR16, 128, 32 + 16 * (12 + 128 * 12) + 32),
    (P.RNG19_RFL8_SIG16_NIR16_DUAL, 32, 8448),
    (P.RNG15_RFL8_NIR8, 128, 8448),
    (P.FUSA_RNG15_RFL8_NIR8_DUAL, 128, 32 + 16 * (12 + 128 * 8) + 32),
])
def test_packet_sizes_and_dtypes(profile, h, size):
    assert profile.packet_size(h) == size == profile.packet_dtype(h).itemsize
    dt = profile.packet_dtype(h)
    assert dt.fields["columns"][1] == profile.header_bytes
    assert dt.fields["footer"][1] == size - profile.footer_bytes
    col = profile.column_dtype(h)
    assert col.itemsize == profile.column_bytes(h)
    assert col.fields["pixels"][1] == profile.column_header_bytes
    assert col["pixels"].shape == (h, profile.pixel_bytes // 4)
    if profile.legacy:
        assert col.fields["status"][1] == 16 + h * 12 and profile.returns == 1
    else:
        assert "status" in col.fields and col.fields["status"][1] == 10
    assert profile.returns == (2 if "DUAL" in profile.name else 1)


def test_to_raw_errors_name_the_unit_and_the_width():
    from lidarpkt.errors import PacketFormatError

    rng = B.BitField("RANGE", 0, 15, 3)
    assert B._to_raw(np.array([8, 16, 0]), rng).tolist() == [1, 2, 0]
    with pytest.raises(PacketFormatError, match=r"field RANGE: values must be multiples of 8 \(the wire unit\); got e.g. 12"):
        B._to_raw(np.array([8, 12, 16]), rng)
    with pytest.raises(PacketFormatError, match=r"field RANGE: value 262144 does not fit in 15 bits × 8$"):
        B._to_raw(np.array([8, (1 << 15) * 8]), rng)
    with pytest.raises(PacketFormatError, match=r"field FLAGS: value 2 does not fit in 1 bits$"):
        B._to_raw(np.array([1, 2]), B.BitField("FLAGS", 15, 1))


def test_read_bits_keeps_leading_axes_and_the_field_type():
    data = np.random.default_rng(3).integers(0, 256, size=(2, 3, 12), dtype=np.uint8)
    for f in P.RNG19_RFL8_SIG16_NIR16.pixel_fields:
        got = B.read_bits(data, f)
        assert got.shape == (2, 3) and got.dtype == f.dtype, f.name
        want = [[(int.from_bytes(data[i, j].tobytes(), "little") >> f.start_bit) & f.mask for j in range(3)] for i in range(2)]
        assert got.tolist() == want, f.name


def test_selected_packet_fields_are_the_rows_of_every_field(ext):
    from lidarpkt.vendors.ouster import decode_packets
    from test_ouster_cases import lidar_streams

    for pcap, jsons in (("ouster-sdk/crc_test.pcap", ["ouster-sdk/crc_test.json"]),
                        ("ouster-sdk/OS-1-64_1024x10_fw20.pcap", ["ouster-sdk/OS-1-64_sensor_config_reduced.json"])):
        md, batch = lidar_streams(pcap, jsons)[0]
        f = decode_packets(batch.payload, md)
        rows = np.array([3, 0, 5])
        s = f.select(rows)
        assert len(s) == 3 and s.profile is f.profile
        assert (s.pixels_per_column, s.columns_per_packet) == (f.pixels_per_column, f.columns_per_packet)
        for name in ("timestamp_ns", "measurement_id", "status", "footer", "column_frame_id", "encoder_count", "crc_ok"):
            a, b = getattr(f, name), getattr(s, name)
            assert (a is None and b is None) or np.array_equal(a[rows], b), name
        for group in ("header", "pixels", "extra"):
            a, b = getattr(f, group), getattr(s, group)
            assert set(a) == set(b) and all(np.array_equal(a[k][rows], b[k]) for k in a), group
