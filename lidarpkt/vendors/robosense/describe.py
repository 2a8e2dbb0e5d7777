"""A RoboSense stream described for ``lidarpkt info``: model, return mode, calibration source, rotation,
time, from one batch of its packets (MSOP, DIFOP, or a ROS scan message holding both)."""

from __future__ import annotations

import datetime as _dt
from typing import Any

import numpy as np

from lidarpkt.core.packet import PacketBatch
from .decode import decode_packets
from .detect import classify, detect_model, is_difop
from .difop import DeviceInfo, decode_difop
from .models import FAMILIES, MODELS, RobosenseModel


def _utc(ns: int) -> str:
    return _dt.datetime.fromtimestamp(ns / 1e9, _dt.timezone.utc).isoformat().replace("+00:00", "Z")


def device_info(payload: np.ndarray, model: RobosenseModel | None = None) -> tuple[DeviceInfo | None, RobosenseModel | None]:
    """The first DIFOP of ``uint8[N, 1248]`` payloads that decodes (as ``model``'s, else any model's) and its model."""
    candidates = [model] if model is not None else list(MODELS)
    for row in payload[is_difop(payload)]:
        for m in candidates:
            info = decode_difop(row, m)
            if info is not None:
                return info, m
    return None, None


def mode_text(model: RobosenseModel, mode_byte: int | None, n_returns: int) -> str:
    """``"strongest"``, ``"dual (strongest, last)"``, ``"single (return mode in the DIFOP)"``."""
    labels = model.labels(mode_byte, n_returns)
    if n_returns == 2:
        return f"dual ({', '.join(labels)})"
    return labels[0] if labels[0] != "unknown" else "single (the return mode is in the DIFOP)"


def describe_stream(batch: PacketBatch) -> dict[str, Any] | None:
    """A JSON-ready description of a RoboSense stream, ``None`` if the batch is none:
    ``{"kind": "RoboSense RS-Helios MSOP", "model": ..., "return_mode": "strongest", "calibration": "DIFOP",
    "packets": N, "difop_packets": ..., "malformed_packets": ..., "rotation_hz": 10, "first_utc": ...}``."""
    match = classify(batch)
    if match is None:
        return None
    payload = batch.payload
    difop = is_difop(payload)
    msop = payload[~difop]
    model = detect_model(msop, match.family) if match.kind == "msop" and len(msop) else None
    info, info_model = device_info(payload, model)
    out: dict[str, Any] = {"packets": int(np.count_nonzero(~difop)), "difop_packets": int(np.count_nonzero(difop))}
    if model is None:
        out["kind"] = "RoboSense DIFOP"
        if info is not None and info_model is not None:
            family = [m for m in FAMILIES[info_model.family] if info.return_mode in m.return_modes]
            n_returns = len(family[0].return_modes[info.return_mode])
            out.update({"return_mode": mode_text(family[0], info.return_mode, n_returns),
                        "calibration": f"DIFOP ({family[0].lasers} lasers)", **info.describe()})
        else:
            out["malformed_packets"] = out["difop_packets"]
        return out
    raw = decode_packets(msop, model)
    good = raw.select(raw.valid)
    out.update({"kind": f"RoboSense {model.name} MSOP", "model": model.name,
                "malformed_packets": int(np.count_nonzero(~raw.valid))})
    if len(good) == 0:
        return out
    if good.wave_mode is not None:
        n_returns = 2 if int(np.bincount(good.wave_mode).argmax()) == 3 else 1
    elif info is not None:
        n_returns = len(model.return_modes.get(info.return_mode, ("?",)))
    elif model.dual_layout == "block_pairs":
        n_returns = 2 if np.all(good.azimuth_cdeg[:, 0::2] == good.azimuth_cdeg[:, 1::2]) else 1
    else:
        n_returns = 1
    out["return_mode"] = mode_text(model, info.return_mode if info is not None else None, n_returns)
    out["calibration"] = "DIFOP" if info is not None else "the sensor's DIFOP packets (none among these) or its angle CSV"
    if info is not None:
        out["motor_speed_rpm"] = info.motor_speed_rpm
        out["rotation_hz"] = info.motor_speed_rpm / 60.0
        out["serial_number"] = info.serial_number
    out["distance_unit_mm"] = int(good.distance_unit_um[0]) / 1000.0
    out["first_utc"] = _utc(int(good.timestamp_ns[0]))
    return out
