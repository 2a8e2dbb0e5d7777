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

# --------------------------------------------------------------------------- bit fields


@dataclass(frozen=True)
class BitField:
    """One field of a little-endian bit-packed record.

    Attributes:
        name: the manual's field name (``RANGE``, ``FLAGS`` ...); ``_``-prefixed = reserved bits.
        start_bit: offset of the least significant bit from the start of the record.
        width: number of bits on the wire.
        upshift: left shift applied after extraction to get the field's unit (RANGE of
            RNG15_RFL8_NIR8 is in 8 mm steps: upshift 3 gives mm).
    """

    name: str
    start_bit: int
    width: int
    upshift: int = 0

    @property
    def reserved(self) -> bool:
        return self.name.startswith("_")

    @property
    def dtype(self) -> np.dtype:
        """Smallest unsigned type holding ``width + upshift`` bits (as ouster-sdk's field types)."""
        bits = self.width + self.upshift
        for dt in (np.uint8, np.uint16, np.uint32, np.uint64):
            if bits <= np.dtype(dt).itemsize * 8:
                return np.dtype(dt)
        raise ValueError(f"bit field {self.name} is wider than 64 bits")

    @property
    def mask(self) -> int:
        return (1 << self.width) - 1


def _check_cover(fields: tuple[BitField, ...], n_bits: int, what: str) -> None:
    """Every bit of the record belongs to exactly one field (checked at import)."""
    used = np.zeros(n_bits, np.int32)
    for f in fields:
        if f.start_bit + f.width > n_bits or f.width <= 0:
            raise PacketFormatError(f"{what}: field {f.name} outside the record")
        used[f.start_bit : f.start_bit + f.width] += 1
    if not np.all(used == 1):
        raise PacketFormatError(f"{what}: bits {np.flatnonzero(used != 1).tolist()} not covered exactly once")


def _reserved(start_bit: int, width: int) -> tuple[BitField, ...]:
    """Reserved bits split into ≤ 32-bit pieces (so any field fits a 64-bit read)."""
    out = []
    while width > 0:
        w = min(32, width, 32 - start_bit % 32) if start_bit % 32 else min(32, width)
        out.append(BitField(f"_reserved_{start_bit}", start_bit, w))
        start_bit += w
        width -= w
    return tuple(out)


# --------------------------------------------------------------------------- packet headers

#: Packet header of the non-legacy profiles (manual: "Lidar Data Packet Format", 256 bits).
STANDARD_HEADER: tuple[BitField, ...] = (
    BitField("packet_type", 0, 16),
    BitField("frame_id", 16, 16),
    BitField("init_id", 32, 24),
    BitField("prod_sn", 56, 40),
    BitField("alert_flags", 96, 8),  # firmware 3.x; reserved (zero) before
    *_reserved(104, 24),
    BitField("countdown_thermal_shutdown", 128, 8),
    BitField("countdown_shot_limiting", 136, 8),
    BitField("thermal_shutdown", 144, 4),
    *_reserved(148, 4),
    BitField("shot_limiting", 152, 4),
    *_reserved(156, 100),
)

#: Packet header of the FUSA profiles (firmware 3.1): other offsets, 32-bit frame id.
FUSA_HEADER: tuple[BitField, ...] = (
    BitField("packet_type", 0, 8),
    BitField("init_id", 8, 24),
    BitField("frame_id", 32, 32),
    BitField("alert_flags", 64, 8),
    *_reserved(72, 16),
    BitField("prod_sn", 88, 40),
    BitField("countdown_thermal_shutdown", 128, 8),
    BitField("countdown_shot_limiting", 136, 8),
    BitField("thermal_shutdown", 144, 4),
    *_reserved(148, 4),
    BitField("shot_limiting", 152, 4),
    *_reserved(156, 100),
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
    *_reserved(20, 8),
    BitField("FLAGS", 28, 4),
    BitField("REFLECTIVITY", 32, 8),
    *_reserved(40, 8),  # high byte of the 16-bit reflectivity word, not part of the field
    BitField("SIGNAL", 48, 16),
    BitField("NEAR_IR", 64, 16),
    *_reserved(80, 16),
)
_RNG19_PIXEL = (
    BitField("RANGE", 0, 19),
    BitField("FLAGS", 19, 5),
    *_reserved(24, 8),
    BitField("REFLECTIVITY", 32, 8),
    *_reserved(40, 8),
    BitField("SIGNAL", 48, 16),
    BitField("NEAR_IR", 64, 16),
    *_reserved(80, 8),
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
    *_reserved(112, 8),
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
    *_reserved(56, 8),
)
_RNG19_ZONE16_PIXEL = (
    BitField("RANGE", 0, 19),
    BitField("FLAGS", 19, 5),
    *_reserved(24, 8),
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
    *_reserved(112, 8),
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
    *_reserved(112, 16),
)
_RNG19_RGB16_DUAL_PIXEL = (
    *_RNG19_DUAL_FIRST_FOUR_WORDS,
    BitField("R", 112, 16),
    BitField("G", 128, 16),
    BitField("B", 144, 16),
)
_FIVE_WORD_PIXEL = (*_RNG19_DUAL_FIRST_FOUR_WORDS, *_reserved(112, 48))
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
    _check_cover(_p.pixel_fields, _p.pixel_bytes * 8, f"{_p.name} pixel")
    if _p.header_fields:
        _check_cover(_p.header_fields, HEADER_BYTES * 8, f"{_p.name} header")
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


def get_profile(name: str) -> Profile:
    """The :class:`Profile` called ``name``; :class:`MetadataError` for profiles not supported."""
    try:
        return PROFILES[name]
    except KeyError:
        raise MetadataError(
            f"udp_profile_lidar {name!r} is not supported; supported profiles: {', '.join(PROFILES)}"
        ) from None


# --------------------------------------------------------------------------- IMU

#: LEGACY IMU packet (48 bytes): three timestamps (ns), acceleration (g), angular velocity (deg/s).
IMU_DTYPE = np.dtype(
    [
        ("sys_timestamp_ns", "<u8"),
        ("accel_timestamp_ns", "<u8"),
        ("gyro_timestamp_ns", "<u8"),
        ("accel_x_g", "<f4"),
        ("accel_y_g", "<f4"),
        ("accel_z_g", "<f4"),
        ("gyro_x_deg_per_s", "<f4"),
        ("gyro_y_deg_per_s", "<f4"),
        ("gyro_z_deg_per_s", "<f4"),
    ]
)
IMU_PACKET_SIZE = IMU_DTYPE.itemsize

#: IMU profiles of the metadata's ``udp_profile_imu``.
IMU_PROFILES = ("LEGACY", "ACCEL32_GYRO32_NMEA")

#: ACCEL32_GYRO32_NMEA (firmware 3.x): the 32-byte packet header of the lidar packets, this NMEA block,
#: ``imu_measurements_per_packet`` measurements of :data:`IMU_MEASUREMENT_DTYPE`, the 32-byte footer.
#: The sentence is NUL-padded ASCII (the last NMEA sentence the sensor received, empty without one).
IMU_NMEA_BLOCK_DTYPE = np.dtype(
    {"names": ["nmea_timestamp_ns", "nmea_sentence"], "formats": ["<u8", "S85"], "offsets": [0, 8], "itemsize": 100}
)
#: One ACCEL32_GYRO32_NMEA measurement: a column-like header (status bit 0 = valid), acceleration in m/s²
#: and angular velocity in rad/s (float32; the LEGACY packet's are in g and deg/s).
IMU_MEASUREMENT_DTYPE = np.dtype(
    [
        ("timestamp_ns", "<u8"),
        ("measurement_id", "<u2"),
        ("status", "<u2"),
        ("accel_x_mps2", "<f4"),
        ("accel_y_mps2", "<f4"),
        ("accel_z_mps2", "<f4"),
        ("gyro_x_radps", "<f4"),
        ("gyro_y_radps", "<f4"),
        ("gyro_z_radps", "<f4"),
    ]
)


def imu_packet_dtype(measurements: int) -> np.dtype:
    """Structured dtype of one ACCEL32_GYRO32_NMEA packet holding ``measurements`` measurements."""
    return _imu_packet_dtype(int(measurements))


@lru_cache(maxsize=16)
def _imu_packet_dtype(m: int) -> np.dtype:
    nmea_at = HEADER_BYTES
    meas_at = nmea_at + IMU_NMEA_BLOCK_DTYPE.itemsize
    footer_at = meas_at + m * IMU_MEASUREMENT_DTYPE.itemsize
    return np.dtype(
        {
            "names": ["header", "nmea", "measurements", "footer"],
            "formats": [("u1", (HEADER_BYTES,)), IMU_NMEA_BLOCK_DTYPE, (IMU_MEASUREMENT_DTYPE, (m,)), ("u1", (FOOTER_BYTES,))],
            "offsets": [0, nmea_at, meas_at, footer_at],
            "itemsize": footer_at + FOOTER_BYTES,
        }
    )


# --------------------------------------------------------------------------- zone monitoring

ZONES_PER_PACKET = 16
ZONESET_HASH_BYTES = 32
#: One zone's state in a zone-monitoring packet (36 bytes); the ranges are in mm like RANGE.
ZONE_STATE_FIELDS: tuple[BitField, ...] = (
    BitField("live", 0, 1),
    *_reserved(1, 7),
    BitField("id", 8, 8),
    BitField("error_flags", 16, 8),
    *_reserved(24, 2),
    BitField("trigger_type", 26, 2),
    *_reserved(28, 3),
    BitField("trigger_status", 31, 1),
    BitField("triggered_frames", 32, 32),
    BitField("count", 64, 32),
    BitField("occlusion_count", 96, 32),
    BitField("invalid_count", 128, 32),
    BitField("max_count", 160, 32),
    BitField("min_range_mm", 192, 19),
    *_reserved(211, 13),
    BitField("max_range_mm", 224, 19),
    *_reserved(243, 13),
    BitField("mean_range_mm", 256, 19),
    *_reserved(275, 13),
)
ZONE_STATE_BYTES = 36
_check_cover(ZONE_STATE_FIELDS, ZONE_STATE_BYTES * 8, "zone state")
#: Zone-monitoring packet: packet header, timestamp (ns), SHA-256 of the live zone set, 16 zone states, footer.
ZONE_PACKET_DTYPE = np.dtype(
    {
        "names": ["header", "timestamp_ns", "live_zoneset_hash", "zones", "footer"],
        "formats": [("u1", (HEADER_BYTES,)), "<u8", ("u1", (ZONESET_HASH_BYTES,)),
                    ("u1", (ZONES_PER_PACKET, ZONE_STATE_BYTES)), ("u1", (FOOTER_BYTES,))],
        "offsets": [0, HEADER_BYTES, HEADER_BYTES + 8, HEADER_BYTES + 8 + ZONESET_HASH_BYTES,
                    HEADER_BYTES + 8 + ZONESET_HASH_BYTES + ZONES_PER_PACKET * ZONE_STATE_BYTES],
        "itemsize": HEADER_BYTES + 8 + ZONESET_HASH_BYTES + ZONES_PER_PACKET * ZONE_STATE_BYTES + FOOTER_BYTES,
    }
)
ZONE_PACKET_SIZE = ZONE_PACKET_DTYPE.itemsize


# --------------------------------------------------------------------------- bit access helpers


def read_bits(data: np.ndarray, field: BitField) -> np.ndarray:
    """Field ``field`` of byte records ``data`` (``uint8[..., nbytes]``), up-shift applied, in ``field.dtype``."""
    first = field.start_bit // 8
    shift = field.start_bit % 8
    nbytes = (shift + field.width + 7) // 8
    if nbytes == 1:  # within one byte (the header's status fields, read for every packet decoded)
        v = data[..., first]
        if shift:
            v = v >> np.uint8(shift)
        if field.width < 8:
            v = v & np.uint8(field.mask)
        v = v.astype(field.dtype)
        return v << field.dtype.type(field.upshift) if field.upshift else v
    acc = np.zeros(data.shape[:-1], np.uint64)
    for k in range(nbytes):
        acc |= data[..., first + k].astype(np.uint64) << np.uint64(8 * k)
    value = (acc >> np.uint64(shift)) & np.uint64(field.mask)
    return value.astype(field.dtype) << field.dtype.type(field.upshift) if field.upshift else value.astype(field.dtype)


def write_bits(data: np.ndarray, field: BitField, value: np.ndarray) -> None:
    """OR ``value`` (in field units, up-shift included) into the zeroed bits of ``data`` (``uint8[..., nbytes]``)."""
    raw = _to_raw(np.asarray(value), field)
    first = field.start_bit // 8
    shift = field.start_bit % 8
    nbytes = (shift + field.width + 7) // 8
    raw = raw << np.uint64(shift)
    for k in range(nbytes):
        data[..., first + k] |= ((raw >> np.uint64(8 * k)) & np.uint64(0xFF)).astype(np.uint8)


def _to_raw(value: np.ndarray, field: BitField) -> np.ndarray:
    """The wire value of ``value``; :class:`PacketFormatError` if it does not fit the field exactly."""
    from lidarpkt.errors import PacketFormatError

    v = value.astype(np.uint64)
    if field.upshift and np.any(v & np.uint64((1 << field.upshift) - 1)):
        raise PacketFormatError(
            f"field {field.name}: values must be multiples of {1 << field.upshift} "
            f"(the wire unit); got e.g. {int(v[(v & np.uint64((1 << field.upshift) - 1)) != 0].flat[0])}"
        )
    raw = v >> np.uint64(field.upshift)
    if np.any(raw > np.uint64(field.mask)):
        raise PacketFormatError(
            f"field {field.name}: value {int(raw.max()) << field.upshift} does not fit in {field.width} bits"
            + (f" × {1 << field.upshift}" if field.upshift else "")
        )
    return raw
