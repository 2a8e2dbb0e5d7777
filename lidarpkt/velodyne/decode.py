"""Batch decoding of VLP-16 payloads into raw field arrays, in the manual's units.

One NumPy pass per batch: the payload array is viewed through the dtypes of
:mod:`lidarpkt.velodyne.packet` and each field is copied out as a whole column.
Frame assembly (:mod:`lidarpkt.velodyne.frames`) and the encoder work from these arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import kernels

from .packet import BLOCK_FLAG, as_data_packets, as_position_packets


@dataclass(eq=False)
class DataPackets:
    """Raw fields of N data packets, exactly as sent (no unit conversion beyond the wire's own).

    Attributes:
        flag: ``uint16[N, 12]`` block flags (0xEEFF on a VLP-16).
        azimuth_cdeg: ``uint16[N, 12]`` block azimuth, hundredths of a degree.
        distance_2mm: ``uint16[N, 12, 32]`` distance in 2 mm units, 0 = no return.
        reflectivity: ``uint8[N, 12, 32]`` calibrated reflectivity (0–100 diffuse, 101–255 retro-reflector).
        timestamp_us: ``uint32[N]`` µs past the top of the hour of the first firing.
        return_mode: ``uint8[N]`` 0x37 strongest, 0x38 last, 0x39 dual.
        product_id: ``uint8[N]`` 0x22 (VLP-16), 0x21 on early VLP-16 units.
    """

    flag: np.ndarray
    azimuth_cdeg: np.ndarray
    distance_2mm: np.ndarray
    reflectivity: np.ndarray
    timestamp_us: np.ndarray
    return_mode: np.ndarray
    product_id: np.ndarray

    def __len__(self) -> int:
        return int(self.timestamp_us.shape[0])

    @property
    def flag_ok(self) -> np.ndarray:
        """``bool[N]``: every block of the packet carries the 0xEEFF flag and an azimuth ≤ 36000.

        36000 (= 0°) does occur in real early-firmware packets (the VeloView capture), so it is accepted.
        """
        return np.all((self.flag == BLOCK_FLAG) & (self.azimuth_cdeg <= 36000), axis=1)

    @property
    def range_mm(self) -> np.ndarray:
        """``uint32[N, 12, 32]`` distance in millimetres (2 mm units × 2, exact)."""
        return self.distance_2mm.astype(np.uint32) << 1

    def select(self, rows: np.ndarray | slice) -> "DataPackets":
        """The chosen packets (boolean mask, indices or a slice)."""
        return DataPackets(**{k: getattr(self, k)[rows] for k in self.__dataclass_fields__})


@dataclass(eq=False)
class PositionPackets:
    """Raw fields of N position packets.

    Attributes:
        timestamp_us: ``uint32[N]`` µs past the hour.
        pps_status: ``uint8[N]`` 0 absent, 1 synchronizing, 2 locked, 3 error.
        thermal_status, last_shutdown_temperature, powerup_temperature: ``uint8[N]`` (newer firmware; 0 on old).
        nmea: ``uint8[N, 128]`` the NUL-padded NMEA sentence bytes.
        unused_head: ``uint8[N, 198]``, unused_tail: ``uint8[N, 178]``: the unused bytes, kept for
            byte-exact re-encoding (the HDL-32E puts gyro data in the head).
    """

    timestamp_us: np.ndarray
    pps_status: np.ndarray
    thermal_status: np.ndarray
    last_shutdown_temperature: np.ndarray
    powerup_temperature: np.ndarray
    nmea: np.ndarray
    unused_head: np.ndarray
    unused_tail: np.ndarray

    def __len__(self) -> int:
        return int(self.timestamp_us.shape[0])

    def sentences(self) -> list[str]:
        """The NMEA sentences as text, NUL padding and the trailing CR LF removed ('' where empty)."""
        out = []
        for row in self.nmea:
            raw = row.tobytes().split(b"\x00", 1)[0]
            out.append(raw.decode("ascii", errors="replace").rstrip("\r\n"))
        return out


def decode_packets(payload: np.ndarray, *, copy: bool = True) -> DataPackets:
    """Every field of ``uint8[N, 1206]`` VLP-16 data payloads as arrays (see :class:`DataPackets`).

    No validation beyond the size: check :attr:`DataPackets.flag_ok` to find malformed packets.
    ``copy=False`` returns strided (unaligned) views into ``payload`` instead of compact arrays:
    no copy, for callers that read each field once (the frame assembler).
    Raises :class:`~lidarpkt.errors.PacketFormatError` if the payload is not ``[N, 1206]``.
    """
    pk = as_data_packets(payload)
    blocks = pk["blocks"]
    channels = blocks["channels"]
    if not copy:
        return DataPackets(
            flag=blocks["flag"], azimuth_cdeg=blocks["azimuth_cdeg"], distance_2mm=channels["distance_2mm"],
            reflectivity=channels["reflectivity"], timestamp_us=pk["timestamp_us"], return_mode=pk["return_mode"],
            product_id=pk["product_id"],
        )
    return DataPackets(
        flag=blocks["flag"].astype(np.uint16),
        azimuth_cdeg=blocks["azimuth_cdeg"].astype(np.uint16),
        distance_2mm=channels["distance_2mm"].astype(np.uint16),
        reflectivity=channels["reflectivity"].astype(np.uint8),
        timestamp_us=pk["timestamp_us"].astype(np.uint32),
        return_mode=pk["return_mode"].astype(np.uint8),
        product_id=pk["product_id"].astype(np.uint8),
    )


def decode_position_packets(payload: np.ndarray) -> PositionPackets:
    """Every field of ``uint8[N, 512]`` VLP-16 position payloads (see :class:`PositionPackets`).

    Raises :class:`~lidarpkt.errors.PacketFormatError` if the payload is not ``[N, 512]``.
    """
    pk = as_position_packets(payload)
    return PositionPackets(**{name: np.array(pk[name]) for name in pk.dtype.names or ()})  # structured: names set


def column_pixels(raw: DataPackets, firing_azimuth_cdeg: np.ndarray, row_laser: np.ndarray, slots: int,
                  sequences: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pixels of a batch as range-image columns: ``range_mm`` ``uint32[slots, 16, W]`` (2 × the
    wire's distance), ``reflectivity`` ``uint8[slots, 16, W]`` and per-firing ``azimuth`` ``uint16[16, W]``
    (from ``firing_azimuth_cdeg``, ``[N, 12 / slots, 32]``), W = N · (12 / slots) · 2; row r is laser
    ``row_laser[r]``; dual packets (``slots`` 2) put block b in slot b % 2.

    Compiled (``lidarpkt._native.velodyne_columns``, one pass a packet at a time) when it is built;
    the NumPy twin makes two passes: the strided 3-byte records copied once into [slot, column,
    laser] order (long inner loops), then per row one gather of a laser column (16 small ufunc
    calls); gathering each row straight from the packets walked inner loops of 2 elements and was
    1.7x slower.
    """
    n, blocks, channels = raw.distance_2mm.shape
    lasers = channels // sequences
    w0 = n * (blocks // slots) * sequences
    rng = np.empty((slots, lasers, w0), np.uint32)
    refl = np.empty((slots, lasers, w0), np.uint8)
    az_px = np.empty((lasers, w0), np.uint16)
    native = kernels.native
    if native is not None and (lasers, blocks, sequences) == (16, 12, 2):
        native.velodyne_columns(raw.distance_2mm, raw.reflectivity, firing_azimuth_cdeg,
                                np.ascontiguousarray(row_laser, np.int64), slots, rng, refl, az_px)
        return rng, refl, az_px
    # [n, blocks per slot, slots, 2 seq, 16 lasers] → [slots, n, blocks per slot, 2 seq, 16 lasers]
    split = (n, blocks // slots, slots, sequences, lasers)
    d = np.empty((slots, n, blocks // slots, sequences, lasers), np.uint16)
    d[...] = raw.distance_2mm.reshape(split).transpose(2, 0, 1, 3, 4)
    f = np.empty((slots, n, blocks // slots, sequences, lasers), np.uint8)
    f[...] = raw.reflectivity.reshape(split).transpose(2, 0, 1, 3, 4)
    d, f = d.reshape(slots, w0, lasers), f.reshape(slots, w0, lasers)
    a = firing_azimuth_cdeg.reshape(w0, lasers)
    two = np.uint32(2)
    for row, laser in enumerate(np.asarray(row_laser).tolist()):
        np.multiply(d[:, :, laser], two, out=rng[:, row])
        refl[:, row] = f[:, :, laser]
        az_px[row] = a[:, laser]
    return rng, refl, az_px
