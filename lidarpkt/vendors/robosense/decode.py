"""Raw fields of a batch of RoboSense MSOP packets of one model, in the manual's units, one NumPy pass.

:func:`decode_packets` views ``uint8[N, 1248]`` payloads through the model's layout
(:mod:`lidarpkt.vendors.robosense.packet`) and returns :class:`RobosensePackets`; its ``valid`` marks the
packets whose header id, block flags, azimuths, distance unit, return ids and time are possible (the
decoder skips and counts the others).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from . import packet as P
from .models import RobosenseModel

#: the Helios header's range_resolution byte → µm per distance unit
RANGE_RESOLUTION_UM = {0: 5000, 1: 2500}
_YMD_LIMITS = np.array([255, 12, 31, 23, 59, 60])  # year (from 2000), month, day, hour, minute, second


def civil_seconds(year: np.ndarray, month: np.ndarray, day: np.ndarray) -> np.ndarray:
    """``int64[N]`` seconds since the epoch at midnight UTC of each date (NumPy's proleptic Gregorian calendar)."""
    months = (np.asarray(year, np.int64) - 1970) * 12 + np.asarray(month, np.int64) - 1
    days = months.astype("datetime64[M]").astype("datetime64[D]") + (np.asarray(day, np.int64) - 1)
    return days.astype("datetime64[s]").astype(np.int64)


def time_ns(stamp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(int64[N] ns since the epoch, bool[N] possible)`` of :data:`~lidarpkt.vendors.robosense.packet.TIME_UTC`
    or :data:`~lidarpkt.vendors.robosense.packet.TIME_YMD` fields (the year-month-day form counts years
    from 2000, in UTC)."""
    names = stamp.dtype.names or ()
    if "seconds" in names:
        seconds = P.be_uint(stamp["seconds"])
        us = stamp["microseconds"].astype(np.int64)
        ok = (us < 1_000_000) & (seconds < (1 << 33))  # beyond the year 2242: a damaged field
        return np.where(ok, seconds * 1_000_000_000 + us * 1000, 0), ok
    parts = np.stack([stamp[k] for k in ("year", "month", "day", "hour", "minute", "second")], axis=-1).astype(np.int64)
    ms, us = stamp["millisecond"].astype(np.int64), stamp["microsecond"].astype(np.int64)
    ok = np.all(parts <= _YMD_LIMITS, axis=-1) & (parts[:, 1] >= 1) & (parts[:, 2] >= 1) & (ms < 1000) & (us < 1000)
    secs = civil_seconds(parts[:, 0] + 2000, np.maximum(parts[:, 1], 1), np.maximum(parts[:, 2], 1))
    secs = secs + parts[:, 3] * 3600 + parts[:, 4] * 60 + parts[:, 5]
    return np.where(ok, secs * 1_000_000_000 + ms * 1_000_000 + us * 1000, 0), ok


@dataclass
class RobosensePackets:
    """Fields of N MSOP packets of one model (B blocks, S slots per block).

    Attributes:
        azimuth_cdeg: ``uint16[N, B]`` block azimuth, 0.01°.
        distance: ``uint16[N, B, S]`` in ``distance_unit_um``; reflectivity: ``uint8[N, B, S]``.
        ret_id: RS-Ruby ``uint8[N, B]`` (1 or 2: which return a block holds), else ``None``.
        wave_mode: RS-Ruby ``uint8[N]`` (1 single return, 3 dual), else ``None``.
        distance_unit_um: ``int32[N]`` µm per distance unit.
        timestamp_ns: ``int64[N]`` time of the packet's first firing, ns since the epoch.
        packet_count: ``int64[N]`` the header's packet counter where the model has one, else ``None``.
        lidar_type, lidar_model: ``uint8[N]`` the header's model fields (0 where not sent).
        valid: ``bool[N]`` packets whose fields are possible.
    """

    azimuth_cdeg: np.ndarray
    distance: np.ndarray
    reflectivity: np.ndarray
    ret_id: np.ndarray | None
    wave_mode: np.ndarray | None
    distance_unit_um: np.ndarray
    timestamp_ns: np.ndarray
    packet_count: np.ndarray | None
    lidar_type: np.ndarray
    lidar_model: np.ndarray
    valid: np.ndarray

    def __len__(self) -> int:
        return int(self.timestamp_ns.shape[0])

    def select(self, which: Any) -> RobosensePackets:
        """The packets at ``which`` (mask, indices or slice)."""
        out: dict[str, Any] = {f.name: None if getattr(self, f.name) is None else getattr(self, f.name)[which]
                               for f in fields(self)}
        return RobosensePackets(**out)

    @staticmethod
    def concatenate(parts: list[RobosensePackets]) -> RobosensePackets:
        """The packets of ``parts`` in order."""
        out: dict[str, Any] = {}
        for f in fields(RobosensePackets):
            values = [getattr(p, f.name) for p in parts]
            out[f.name] = None if values[0] is None else np.concatenate(values)
        return RobosensePackets(**out)


def decode_packets(payload: np.ndarray, model: RobosenseModel) -> RobosensePackets:
    """Decode ``uint8[N, 1248]`` MSOP payloads of ``model``.

    Raises :class:`~lidarpkt.errors.PacketFormatError` for payloads of another size.
    """
    p = P.as_packets(payload, model.layout)
    header, blocks = p["header"], p["blocks"]
    n = len(p)
    ident = P.MSOP_ID_V1 if model.family == "v1" else P.MSOP_ID_V2
    ok = np.all(header["header_id"] == np.frombuffer(ident, np.uint8), axis=1)
    az = blocks["azimuth"]
    ok &= np.all(az < 36000, axis=1)
    ret_id = wave_mode = None
    if model.family == "ruby":
        ok &= np.all(blocks["flag"] == P.RUBY_BLOCK_FLAG, axis=1)
        ret_id = blocks["ret_id"]
        wave_mode = header["wave_mode"] & 0x0F
        ok &= np.all((ret_id == 1) | (ret_id == 2), axis=1) & ((wave_mode == 1) | (wave_mode == 3))
    else:
        ok &= np.all(blocks["flag"] == P.BLOCK_FLAG, axis=1)
    if model.distance_unit_um is not None:
        unit = np.full(n, model.distance_unit_um, np.int32)
    else:
        rr = header["range_resolution"]
        ok &= rr <= 1
        unit = np.where(rr == 0, RANGE_RESOLUTION_UM[0], RANGE_RESOLUTION_UM[1]).astype(np.int32)
    ts, ts_ok = time_ns(header["timestamp"])
    ok &= ts_ok
    type_field = "lidar_type" if "lidar_type" in (header.dtype.names or ()) else None
    zeros = np.zeros(n, np.uint8)
    channels = blocks["channels"]
    return RobosensePackets(
        azimuth_cdeg=az, distance=channels["distance"], reflectivity=channels["reflectivity"], ret_id=ret_id,
        wave_mode=wave_mode, distance_unit_um=unit, timestamp_ns=ts.astype(np.int64),
        packet_count=header[model.packet_counter].astype(np.int64) if model.packet_counter else None,
        lidar_type=header[type_field] if type_field else zeros, lidar_model=header["lidar_model"], valid=ok,
    )
