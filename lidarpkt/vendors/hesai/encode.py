"""The inverse of :func:`lidarpkt.vendors.hesai.decode_packets`: Pandar packets from their fields.

For round-trip tests and generated captures: every field :class:`~lidarpkt.vendors.hesai.decode.HesaiPackets`
holds goes back to its bytes through the same layouts (:mod:`lidarpkt.vendors.hesai.packet`); the header's
start bytes, protocol version, lasers, blocks and return count follow from the model and mode.
"""

from __future__ import annotations

import numpy as np

from lidarpkt.errors import PacketFormatError
from .decode import returns_of
from .models import HesaiModel
from .packet import SOB, SOP


def utc_fields(timestamp_ns: np.ndarray, year_offset: int) -> tuple[np.ndarray, np.ndarray]:
    """``(uint8[N, 6] UTC fields, uint32[N] µs past the second)`` of ``int64[N]`` ns since the epoch."""
    ns = np.asarray(timestamp_ns, np.int64)
    seconds, us = np.divmod(ns, 1_000_000_000)
    days, sod = np.divmod(seconds, 86400)
    z = days + 719468
    era = np.floor_divide(z, 146097)
    doe = z - era * 146097
    yoe = (doe - doe // 1460 + doe // 36524 - doe // 146096) // 365
    doy = doe - (365 * yoe + yoe // 4 - yoe // 100)
    mp = (5 * doy + 2) // 153
    day = doy - (153 * mp + 2) // 5 + 1
    month = np.where(mp < 10, mp + 3, mp - 9)
    year = yoe + era * 400 + (month <= 2)
    out = np.stack([year - year_offset, month, day, sod // 3600, sod // 60 % 60, sod % 60], axis=1)
    if np.any((out[:, 0] < 0) | (out[:, 0] > 255)):
        raise PacketFormatError(f"timestamps outside the years {year_offset}-{year_offset + 255} the UTC field holds")
    return out.astype(np.uint8), (us // 1000).astype(np.uint32)


def encode_packets(model: HesaiModel, *, azimuth_cdeg: np.ndarray, distance: np.ndarray, reflectivity: np.ndarray,
                   return_mode: int | np.ndarray, timestamp_ns: np.ndarray, motor_speed_rpm: int | np.ndarray = 600,
                   dis_unit_mm: int = 4, factory_information: int = 0x42, udp_sequence: np.ndarray | None = None,
                   mode_flag: np.ndarray | None = None, confidence: np.ndarray | None = None,
                   size: int | None = None) -> np.ndarray:
    """``uint8[N, size]`` packets of ``model`` (``size``: one of ``model.sizes``, the first by default).

    Args:
        azimuth_cdeg: ``[N, B]`` block azimuths, 0.01°; distance: ``[N, B, C]`` in ``dis_unit_mm``;
            reflectivity: ``[N, B, C]``.
        return_mode: the tail's byte (one for all packets, or ``[N]``).
        timestamp_ns: ``[N]`` packet times, ns since the epoch (to the µs).
        dis_unit_mm: the header's distance unit (the Pandar40P has none: 4 mm).

    Raises :class:`~lidarpkt.errors.PacketFormatError` for shapes, sizes or modes the model does not have.
    """
    size = model.sizes[0] if size is None else int(size)
    if size not in model.sizes:
        raise PacketFormatError(f"a {model.name} packet has {' or '.join(map(str, model.sizes))} B, not {size}")
    az = np.asarray(azimuth_cdeg)
    n = az.shape[0]
    if az.shape != (n, model.blocks) or np.shape(distance) != (n, model.blocks, model.channels) \
            or np.shape(reflectivity) != np.shape(distance):
        raise PacketFormatError(f"a {model.name} packet has {model.blocks} blocks of {model.channels} channels")
    modes = np.broadcast_to(np.asarray(return_mode, np.uint8), (n,))
    nret = {returns_of(m) for m in np.unique(modes)}
    if not nret <= set(model.returns):
        raise PacketFormatError(f"return mode {sorted(set(modes.tolist()))} is not one of the {model.name}'s")
    if model.dis_unit_mm is not None and dis_unit_mm != model.dis_unit_mm:
        raise PacketFormatError(f"the {model.name}'s distance unit is {model.dis_unit_mm} mm")
    p = np.zeros(n, model.layout)
    names = model.layout.names or ()
    if "header" in names:
        h = p["header"]
        h["sop"] = SOP
        h["laser_num"], h["block_num"], h["dis_unit"] = model.channels, model.blocks, dis_unit_mm
        if model.protocol is not None:
            h["protocol_major"], h["protocol_minor"] = model.protocol
            h["return_num"] = np.array([returns_of(m) for m in modes], np.uint8)
    blocks = p["blocks"]
    if model.header == "none":
        blocks["sob"] = SOB
    blocks["azimuth"] = az
    blocks["units"]["distance"] = distance
    blocks["units"]["reflectivity"] = reflectivity
    if confidence is not None and "confidence" in (blocks["units"].dtype.names or ()):
        blocks["units"]["confidence"] = confidence
    t = p["tail"]
    tail_names = t.dtype.names or ()
    t["return_mode"] = modes
    t["motor_speed"] = motor_speed_rpm
    t["utc"], t["timestamp_us"] = utc_fields(timestamp_ns, model.year_offset)
    t["factory_information"] = factory_information
    if udp_sequence is not None and "udp_sequence" in tail_names:
        t["udp_sequence"] = udp_sequence
    if mode_flag is not None and "mode_flag" in tail_names:
        t["mode_flag"] = mode_flag
    out = np.zeros((n, size), np.uint8)
    out[:, : model.layout.itemsize] = p.view(np.uint8).reshape(n, model.layout.itemsize)
    return out
