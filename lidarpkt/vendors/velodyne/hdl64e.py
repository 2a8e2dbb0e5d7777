"""HDL-64E S2/S3: the status cycle of its data packets, and the calibration it carries.

An HDL-64E packet ends with a status type byte (1204) and a status value byte (1205) where the
other models put the return mode and the factory byte. Types ``H M S D N Y G`` (GPS time and
date), ``T`` (temperature) and ``V`` (firmware version) are status; the values of every other type
(the S3's ``W`` warning byte among them) are, one per packet, the bytes of the unit's parameter
block: 1820 bytes that begin with ``UNIT#``, then the upper and lower block noise thresholds,
64 laser records of 28 bytes (the first 21 used) and a 21-byte tail (calibration date, humidity,
RPM, field of view, IP addresses, return mode, power level, status), the last two bytes a CRC-16
(S3) or the block's length, 1820 (S2).

A laser record, little-endian: laser id u8, vertical correction i16 (0.01°), rotational
correction i16 (0.01°), far distance correction i16 (mm), distance correction x and y i16 (mm),
vertical and horizontal offset i16 (mm), focal distance i16 (mm), focal slope i16 (0.1), minimum
and maximum intensity u8. The reading (which types are status, the units, the CRC: polynomial
0x8005, initial value 0, not reflected, over bytes 1–20 of each laser record) follows
velodyne_decoder 3.1.0's ``hdl64e`` module, the reference this is tested against.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np

from .calibration import VelodyneCalibration

STATUS_TYPES = b"HMSDNYGTV"
UNIT_PARAMETERS_SIZE = 1820
HEAD_SIZE = 7  # "UNIT#", upper and lower noise thresholds
LASER_RECORD_SIZE = 28
LASER_FIELDS = struct.Struct("<BhhhhhhhhhBB")  # the 21 used bytes of a laser record
TAIL_SIZE = 21
TOKEN = b"UNIT#"


def crc16(data: bytes) -> int:
    """CRC-16 with polynomial 0x8005, initial value 0, not reflected, no final XOR (the S3's checksum)."""
    reg = 0
    for octet in data:
        reg ^= octet << 8
        for _ in range(8):
            reg = ((reg << 1) ^ 0x8005) if reg & 0x8000 else reg << 1
            reg &= 0xFFFF
    return reg


def _laser_records(block: bytes) -> list[bytes]:
    body = block[HEAD_SIZE:UNIT_PARAMETERS_SIZE - TAIL_SIZE]
    return [body[i:i + LASER_RECORD_SIZE] for i in range(0, len(body), LASER_RECORD_SIZE)]


def checksum_ok(block: bytes, s3: bool) -> bool:
    """Whether a 1820-byte parameter block's last two bytes are its CRC-16 (S3) or its length (S2)."""
    stored = struct.unpack_from("<H", block, UNIT_PARAMETERS_SIZE - 2)[0]
    if not s3:
        return stored == UNIT_PARAMETERS_SIZE
    return stored == crc16(b"".join(r[1:21] for r in _laser_records(block)))


def parse_unit_parameters(block: bytes, source: str = "HDL-64E status cycle") -> VelodyneCalibration:
    """The calibration in a 1820-byte parameter block (starting at ``UNIT#``), in SI units."""
    rows = [LASER_FIELDS.unpack(r[:21]) for r in _laser_records(block)]
    a = np.array(rows, dtype=np.float64)  # [64, 12]
    order = np.argsort(a[:, 0], kind="stable")  # by laser id
    a = a[order]
    return VelodyneCalibration(
        vert_correction_rad=np.radians(a[:, 1] * 0.01), rot_correction_rad=np.radians(a[:, 2] * 0.01),
        dist_correction_m=a[:, 3] * 0.001, dist_correction_x_m=a[:, 4] * 0.001, dist_correction_y_m=a[:, 5] * 0.001,
        vert_offset_m=a[:, 6] * 0.001, horiz_offset_m=a[:, 7] * 0.001, focal_distance_m=a[:, 8] * 0.001,
        focal_slope=a[:, 9] * 0.1, min_intensity=a[:, 10], max_intensity=a[:, 11], distance_resolution_m=0.002,
        source=source)


@dataclass
class StatusCycle:
    """Collects the status bytes of consecutive HDL-64E packets until a whole parameter block passed.

    ``status`` holds the last value of each status type (``{"T": 31, ...}``); :attr:`calibration` the
    calibration once a block with a good checksum was read (``None`` before)."""

    status: dict[str, int] = field(default_factory=dict)
    calibration: VelodyneCalibration | None = None
    bad_blocks: int = 0
    _bytes: bytearray = field(default_factory=bytearray)

    @property
    def s3(self) -> bool:
        """An S3 (its cycle carries the ``W`` warning byte)."""
        return "W" in self.status

    def push(self, status_type: np.ndarray, status_value: np.ndarray) -> VelodyneCalibration | None:
        """Feed the status bytes of packets in order (``uint8[N]`` each); returns the calibration when known."""
        if self.calibration is not None:
            return self.calibration
        types = np.asarray(status_type, np.uint8)
        values = np.asarray(status_value, np.uint8)
        is_status = np.isin(types, np.frombuffer(STATUS_TYPES + b"W", np.uint8))
        for t in np.unique(types[is_status]).tolist():
            self.status[chr(t)] = int(values[np.flatnonzero(types == t)[-1]])
        self._bytes += values[~is_status | (types == ord("W"))].tobytes()
        while len(self._bytes) >= UNIT_PARAMETERS_SIZE and self.calibration is None:
            start = self._bytes.find(TOKEN)
            if start < 0:
                del self._bytes[:len(self._bytes) - len(TOKEN) + 1]  # keep a token cut at the end
                break
            if len(self._bytes) - start < UNIT_PARAMETERS_SIZE:
                del self._bytes[:start]
                break
            block = bytes(self._bytes[start:start + UNIT_PARAMETERS_SIZE])
            if checksum_ok(block, self.s3):
                self.calibration = parse_unit_parameters(block)
                self._bytes.clear()
            else:
                self.bad_blocks += 1
                del self._bytes[:start + len(TOKEN)]
        return self.calibration


#: The tail a block is encoded with by default: 600 RPM, field of view 0–360°, 100 hours, source and
#: destination addresses 192.168.3.43 and .255, strongest return, status 0, power level 0xA0.
DEFAULT_TAIL = struct.pack("<hHHH4B4BBBB", 600, 0, 36000, 100, 192, 168, 3, 43, 192, 168, 3, 255, 0, 0, 0xA0)
#: Calibration date (2016-11-15 12:47:47) and humidity (25 %), kept in the last laser record's unused bytes.
DEFAULT_DATE = bytes([16, 11, 15, 12, 47, 47, 25])


def encode_unit_parameters(calibration: VelodyneCalibration, *, s3: bool = True, noise: tuple[int, int] = (24, 24),
                           tail: bytes = DEFAULT_TAIL, date: bytes = DEFAULT_DATE) -> bytes:
    """The 1820-byte parameter block of ``calibration`` (the inverse of :func:`parse_unit_parameters`,
    values rounded to the block's units): for the encoder and the tests. ``tail``: the 19 bytes between the
    laser records and the checksum; ``date``: the calibration date and humidity in the last record's
    unused 7 bytes."""
    c = calibration
    vert, rot, dist = np.asarray(c.vert_correction_rad), np.asarray(c.rot_correction_rad), np.asarray(c.dist_correction_m)
    dx, dy = np.asarray(c.dist_correction_x_m), np.asarray(c.dist_correction_y_m)
    voff, hoff = np.asarray(c.vert_offset_m), np.asarray(c.horiz_offset_m)
    fd, fs = np.asarray(c.focal_distance_m), np.asarray(c.focal_slope)
    imin, imax = np.asarray(c.min_intensity), np.asarray(c.max_intensity)
    records = []
    for i in range(64):
        values = (i, round(np.degrees(vert[i]) * 100), round(np.degrees(rot[i]) * 100), round(dist[i] * 1000),
                  round(dx[i] * 1000), round(dy[i] * 1000), round(voff[i] * 1000), round(hoff[i] * 1000),
                  round(fd[i] * 1000), round(fs[i] * 10), int(imin[i]), int(imax[i]))
        records.append(LASER_FIELDS.pack(*values) + (date if i == 63 else bytes(LASER_RECORD_SIZE - 21)))
    head = TOKEN + bytes(noise)
    body = b"".join(records)
    check = crc16(b"".join(r[1:21] for r in records)) if s3 else UNIT_PARAMETERS_SIZE
    block = head + body + tail + struct.pack("<H", check)
    if len(block) != UNIT_PARAMETERS_SIZE:
        raise ValueError(f"a parameter block of {len(block)} bytes: the tail must have {TAIL_SIZE - 2}")
    return block


def status_bytes(block: bytes, n: int, *, s3: bool = True, offset: int = 0, temperature: int = 31,
                 version: int = 0x26) -> tuple[np.ndarray, np.ndarray]:
    """``n`` packets' (status type, status value) bytes cycling through ``block``: cycles of 16 packets, the
    status types H M S D N Y G T V first, then 7 bytes of the block (the S3's first of them typed ``W``, the
    others ``0x00``); ``offset`` starts the stream inside the block."""
    types = np.zeros(n, np.uint8)
    values = np.zeros(n, np.uint8)
    pos = offset
    status = {"H": 12, "M": 30, "S": 5, "D": 26, "N": 11, "Y": 26, "G": 65, "T": temperature, "V": version}
    for i in range(n):
        k = i % 16
        if k < 9:
            t = STATUS_TYPES[k]
            types[i], values[i] = t, status[chr(t)]
        else:
            types[i] = ord("W") if s3 and k == 9 else 0x00
            values[i] = block[pos % UNIT_PARAMETERS_SIZE]
            pos += 1
    return types, values
