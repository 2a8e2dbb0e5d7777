"""The bit-field table helpers of lidarpkt.ouster.profiles, called directly (they run at import,
where only a direct call can show a broken one): reserved-bit splitting, the cover check, the
field types and lookups."""

from __future__ import annotations

import numpy as np
import pytest

from lidarpkt.errors import MetadataError
from lidarpkt.ouster import profiles as P


def pieces(fields):
    return [(f.name, f.start_bit, f.width) for f in fields]


def test_reserved_bits_split_at_32_bit_words():
    assert pieces(P._reserved(104, 24)) == [("_reserved_104", 104, 24)]
    assert pieces(P._reserved(156, 100)) == [("_reserved_156", 156, 4), ("_reserved_160", 160, 32),
                                             ("_reserved_192", 192, 32), ("_reserved_224", 224, 32)]
    assert pieces(P._reserved(0, 64)) == [("_reserved_0", 0, 32), ("_reserved_32", 32, 32)]
    assert pieces(P._reserved(40, 8)) == [("_reserved_40", 40, 8)]
    assert pieces(P._reserved(30, 5)) == [("_reserved_30", 30, 2), ("_reserved_32", 32, 3)]
    assert P._reserved(8, 0) == ()
    assert all(f.reserved for f in P._reserved(156, 100))


def test_cover_check_accepts_an_exact_cover_and_names_the_bad_bits():
    ok = (P.BitField("A", 0, 3), P.BitField("B", 3, 5))
    P._check_cover(ok, 8, "t")
    with pytest.raises(AssertionError, match=r"t: bits \[7\] not covered exactly once"):
        P._check_cover((P.BitField("A", 0, 7),), 8, "t")
    with pytest.raises(AssertionError, match=r"bits \[2\] not covered exactly once"):
        P._check_cover((P.BitField("A", 0, 3), P.BitField("B", 2, 1), P.BitField("C", 3, 5)), 8, "t")
    with pytest.raises(AssertionError, match="field B outside the record"):
        P._check_cover((P.BitField("A", 0, 4), P.BitField("B", 4, 5)), 8, "t")
    with pytest.raises(AssertionError, match="field Z outside the record"):
        P._check_cover((P.BitField("A", 0, 8), P.BitField("Z", 8, 0)), 8, "t")


def test_bit_field_types_masks_and_lookups():
    assert P.BitField("R", 0, 15, 3).dtype == np.uint32  # 18 bits
    assert P.BitField("R", 0, 13, 3).dtype == np.uint16  # exactly 16
    assert P.BitField("N", 0, 8, 4).dtype == np.uint16
    assert P.BitField("F", 0, 8).dtype == np.uint8
    assert P.BitField("S", 0, 40).dtype == np.uint64
    with pytest.raises(ValueError, match="wider than 64 bits"):
        _ = P.BitField("X", 0, 64, 1).dtype
    assert P.BitField("F", 0, 5).mask == 0b11111 and P.BitField("W", 0, 32).mask == 0xFFFFFFFF
    assert P.RNG15_RFL8_NIR8.field("NEAR_IR") == P.BitField("NEAR_IR", 24, 8, 4)
    with pytest.raises(KeyError, match="RNG15_RFL8_NIR8 has no pixel field 'SIGNAL'"):
        P.RNG15_RFL8_NIR8.field("SIGNAL")
    assert P.get_profile("LEGACY") is P.LEGACY
    with pytest.raises(MetadataError, match="'FIVE_WORD_PIXEL' is not supported"):
        P.get_profile("FIVE_WORD_PIXEL")


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
