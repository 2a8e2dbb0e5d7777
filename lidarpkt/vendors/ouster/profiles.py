"""Ouster lidar packet layouts, each declared once.

A profile is a set of bit-field tables with the field names of the Ouster
firmware user manual ("Lidar Data Format" / "Configurable Data Packet Format"):

* the packet header (32 bytes for non-legacy profiles, none for LEGACY),
* the column header (and, for LEGACY, the column status word after the pixels),
* the pixel: ``BitField(name, start_bit, width, upshift)`` counted from the first
  byte of the pixel, read little-endian. ``upshift`` is the manual's unit scaling of
  the low-data-rate fields (RANGE × 8 → mm, NEAR_IR × 16),
* the 32-byte packet footer (firmware ≥ 2.5 writes a CRC-64/XZ in its last 8 bytes).

Bits that the manual leaves reserved are declared too (names starting with ``_``) so
that every bit of a pixel/header belongs to exactly one field and a decode → encode
round trip gives the packet back byte for byte.

Everything else (the NumPy structured dtype of a whole packet, decoding, encoding and
the digests in the tests) is derived from these tables.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cache, lru_cache

import numpy as np

from lidarpkt.errors import MetadataError, PacketFormatError
from .bitfield import BitField, check_cover, reserved_bits

# --------------------------------------------------------------------------- packet headers

#: Packet header of the non-legacy profiles (manual: "Lidar Data Packet Format", 256 bits).
STANDARD_HEADER: tuple[BitField, ...] = (
    BitField("packet_type", 0, 16),
    BitField("frame_id", 16, 16),
    BitField("init_id", 32, 24),
    BitField("prod_sn", 56, 40),
    BitField("alert_flags", 96, 8),  # firmware 3.x; reserved (zero) before
    *reserved_bits(104, 24),
    BitField("countdown_thermal_shutdown", 128, 8),
    BitField("countdown_shot_limiting", 136, 8),
    BitField("thermal_shutdown", 144, 4),
    *reserved_bits(148, 4),
    BitField("shot_limiting", 152, 4),
    *reserved_bits(156, 100),
)

#: Packet header of the FUSA profiles (firmware 3.1): other offsets, 32-bit frame id.
FUSA_HEADER: tuple[BitField, ...] = (
    BitField("packet_type", 0, 8),
    BitField("init_id", 8, 24),
    BitField("frame_id", 32, 32),
    BitField("alert_flags", 64, 8),
    *reserved_bits(72, 16),
    BitField("prod_sn", 88, 40),
    BitField("countdown_thermal_shutdown", 128, 8),
    BitField("countdown_shot_limiting", 136, 8),
    BitField("thermal_shutdown", 144, 4),
    *reserved_bits(148, 4),
    BitField("shot_limiting", 152, 4),
    *reserved_bits(156, 100),
)

HEADER_BYTES = 32
#: The status fields of the packet header (firmware 3.x; zero before), kept per column in ``Frame.extra``.
HEADER_STATUS_FIELDS = ("alert_flags", "shot_limiting", "thermal_shutdown", "countdown_shot_limiting",
                        "countdown_thermal_shutdown")
FOOTER_BYTES = 32
CRC_BYTES = 8

# --------------------------------------------------------------------------- column headers

#: (name, NumPy type, byte offset in the column). LEGACY: the status word follows the pixels.
LEGACY_COLUMN_HEADER = (("timestamp_ns", "<u8", 0), ("measurement_id", "<u2", 8), ("frame_id", "<u2", 10), ("encoder_count", "<u4", 12))
LEGACY_COLUMN_HEADER_BYTES = 16
LEGACY_COLUMN_STATUS = ("status", "<u4")  # after the pixels; 0xFFFFFFFF = valid
STANDARD_COLUMN_HEADER = (("timestamp_ns", "<u8", 0), ("measurement_id", "<u2", 8), ("status", "<u2", 10))
STANDARD_COLUMN_HEADER_BYTES = 12
LEGACY_STATUS_VALID = 0xFFFFFFFF

# --------------------------------------------------------------------------- pixels

_LEGACY_PIXEL = (
    BitField("RANGE", 0, 20),
    *reserved_bits(20, 8),
    BitField("FLAGS", 28, 4),
    BitField("REFLECTIVITY", 32, 8),
    *reserved_bits(40, 8),  # high byte of the 16-bit reflectivity word, not part of the field
    BitField("SIGNAL", 48, 16),
    BitField("NEAR_IR", 64, 16),
    *reserved_bits(80, 16),
)
_RNG19_PIXEL = (
    BitField("RANGE", 0, 19),
    BitField("FLAGS", 19, 5),
    *reserved_bits(24, 8),
    BitField("REFLECTIVITY", 32, 8),
    *reserved_bits(40, 8),
    BitField("SIGNAL", 48, 16),
    BitField("NEAR_IR", 64, 16),
    *reserved_bits(80, 8),
    BitField("WINDOW", 88, 8),
)
_RNG19_DUAL_FIRST_FOUR_WORDS = (
    BitField("RANGE", 0, 19),
    BitField("FLAGS", 19, 5),
    BitField("REFLECTIVITY", 24, 8),
    BitField("RANGE2", 32, 19),
    BitField("FLAGS2", 51, 5),
    BitField("REFLECTIVITY2", 56, 8),
    BitField("SIGNAL", 64, 16),
    BitField("SIGNAL2", 80, 16),
    BitField("NEAR_IR", 96, 16),
)
_RNG19_DUAL_PIXEL = (
    *_RNG19_DUAL_FIRST_FOUR_WORDS,
    *reserved_bits(112, 8),
    BitField("WINDOW", 120, 8),
)
_RNG15_PIXEL = (
    BitField("RANGE", 0, 15, 3),
    BitField("FLAGS", 15, 1),
    BitField("REFLECTIVITY", 16, 8),
    BitField("NEAR_IR", 24, 8, 4),
)
_RNG15_DUAL_PIXEL = (
    BitField("RANGE", 0, 15, 3),
    BitField("FLAGS", 15, 1),
    BitField("REFLECTIVITY", 16, 8),
    BitField("NEAR_IR", 24, 8, 4),
    BitField("RANGE2", 32, 15, 3),
    BitField("FLAGS2", 47, 1),
    BitField("REFLECTIVITY2", 48, 8),
    BitField("WINDOW", 56, 8),
)
_RNG15_ZONE16_PIXEL = (
    BitField("RANGE", 0, 15, 3),
    BitField("FLAGS", 15, 1),
    BitField("REFLECTIVITY", 16, 8),
    BitField("NEAR_IR", 24, 8, 4),
    BitField("ZONE_MASK", 32, 16),
    BitField("WINDOW", 48, 8),
    *reserved_bits(56, 8),
)
_RNG19_ZONE16_PIXEL = (
    BitField("RANGE", 0, 19),
    BitField("FLAGS", 19, 5),
    *reserved_bits(24, 8),
    BitField("REFLECTIVITY", 32, 8),
    BitField("WINDOW", 40, 8),
    BitField("SIGNAL", 48, 16),
    BitField("NEAR_IR", 64, 16),
    BitField("ZONE_MASK", 80, 16),
)
_RNG19_ZONE16_DUAL_PIXEL = (  # no NEAR_IR: the zone mask takes its place
    BitField("RANGE", 0, 19),
    BitField("FLAGS", 19, 5),
    BitField("REFLECTIVITY", 24, 8),
    BitField("RANGE2", 32, 19),
    BitField("FLAGS2", 51, 5),
    BitField("REFLECTIVITY2", 56, 8),
    BitField("SIGNAL", 64, 16),
    BitField("SIGNAL2", 80, 16),
    BitField("ZONE_MASK", 96, 16),
    *reserved_bits(112, 8),
    BitField("WINDOW", 120, 8),
)
_RNG19_RGB16_PIXEL = (
    BitField("RANGE", 0, 19),
    BitField("FLAGS", 19, 5),
    BitField("REFLECTIVITY", 24, 8),
    BitField("SIGNAL", 32, 16),
    BitField("NEAR_IR", 48, 16),
    BitField("R", 64, 16),
    BitField("G", 80, 16),
    BitField("B", 96, 16),
    *reserved_bits(112, 16),
)
_RNG19_RGB16_DUAL_PIXEL = (
    *_RNG19_DUAL_FIRST_FOUR_WORDS,
    BitField("R", 112, 16),
    BitField("G", 128, 16),
    BitField("B", 144, 16),
)
_FIVE_WORD_PIXEL = (*_RNG19_DUAL_FIRST_FOUR_WORDS, *reserved_bits(112, 48))
_RNG15_WIN8_PIXEL = (
    BitField("RANGE", 0, 15, 3),
    BitField("FLAGS", 15, 1),
    BitField("REFLECTIVITY", 16, 8),
    BitField("WINDOW", 24, 8),
)

#: Packet-header layouts by the metadata's ``header_type`` (firmware 3.2 names it; FUSA before it
#: was implied by the FUSA_RNG15_RFL8_NIR8_DUAL profile name).
HEADER_TYPES: dict[str, tuple[BitField, ...]] = {"STANDARD": STANDARD_HEADER, "FUSA": FUSA_HEADER}


@dataclass(frozen=True)
class Profile:
    """One lidar UDP profile.

    Attributes:
        name: ``udp_profile_lidar`` as the metadata spells it.
        pixel_bytes: bytes per pixel.
        pixel_fields: the pixel bit-field table.
        header_fields: packet-header bit-field table (empty for LEGACY).
        return_labels: meaning of each return slot (1 or 2).
        legacy: LEGACY layout (per-column frame id, encoder count and status word, no header/footer).
    """

    name: str
    pixel_bytes: int
    pixel_fields: tuple[BitField, ...]
    header_fields: tuple[BitField, ...] = ()
    return_labels: tuple[str, ...] = ("strongest",)
    legacy: bool = False

    def __hash__(self) -> int:
        # by name (equal profiles have equal names): the field-wise hash of the dataclass hashed every bit
        # field each time a profile keyed a cache, ~70 times per batch of packets decoded
        return hash(self.name)

    @property
    def header_type(self) -> str | None:
        """``"STANDARD"`` or ``"FUSA"`` (the packet-header layout), ``None`` for LEGACY (no header)."""
        for name, fields in HEADER_TYPES.items():
            if fields is self.header_fields:
                return name
        return None

    @property
    def header_status_bytes(self) -> tuple[int, int] | None:
        """``(first, end)`` bytes of the header that hold :data:`HEADER_STATUS_FIELDS`, ``None`` for LEGACY."""
        return _status_bytes(self.header_fields) if self.header_fields else None

    @property
    def header_bytes(self) -> int:
        return 0 if self.legacy else HEADER_BYTES

    @property
    def footer_bytes(self) -> int:
        return 0 if self.legacy else FOOTER_BYTES

    @property
    def column_header_bytes(self) -> int:
        return LEGACY_COLUMN_HEADER_BYTES if self.legacy else STANDARD_COLUMN_HEADER_BYTES

    @property
    def column_footer_bytes(self) -> int:
        return 4 if self.legacy else 0

    @property
    def returns(self) -> int:
        return len(self.return_labels)

    @property
    def field_names(self) -> tuple[str, ...]:
        """Pixel fields in table order, reserved ones left out."""
        return tuple(f.name for f in self.pixel_fields if not f.reserved)

    def field(self, name: str) -> BitField:
        for f in self.pixel_fields:
            if f.name == name:
                return f
        raise KeyError(f"profile {self.name} has no pixel field {name!r}")

    def column_bytes(self, pixels_per_column: int) -> int:
        return self.column_header_bytes + pixels_per_column * self.pixel_bytes + self.column_footer_bytes

    def packet_size(self, pixels_per_column: int, columns_per_packet: int = 16) -> int:
        """Bytes of one lidar packet (UDP payload)."""
        return self.header_bytes + columns_per_packet * self.column_bytes(pixels_per_column) + self.footer_bytes

    def column_dtype(self, pixels_per_column: int) -> np.dtype:
        """Structured dtype of one column; ``pixels`` is ``<u4[H, pixel_bytes // 4]`` (32-bit words)."""
        head = LEGACY_COLUMN_HEADER if self.legacy else STANDARD_COLUMN_HEADER
        names = [n for n, _, _ in head] + ["pixels"]
        formats = [t for _, t, _ in head] + [("<u4", (pixels_per_column, self.pixel_bytes // 4))]
        offsets = [o for _, _, o in head] + [self.column_header_bytes]
        if self.legacy:
            names.append(LEGACY_COLUMN_STATUS[0])
            formats.append(LEGACY_COLUMN_STATUS[1])
            offsets.append(self.column_header_bytes + pixels_per_column * self.pixel_bytes)
        return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": self.column_bytes(pixels_per_column)})

    def packet_dtype(self, pixels_per_column: int, columns_per_packet: int = 16) -> np.dtype:
        """Structured dtype of one packet: ``header`` bytes, ``columns[C]``, ``footer`` bytes."""
        return _packet_dtype(self, pixels_per_column, columns_per_packet)


@cache
def _status_bytes(header_fields: tuple[BitField, ...]) -> tuple[int, int]:
    bits = [(f.start_bit, f.start_bit + f.width) for f in header_fields if f.name in HEADER_STATUS_FIELDS]
    return min(b for b, _ in bits) // 8, -(-max(e for _, e in bits) // 8)


@lru_cache(maxsize=64)
def _packet_dtype(profile: Profile, h: int, c: int) -> np.dtype:
    names = ["header", "columns", "footer"]
    formats = [("u1", (profile.header_bytes,)), (profile.column_dtype(h), (c,)), ("u1", (profile.footer_bytes,))]
    offsets = [0, profile.header_bytes, profile.header_bytes + c * profile.column_bytes(h)]
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": profile.packet_size(h, c)})


_DUAL = ("strongest", "second_strongest")
LEGACY = Profile("LEGACY", 12, _LEGACY_PIXEL, legacy=True)
RNG19_RFL8_SIG16_NIR16 = Profile("RNG19_RFL8_SIG16_NIR16", 12, _RNG19_PIXEL, STANDARD_HEADER)
RNG19_RFL8_SIG16_NIR16_DUAL = Profile("RNG19_RFL8_SIG16_NIR16_DUAL", 16, _RNG19_DUAL_PIXEL, STANDARD_HEADER, _DUAL)
RNG15_RFL8_NIR8 = Profile("RNG15_RFL8_NIR8", 4, _RNG15_PIXEL, STANDARD_HEADER)
RNG15_RFL8_NIR8_DUAL = Profile("RNG15_RFL8_NIR8_DUAL", 8, _RNG15_DUAL_PIXEL, STANDARD_HEADER, _DUAL)
# the deprecated name of RNG15_RFL8_NIR8_DUAL under a FUSA header (firmware 3.1)
FUSA_RNG15_RFL8_NIR8_DUAL = Profile("FUSA_RNG15_RFL8_NIR8_DUAL", 8, _RNG15_DUAL_PIXEL, FUSA_HEADER, _DUAL)
RNG15_RFL8_NIR8_ZONE16 = Profile("RNG15_RFL8_NIR8_ZONE16", 8, _RNG15_ZONE16_PIXEL, STANDARD_HEADER)
RNG19_RFL8_SIG16_NIR16_ZONE16 = Profile("RNG19_RFL8_SIG16_NIR16_ZONE16", 12, _RNG19_ZONE16_PIXEL, STANDARD_HEADER)
RNG19_RFL8_SIG16_ZONE16_DUAL = Profile("RNG19_RFL8_SIG16_ZONE16_DUAL", 16, _RNG19_ZONE16_DUAL_PIXEL, STANDARD_HEADER, _DUAL)
RNG19_RFL8_SIG16_NIR16_RGB16 = Profile("RNG19_RFL8_SIG16_NIR16_RGB16", 16, _RNG19_RGB16_PIXEL, STANDARD_HEADER)
RNG19_RFL8_SIG16_NIR16_RGB16_DUAL = Profile(
    "RNG19_RFL8_SIG16_NIR16_RGB16_DUAL", 20, _RNG19_RGB16_DUAL_PIXEL, STANDARD_HEADER, _DUAL)
RNG15_RFL8_WIN8 = Profile("RNG15_RFL8_WIN8", 4, _RNG15_WIN8_PIXEL, STANDARD_HEADER)
FIVE_WORD_PIXEL = Profile("FIVE_WORD_PIXEL", 20, _FIVE_WORD_PIXEL, STANDARD_HEADER, _DUAL)

PROFILES: dict[str, Profile] = {
    p.name: p
    for p in (
        LEGACY,
        RNG19_RFL8_SIG16_NIR16,
        RNG19_RFL8_SIG16_NIR16_DUAL,
        RNG15_RFL8_NIR8,
        RNG15_RFL8_NIR8_DUAL,
        FUSA_RNG15_RFL8_NIR8_DUAL,
        RNG15_RFL8_NIR8_ZONE16,
        RNG19_RFL8_SIG16_NIR16_ZONE16,
        RNG19_RFL8_SIG16_ZONE16_DUAL,
        RNG19_RFL8_SIG16_NIR16_RGB16,
        RNG19_RFL8_SIG16_NIR16_RGB16_DUAL,
        RNG15_RFL8_WIN8,
        FIVE_WORD_PIXEL,
    )
}

for _p in PROFILES.values():
    check_cover(_p.pixel_fields, _p.pixel_bytes * 8, f"{_p.name} pixel")
    if _p.header_fields:
        check_cover(_p.header_fields, HEADER_BYTES * 8, f"{_p.name} header")
    for _f in _p.pixel_fields:  # decode reads each pixel field from one 32-bit word
        if _f.start_bit // 32 != (_f.start_bit + _f.width - 1) // 32:
            raise PacketFormatError(f"{_p.name} pixel: field {_f.name} straddles a 32-bit word")


@cache
def with_header(profile: Profile, header_type: str) -> Profile:
    """``profile`` under the packet header ``header_type`` (``"STANDARD"`` or ``"FUSA"``); LEGACY has none.

    The same object for the same arguments (decoders key caches by profile).

    Raises:
        MetadataError: ``header_type`` is neither.
    """
    if profile.legacy:
        return profile
    try:
        header = HEADER_TYPES[header_type]
    except KeyError:
        raise MetadataError(f"header_type {header_type!r} is not supported; supported: {', '.join(HEADER_TYPES)}") from None
    return profile if header is profile.header_fields else replace(profile, header_fields=header)


#: pixels per column of the layouts a stream without metadata is compared with (``lidarpkt info``'s guess)
GUESS_ROWS = (16, 32, 64, 128)


@cache
def guessable_packet_sizes() -> frozenset[int]:
    """Sizes (bytes) of a lidar packet of every profile with :data:`GUESS_ROWS` pixels and 16 columns: the
    only sizes a stream without metadata can be guessed to be Ouster lidar packets at."""
    return frozenset(p.packet_size(h, 16) for p in PROFILES.values() for h in GUESS_ROWS)


def get_profile(name: str) -> Profile:
    """The :class:`Profile` called ``name``; :class:`MetadataError` for profiles not supported."""
    try:
        return PROFILES[name]
    except KeyError:
        raise MetadataError(
            f"udp_profile_lidar {name!r} is not supported; supported profiles: {', '.join(PROFILES)}"
        ) from None
