"""Batch decoding of VLP-16 payloads into raw field arrays, in the manual's units.

One NumPy pass per batch: the payload array is viewed through the dtypes of
:mod:`lidarpkt.vendors.velodyne.packet` and each field is copied out as a whole column.
Frame assembly (:mod:`lidarpkt.vendors.velodyne.frames`) and the encoder work from these arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidarpkt.core import kernels

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
        return blocks_ok(self.flag, self.azimuth_cdeg, [BLOCK_FLAG] * self.flag.shape[1])

    @property
    def range_mm(self) -> np.ndarray:
        """``uint32[N, 12, 32]`` distance in millimetres (2 mm units × 2, exact)."""
        return self.distance_2mm.astype(np.uint32) << 1

    def select(self, rows: np.ndarray | slice) -> "DataPackets":
        """The chosen packets (boolean mask, indices or a slice); ``self`` for a mask that keeps every packet
        (the common case of a sound capture: no copy of the batch)."""
        if isinstance(rows, np.ndarray) and rows.dtype == bool and rows.shape == (len(self),) and rows.all():
            return self
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


@dataclass(eq=False)
class Hdl32eInertial:
    """The inertial words of N HDL-32E position packets, three sensors each (HDL-32E manual, "Positioning Packet").

    Attributes:
        gyro_deg_s: ``float64[N, 3]`` rotation rate of each sensor's gyroscope, °/s.
        temperature_c: ``float64[N, 3]`` each sensor's temperature, °C.
        accel_g: ``float64[N, 3, 2]`` each sensor's X and Y acceleration, g.
        tag: ``uint8[N, 3, 4]`` the high 4 bits of each word (gyro, temperature, accel X, accel Y): 0, 1, 2, 3
            in the real capture, the word's place.
    """

    gyro_deg_s: np.ndarray
    temperature_c: np.ndarray
    accel_g: np.ndarray
    tag: np.ndarray


def hdl32e_inertial(payload: np.ndarray) -> Hdl32eInertial:
    """The gyro, temperature and accelerometer readings of ``uint8[N, 512]`` HDL-32E position payloads.

    Raises :class:`~lidarpkt.errors.PacketFormatError` if the payload is not ``[N, 512]``.
    """
    from .packet import (HDL32E_ACCEL_G, HDL32E_GYRO_DEG_S, HDL32E_INERTIAL_DTYPE, HDL32E_INERTIAL_OFFSET,
                         HDL32E_TEMPERATURE_C, HDL32E_TEMPERATURE_OFFSET_C)

    pos = as_position_packets(payload)  # checks the size
    raw = np.asarray(payload, np.uint8)
    words = np.ascontiguousarray(raw[:, HDL32E_INERTIAL_OFFSET:HDL32E_INERTIAL_OFFSET + HDL32E_INERTIAL_DTYPE.itemsize])
    sensors = words.view(HDL32E_INERTIAL_DTYPE)[:, 0]["sensors"]  # [N, 3]
    u = np.stack([sensors[k] for k in ("gyro", "temperature", "accel_x", "accel_y")], axis=-1).astype(np.int32)
    value = u & 0x0FFF
    value = np.where(value >= 0x800, value - 0x1000, value)  # 12-bit two's complement
    del pos
    return Hdl32eInertial(
        gyro_deg_s=value[..., 0] * HDL32E_GYRO_DEG_S,
        temperature_c=value[..., 1] * HDL32E_TEMPERATURE_C + HDL32E_TEMPERATURE_OFFSET_C,
        accel_g=value[..., 2:4] * HDL32E_ACCEL_G,
        tag=(u >> 12).astype(np.uint8),
    )


def decode_position_packets(payload: np.ndarray) -> PositionPackets:
    """Every field of ``uint8[N, 512]`` VLP-16 position payloads (see :class:`PositionPackets`).

    Raises :class:`~lidarpkt.errors.PacketFormatError` if the payload is not ``[N, 512]``.
    """
    pk = as_position_packets(payload)
    return PositionPackets(**{name: np.array(pk[name]) for name in pk.dtype.names or ()})  # structured: names set


def column_pixels(raw: DataPackets, rate_cdeg_s: np.ndarray, dt_s: np.ndarray, row_laser: np.ndarray, slots: int,
                  sequences: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pixels of a batch as range-image columns: ``range_mm`` ``uint32[slots, 16, W]`` (2 × the
    wire's distance), ``reflectivity`` ``uint8[slots, 16, W]`` and per-firing ``azimuth`` ``uint16[16, W]``,
    W = N · (12 / slots) · 2; row r is laser ``row_laser[r]``; dual packets (``slots`` 2) put block b in
    slot b % 2. The azimuth of a firing is :func:`~lidarpkt.vendors.velodyne.timing.firing_azimuths` of its
    block's azimuth (block 2k of a dual pair), the packet's rate (``rate_cdeg_s``, ``float32[N]``) and its
    delay (``dt_s``, ``float32[12 / slots, 32]``).

    Compiled (``lidarpkt._native.velodyne_columns``, one pass in chunks of 64 packets, each packet's firing
    azimuths computed in an L1 tile) when it is built; the NumPy twin computes every firing azimuth, copies
    the strided 3-byte records once into [slot, column, laser] order (long inner loops), then per row
    gathers a laser column (16 small ufunc calls), so that the inner loops are long.
    """
    n, blocks, channels = raw.distance_2mm.shape
    lasers = channels // sequences
    w0 = n * (blocks // slots) * sequences
    rng = np.empty((slots, lasers, w0), np.uint32)
    refl = np.empty((slots, lasers, w0), np.uint8)
    az_px = np.empty((lasers, w0), np.uint16)
    native = kernels.native
    if native is not None and (lasers, blocks, sequences) == (16, 12, 2):
        native.velodyne_columns(raw.distance_2mm, raw.reflectivity, raw.azimuth_cdeg,
                                np.ascontiguousarray(rate_cdeg_s, np.float32), np.ascontiguousarray(dt_s, np.float32),
                                np.ascontiguousarray(row_laser, np.int64), slots, rng, refl, az_px)
        return rng, refl, az_px
    from .timing import firing_azimuths

    az = raw.azimuth_cdeg
    fa = firing_azimuths(az[:, ::slots], rate_cdeg_s, dt_s, general=bool(az.size and int(az.max()) > 36000))
    # [n, blocks per slot, slots, 2 seq, 16 lasers] → [slots, n, blocks per slot, 2 seq, 16 lasers]
    split = (n, blocks // slots, slots, sequences, lasers)
    d = np.empty((slots, n, blocks // slots, sequences, lasers), np.uint16)
    d[...] = raw.distance_2mm.reshape(split).transpose(2, 0, 1, 3, 4)
    f = np.empty((slots, n, blocks // slots, sequences, lasers), np.uint8)
    f[...] = raw.reflectivity.reshape(split).transpose(2, 0, 1, 3, 4)
    d, f = d.reshape(slots, w0, lasers), f.reshape(slots, w0, lasers)
    a = fa.reshape(w0, lasers)
    two = np.uint32(2)
    for row, laser in enumerate(np.asarray(row_laser).tolist()):
        np.multiply(d[:, :, laser], two, out=rng[:, row])
        refl[:, row] = f[:, :, laser]
        az_px[row] = a[:, laser]
    return rng, refl, az_px


def blocks_ok(flag: np.ndarray, azimuth_cdeg: np.ndarray, expected: np.ndarray | list[int]) -> np.ndarray:
    """``bool[N]``: each block ``b`` whose expected flag ``expected[b]`` is not 0 carries that flag and an azimuth
    ≤ 36000 (0: a block the layout leaves unused, not checked); ``flag``, ``azimuth_cdeg``: ``[N, blocks]``.
    Block by block: reducing an ``[N, 12]`` view of the packets along its short axis took several times as
    long as twelve passes down its columns."""
    ok = np.ones(flag.shape[0], bool)
    for b, want in enumerate(np.asarray(expected).tolist()):
        if want:
            ok &= flag[:, b] == want
            ok &= azimuth_cdeg[:, b] <= 36000
    return ok


def flags_ok(raw: DataPackets, model) -> np.ndarray:
    """``bool[N]``: each block carries its bank's flag (``model``'s single-mode layout: 0xEEFF, 0xDDFF, ...;
    in the VLS-128's dual mode blocks 8–11 are unused and not checked) and an azimuth ≤ 36000."""
    from .layout import packet_layout

    single = packet_layout(model, "strongest").flag
    dual = packet_layout(model, "dual").flag
    is_dual = raw.return_mode == 0x39
    if not is_dual.any() or is_dual.all():
        return blocks_ok(raw.flag, raw.azimuth_cdeg, dual if is_dual.any() else single)
    ok = np.empty(len(is_dual), bool)
    for rows, expected in ((is_dual, dual), (~is_dual, single)):
        ok[rows] = blocks_ok(raw.flag[rows], raw.azimuth_cdeg[rows], expected)
    return ok


def layout_pixels(raw: DataPackets, layout, rate_cdeg_s: np.ndarray, row_laser: np.ndarray,
                  unit_mm: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pixels of a batch as range-image columns, for any model's :class:`~.layout.PacketLayout`:
    ``range_mm`` ``uint32[slots, L, W]`` (the wire's distance × ``unit_mm``), ``reflectivity``
    ``uint8[slots, L, W]`` and per-firing ``azimuth`` ``uint16[L, W]``, W = N · columns per packet; row r
    is laser ``row_laser[r]``. ``rate_cdeg_s``: ``float32[N]`` rotation rate of each packet (0.01°/s).

    The azimuth of a firing is velodyne_decoder's: lround(block azimuth + rate · dt) mod 36000 in float32.
    """
    from .timing import round_azimuth_cdeg

    n = len(raw)
    src = layout.source[:, row_laser, :]  # [S, L, C] channel index of each pixel, rows in elevation order
    s, lasers, c = src.shape
    src0 = src[0]
    block = layout.azimuth_block.reshape(-1)[src0]  # [L, C]
    dt = layout.dt_s32.reshape(-1)[src0]
    native = kernels.native
    if native is not None and hasattr(native, "velodyne_layout_columns"):
        rng = np.empty((s, lasers, n * c), np.uint32)
        f = np.empty((s, lasers, n * c), np.uint8)
        az_px = np.empty((lasers, n * c), np.uint16)
        native.velodyne_layout_columns(raw.distance_2mm, raw.reflectivity, raw.azimuth_cdeg,
                                       np.ascontiguousarray(src, np.int64), np.ascontiguousarray(block, np.int64),
                                       np.ascontiguousarray(dt, np.float32),
                                       np.ascontiguousarray(rate_cdeg_s, np.float32), unit_mm, rng, f, az_px)
        return rng, f, az_px
    dist = np.ascontiguousarray(raw.distance_2mm).reshape(n, -1)
    refl = np.ascontiguousarray(raw.reflectivity).reshape(n, -1)
    rng = np.empty((s, lasers, n, c), np.uint32)
    rng[...] = dist[:, src].transpose(1, 2, 0, 3)
    rng *= np.uint32(unit_mm)
    f = np.empty((s, lasers, n, c), np.uint8)
    f[...] = refl[:, src].transpose(1, 2, 0, 3)
    az = raw.azimuth_cdeg[:, block]  # [n, L, C]
    value = np.asarray(rate_cdeg_s, np.float32)[:, None, None] * dt[None]
    az_px = round_azimuth_cdeg(value, az)
    return (rng.reshape(s, lasers, n * c), f.reshape(s, lasers, n * c),
            np.ascontiguousarray(az_px.transpose(1, 0, 2)).reshape(lasers, n * c))
