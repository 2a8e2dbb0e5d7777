"""The inverse of :mod:`lidarpkt.vendors.velodyne.decode`: raw field arrays → VLP-16 payloads.

Used by the fixture generator for synthetic strongest/last/dual captures and by the
round-trip tests (``encode(decode(payload)) == payload`` for every real payload).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Iterable, Sequence

import numpy as np

from lidarpkt.errors import NMEAError, PacketFormatError

if TYPE_CHECKING:
    from lidarpkt.core.frame import Frame
from .packet import (
    BLOCK_FLAG,
    BLOCKS_PER_PACKET,
    CHANNELS_PER_BLOCK,
    DATA_PACKET_DTYPE,
    DATA_PACKET_SIZE,
    NMEA_SIZE,
    POSITION_PACKET_DTYPE,
    POSITION_PACKET_SIZE,
    PRODUCT_VLP16,
    RETURN_MODE_CODES,
)


def _mode_code(return_mode) -> np.ndarray | int:
    if isinstance(return_mode, str):
        try:
            return RETURN_MODE_CODES[return_mode]
        except KeyError:
            raise PacketFormatError(
                f"unknown VLP-16 return mode {return_mode!r}: use one of {sorted(RETURN_MODE_CODES)}"
            ) from None
    return np.asarray(return_mode)


def _check_range(name: str, values: np.ndarray | int, upper: int) -> None:
    values = np.asarray(values)
    if values.size and (values.min() < 0 or values.max() > upper):
        raise PacketFormatError(f"{name} must lie in 0..{upper}, got {values.min()}..{values.max()}")


def encode_data_packets(
    azimuth_cdeg: np.ndarray,
    distance_2mm: np.ndarray,
    reflectivity: np.ndarray,
    timestamp_us: np.ndarray,
    return_mode: str | int | np.ndarray,
    product_id: int | np.ndarray = PRODUCT_VLP16,
    *,
    flag: int | np.ndarray = BLOCK_FLAG,
) -> np.ndarray:
    """N VLP-16 data packets from their fields.

    Args:
        azimuth_cdeg: ``[N, 12]`` block azimuths, 0.01° (0–35999).
        distance_2mm: ``[N, 12, 32]`` distances in 2 mm units (0 = no return).
        reflectivity: ``[N, 12, 32]`` 0–255.
        timestamp_us: ``[N]`` µs past the hour (0–3 599 999 999).
        return_mode: ``"strongest"``/``"last"``/``"dual"`` or the byte (0x37/0x38/0x39), scalar or ``[N]``.
            In dual mode blocks 2k and 2k+1 must be the last and strongest returns of the same firings.
        product_id: 0x22 by default, scalar or ``[N]``.
        flag: block flag, scalar or ``[N, 12]`` (0xEEFF).

    Returns:
        ``uint8[N, 1206]`` payloads.

    Raises:
        PacketFormatError: a shape or a value does not fit its field.
    """
    azimuth_cdeg = np.asarray(azimuth_cdeg)
    if azimuth_cdeg.ndim != 2 or azimuth_cdeg.shape[1] != BLOCKS_PER_PACKET:
        raise PacketFormatError(f"azimuth_cdeg must be [N, {BLOCKS_PER_PACKET}], got {azimuth_cdeg.shape}")
    n = azimuth_cdeg.shape[0]
    shape = (n, BLOCKS_PER_PACKET, CHANNELS_PER_BLOCK)
    distance_2mm = np.asarray(distance_2mm)
    reflectivity = np.asarray(reflectivity)
    if distance_2mm.shape != shape or reflectivity.shape != shape:
        raise PacketFormatError(
            f"distance_2mm and reflectivity must be {list(shape)}, got {list(distance_2mm.shape)} "
            f"and {list(reflectivity.shape)}"
        )
    _check_range("azimuth_cdeg", azimuth_cdeg, 0xFFFF)
    _check_range("distance_2mm", distance_2mm, 0xFFFF)
    _check_range("reflectivity", reflectivity, 0xFF)
    _check_range("timestamp_us", timestamp_us, 0xFFFFFFFF)
    out = np.zeros(n, DATA_PACKET_DTYPE)
    blocks = out["blocks"]
    blocks["flag"] = flag
    blocks["azimuth_cdeg"] = azimuth_cdeg
    blocks["channels"]["distance_2mm"] = distance_2mm
    blocks["channels"]["reflectivity"] = reflectivity
    out["timestamp_us"] = np.broadcast_to(np.asarray(timestamp_us), (n,))
    out["return_mode"] = _mode_code(return_mode)
    out["product_id"] = product_id
    return out.view(np.uint8).reshape(n, DATA_PACKET_SIZE)


def _nmea_bytes(nmea: str | bytes | Sequence[str | bytes] | np.ndarray, n: int) -> np.ndarray:
    if isinstance(nmea, np.ndarray) and nmea.dtype == np.uint8:
        arr = np.broadcast_to(nmea.reshape(-1, NMEA_SIZE) if nmea.ndim == 1 else nmea, (n, NMEA_SIZE))
        return arr
    items = [nmea] * n if isinstance(nmea, (str, bytes)) else list(nmea)
    if len(items) != n:
        raise PacketFormatError(f"got {len(items)} NMEA sentences for {n} position packets")
    out = np.zeros((n, NMEA_SIZE), np.uint8)
    for i, s in enumerate(items):
        raw = s.encode("ascii") if isinstance(s, str) else bytes(s)
        if raw and not raw.endswith(b"\r\n"):
            raw += b"\r\n"  # the sensor terminates each sentence with CR LF
        if len(raw) > NMEA_SIZE:
            raise NMEAError(f"NMEA sentence of {len(raw)} bytes does not fit the {NMEA_SIZE}-byte field: {raw[:40]!r}…")
        out[i, : len(raw)] = np.frombuffer(raw, np.uint8)
    return out


def encode_position_packets(
    timestamp_us: np.ndarray | int,
    pps_status: np.ndarray | int,
    nmea: str | bytes | Sequence[str | bytes] | np.ndarray,
    *,
    thermal_status: np.ndarray | int = 0,
    last_shutdown_temperature: np.ndarray | int = 0,
    powerup_temperature: np.ndarray | int = 0,
    unused_head: np.ndarray | None = None,
    unused_tail: np.ndarray | None = None,
) -> np.ndarray:
    """N VLP-16 position packets.

    Args:
        timestamp_us: ``[N]`` (or scalar for one packet) µs past the hour.
        pps_status: 0 absent, 1 synchronizing, 2 locked, 3 error; scalar or ``[N]``.
        nmea: one sentence for all packets, a list of N sentences (text without or with the
            trailing CR LF, which is added when missing; ``""`` leaves the field empty), or the raw
            ``uint8[N, 128]`` field as decoded.
        thermal_status, last_shutdown_temperature, powerup_temperature: bytes 203–205.
        unused_head, unused_tail: ``uint8[N, 198]`` / ``[N, 178]`` raw unused bytes (zero by default).

    Returns:
        ``uint8[N, 512]`` payloads.

    Raises:
        PacketFormatError, NMEAError: a value does not fit its field.
    """
    timestamp_us = np.atleast_1d(np.asarray(timestamp_us))
    n = timestamp_us.shape[0]
    _check_range("timestamp_us", timestamp_us, 0xFFFFFFFF)
    _check_range("pps_status", pps_status, 0xFF)
    out = np.zeros(n, POSITION_PACKET_DTYPE)
    out["timestamp_us"] = timestamp_us
    out["pps_status"] = pps_status
    out["thermal_status"] = thermal_status
    out["last_shutdown_temperature"] = last_shutdown_temperature
    out["powerup_temperature"] = powerup_temperature
    out["nmea"] = _nmea_bytes(nmea, n)
    if unused_head is not None:
        out["unused_head"] = unused_head
    if unused_tail is not None:
        out["unused_tail"] = unused_tail
    return out.view(np.uint8).reshape(n, POSITION_PACKET_SIZE)


def encode_frames(frames: "Iterable[Frame]") -> np.ndarray:
    """Data packets that decode to ``frames`` (the inverse of :class:`~lidarpkt.vendors.velodyne.VelodyneDecoder`).

    Any model: the 16-laser Pucks as below; the others through their layout table
    (:mod:`lidarpkt.vendors.velodyne.layout`): every block of a column takes the azimuth of the column's
    first firing (laser 0), the timestamp is the first column's time less the model's column offset;
    the HDL-64E's status bytes are written as zeros, the VLS-128's unused dual blocks as zero blocks.

    ``frames``: consecutive VLP-16 frames of one return mode, as the decoder made them (their
    columns, concatenated, must start at a packet boundary: 24 columns per packet in single-return
    modes, 12 in dual). Invalid (lost) columns are skipped. Block azimuths come from the first
    firing of each block, timestamps from the column timestamps (µs past the hour), the return
    mode and product id from ``frame.sensor``. A block azimuth of 36000 (seen on early units)
    comes back as 0, since frames keep azimuths in [0°, 360°).

    Returns:
        ``uint8[N, 1206]`` payloads.

    Raises:
        PacketFormatError: frames of several return modes, or columns that do not fill whole packets.
    """
    from .models import VLP16, model_named

    frames = list(frames)
    if not frames:
        return np.zeros((0, DATA_PACKET_SIZE), np.uint8)
    modes = {f.sensor.return_mode for f in frames}
    if len(modes) != 1:
        raise PacketFormatError(f"frames of several return modes {sorted(modes)}: encode each mode separately")
    mode = modes.pop()
    model = model_named(frames[0].sensor.model) if frames[0].sensor.model else VLP16
    geometry = frames[0].sensor.geometry
    if model.sequences_per_block != 2:
        return _encode_layout_frames(frames, model, mode)
    row_laser = getattr(geometry, "row_laser", np.argsort(-np.asarray(model.elevation_deg), kind="stable"))
    laser_row = np.argsort(row_laser)  # row of each laser id
    valid = np.concatenate([f.column_valid for f in frames])
    rng = np.concatenate([f.range_mm for f in frames], axis=-1)[..., valid]
    refl = np.concatenate([f.reflectivity for f in frames], axis=-1)[..., valid]
    az = np.concatenate([f.extra["azimuth_cdeg"] for f in frames], axis=-1)[:, valid]
    ts = np.concatenate([f.column_timestamp_ns for f in frames])[valid]
    dual = mode == "dual"
    per = model.columns_per_packet(mode)
    lasers, blocks, seqs = model.lasers, model.blocks_per_packet, model.sequences_per_block
    channels = lasers * seqs
    w = rng.shape[-1]
    if w % per:
        raise PacketFormatError(f"{w} valid columns do not fill whole {mode} packets of {per} columns")
    n = w // per
    dist = (rng[:, laser_row] >> 1).astype(np.uint16)  # [R, 16 lasers, W]
    refl = refl[:, laser_row]
    if dual:
        # [2 slots, 16, n, 6 pairs, 2 seq] → [n, 6, 2 slots, 2 seq, 16]
        pairs = blocks // 2
        dist = dist.reshape(2, lasers, n, pairs, seqs).transpose(2, 3, 0, 4, 1).reshape(n, blocks, channels)
        refl = refl.reshape(2, lasers, n, pairs, seqs).transpose(2, 3, 0, 4, 1).reshape(n, blocks, channels)
        block_az = np.repeat(az[laser_row[0]].reshape(n, pairs, seqs)[:, :, 0], 2, axis=1)
    else:
        dist = dist.reshape(lasers, n, blocks, seqs).transpose(1, 2, 3, 0).reshape(n, blocks, channels)
        refl = refl.reshape(lasers, n, blocks, seqs).transpose(1, 2, 3, 0).reshape(n, blocks, channels)
        block_az = az[laser_row[0]].reshape(n, blocks, seqs)[:, :, 0]
    toh_us = (ts.reshape(n, per)[:, 0] // 1000) % 3_600_000_000
    product = frames[0].sensor.product_id if frames[0].sensor.product_id is not None else PRODUCT_VLP16
    return encode_data_packets(block_az, dist, refl, toh_us, mode, product)


def _encode_layout_frames(frames: "list[Frame]", model, mode: str) -> np.ndarray:
    """:func:`encode_frames` for a model decoded through its layout table (not a 16-laser Puck)."""
    from .layout import packet_layout

    lay = packet_layout(model, mode)
    row_laser = getattr(frames[0].sensor.geometry, "row_laser", np.argsort(-np.asarray(model.elevation_deg),
                                                                             kind="stable"))
    laser_row = np.argsort(row_laser)
    valid = np.concatenate([f.column_valid for f in frames])
    rng = np.concatenate([f.range_mm for f in frames], axis=-1)[..., valid]
    refl = np.concatenate([f.reflectivity for f in frames], axis=-1)[..., valid]
    az = np.concatenate([f.extra["azimuth_cdeg"] for f in frames], axis=-1)[:, valid]
    ts = np.concatenate([f.column_timestamp_ns for f in frames])[valid]
    c = lay.columns
    w = rng.shape[-1]
    if w % c:
        raise PacketFormatError(f"{w} valid columns do not fill whole {mode} packets of {c} columns")
    n = w // c
    unit = round(model.distance_resolution_m * 1000)
    dist = np.zeros((n, 12 * 32), np.int64)
    f_out = np.zeros((n, 12 * 32), np.int64)
    for slot in range(lay.slots):
        src = lay.source[slot]  # [L, C] channel of each laser's pixel
        dist[:, src] = (rng[slot][laser_row] // unit).reshape(model.lasers, n, c).transpose(1, 0, 2)
        f_out[:, src] = refl[slot][laser_row].reshape(model.lasers, n, c).transpose(1, 0, 2)
    column_az = az[laser_row[0]].reshape(n, c)  # laser 0 fires first in every column
    used = lay.column[:, 0] >= 0
    block_az = np.where(used[None, :], column_az[:, np.maximum(lay.column[:, 0], 0)], 0)
    flags = np.broadcast_to(lay.flag, (n, 12))
    first_ns = ts.reshape(n, c)[:, 0] - int(round(model.column_offset_ns))
    toh_us = (first_ns // 1000) % 3_600_000_000
    hdl64 = model.dual_layout == "upper_lower"
    product = 0 if hdl64 else (frames[0].sensor.product_id if frames[0].sensor.product_id is not None
                               else model.product_ids[0])
    return encode_data_packets(block_az, dist.reshape(n, 12, 32), f_out.reshape(n, 12, 32), toh_us,
                               0 if hdl64 else mode, product, flag=flags)
