"""Raw fields of a batch of Hesai Pandar packets of one model, in the manual's units, one NumPy pass.

:func:`decode_packets` views ``uint8[N, L]`` payloads through the model's layout
(:mod:`lidarpkt.vendors.hesai.packet`) and returns :class:`HesaiPackets`: per-packet tail fields, per-block
azimuths, per-unit distances and reflectivities, and :attr:`HesaiPackets.valid`, the packets whose
start bytes, azimuths, return mode, distance unit and UTC time are possible (the decoder skips and
counts the others).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from .models import RETURN_MODES, HesaiModel
from .packet import SOB, SOP, as_packets

_UTC_LIMITS = np.array([255, 12, 31, 23, 59, 59])  # year byte, month, day, hour, minute, second


def utc_seconds(utc: np.ndarray, year_offset: int) -> np.ndarray:
    """``int64[N]`` seconds since the Unix epoch of ``uint8[N, 6]`` (year − ``year_offset``, month,
    day, hour, minute, second) UTC fields; days from the civil calendar, proleptic Gregorian."""
    u = utc.astype(np.int64)
    y = u[:, 0] + year_offset
    m, d = u[:, 1], u[:, 2]
    y = y - (m <= 2)
    era = np.floor_divide(y, 400)
    yoe = y - era * 400
    mp = (m + 9) % 12
    doy = (153 * mp + 2) // 5 + d - 1
    doe = yoe * 365 + yoe // 4 - yoe // 100 + doy
    days = era * 146097 + doe - 719468
    return days * 86400 + u[:, 3] * 3600 + u[:, 4] * 60 + u[:, 5]


@dataclass
class HesaiPackets:
    """Fields of N packets of one model (shapes: B blocks, C channels).

    Attributes:
        azimuth_cdeg: ``uint16[N, B]`` block azimuth, 0.01°.
        distance: ``uint16[N, B, C]`` in ``dis_unit_mm``; reflectivity: ``uint8[N, B, C]``.
        confidence: ``uint8[N, B, C]``, the 4-byte units' last byte (reserved on most models), else ``None``.
        dis_unit_mm: ``uint8[N]`` millimetres per distance unit.
        return_mode: ``uint8[N]`` the tail's return-mode byte; motor_speed_rpm: ``uint16[N]``.
        timestamp_ns: ``int64[N]`` packet time, ns since the epoch (UTC second + µs of the tail).
        timestamp_us: ``uint32[N]`` µs past the UTC second; utc: ``uint8[N, 6]`` as sent.
        factory_information: ``uint8[N]``.
        udp_sequence: ``uint32[N]`` where the protocol has one, else ``None``.
        mode_flag: PandarQT128 ``uint8[N]`` (its firing loop), else ``None``.
        valid: ``bool[N]`` packets whose fields are possible (see the module docstring).
    """

    azimuth_cdeg: np.ndarray
    distance: np.ndarray
    reflectivity: np.ndarray
    confidence: np.ndarray | None
    dis_unit_mm: np.ndarray
    return_mode: np.ndarray
    motor_speed_rpm: np.ndarray
    timestamp_ns: np.ndarray
    timestamp_us: np.ndarray
    utc: np.ndarray
    factory_information: np.ndarray
    udp_sequence: np.ndarray | None
    mode_flag: np.ndarray | None
    valid: np.ndarray

    def __len__(self) -> int:
        return int(self.return_mode.shape[0])

    def select(self, which) -> HesaiPackets:
        """The packets at ``which`` (mask, indices or slice)."""
        out: dict[str, Any] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            out[f.name] = None if v is None else v[which]
        return HesaiPackets(**out)


def decode_packets(payload: np.ndarray, model: HesaiModel) -> HesaiPackets:
    """Decode ``uint8[N, L]`` payloads (L ≥ the model's layout) of ``model``.

    Raises :class:`~lidarpkt.errors.PacketFormatError` if the payloads are shorter than the layout.
    """
    p = as_packets(payload, model.layout)
    blocks, tail = p["blocks"], p["tail"]
    az = blocks["azimuth"]
    units = blocks["units"]
    mode = tail["return_mode"]
    utc = tail["utc"]
    n = len(p)
    if model.dis_unit_mm is not None:
        unit_mm = np.full(n, model.dis_unit_mm, np.uint8)
    else:
        unit_mm = p["header"]["dis_unit"]
    ok = np.all(az < 36000, axis=1) & (unit_mm > 0)
    if model.header != "none":
        hdr = p["header"]
        ok &= (hdr["sop"] == SOP) & (hdr["laser_num"] == model.channels) & (hdr["block_num"] == model.blocks)
    else:
        ok &= np.all(blocks["sob"] == SOB, axis=1)
    counts = np.zeros(256, np.int64)
    for code, labels in RETURN_MODES.items():
        if len(labels) in model.returns:
            counts[code] = len(labels)
    ok &= counts[mode] > 0
    ok &= np.all(utc <= _UTC_LIMITS, axis=1) & (utc[:, 1] >= 1) & (utc[:, 2] >= 1)
    ok &= tail["timestamp_us"] < 1_000_000
    seconds = utc_seconds(utc, model.year_offset)
    ts = seconds * 1_000_000_000 + tail["timestamp_us"].astype(np.int64) * 1000
    names = tail.dtype.names or ()
    return HesaiPackets(
        azimuth_cdeg=az, distance=units["distance"], reflectivity=units["reflectivity"],
        confidence=units["confidence"] if "confidence" in (units.dtype.names or ()) else None, dis_unit_mm=unit_mm,
        return_mode=mode, motor_speed_rpm=tail["motor_speed"], timestamp_ns=ts, timestamp_us=tail["timestamp_us"],
        utc=utc, factory_information=tail["factory_information"],
        udp_sequence=tail["udp_sequence"] if "udp_sequence" in names else None,
        mode_flag=tail["mode_flag"] if "mode_flag" in names else None, valid=ok,
    )


def returns_of(mode: int) -> int:
    """Returns per firing in return mode ``mode`` (its byte); 0 for an unknown byte."""
    labels = RETURN_MODES.get(int(mode))
    return len(labels) if labels else 0
