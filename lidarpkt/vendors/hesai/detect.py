"""Which Pandar model sent a stream, from its packets alone: payload size, then the bytes.

The size names the candidates (:data:`lidarpkt.vendors.hesai.models.BY_SIZE`); the content decides:
a 12-byte header starts EE FF and gives the protocol version, lasers and blocks; the Pandar64's
8-byte header starts EE FF and gives lasers and blocks; the Pandar40P has no header, each of its
blocks starts FF EE. A stream is that model when most of its first packets say so.
"""

from __future__ import annotations

import numpy as np

from lidarpkt.core.packet import PacketBatch
from .models import BY_SIZE, RETURN_MODE_NAMES, HesaiModel

_LOOK = 16  # packets looked at


def _fits(head: np.ndarray, model: HesaiModel) -> np.ndarray:
    """``bool[n]``: the payloads ``head`` (``uint8[n, L]``) carry ``model``'s start bytes and header."""
    if model.header == "12B":
        major, minor = model.protocol or (0, 0)
        return ((head[:, 0] == 0xEE) & (head[:, 1] == 0xFF) & (head[:, 2] == major) & (head[:, 3] == minor)
                & (head[:, 6] == model.channels) & (head[:, 7] == model.blocks))
    if model.header == "8B":
        return (head[:, 0] == 0xEE) & (head[:, 1] == 0xFF) & (head[:, 2] == model.channels) & (head[:, 3] == model.blocks)
    stride = model.layout["blocks"].base.itemsize
    return (head[:, 0] == 0xFF) & (head[:, 1] == 0xEE) & (head[:, stride] == 0xFF) & (head[:, stride + 1] == 0xEE)


def detect_model(payload: np.ndarray) -> HesaiModel | None:
    """The model of ``uint8[N, L]`` payloads of one stream, ``None`` if they are no Pandar packets we decode."""
    if payload.ndim != 2 or payload.shape[0] == 0:
        return None
    head = payload[:_LOOK]
    for model in BY_SIZE.get(int(payload.shape[1]), ()):
        if np.count_nonzero(_fits(head, model)) * 2 > len(head):
            return model
    return None


def classify(batch: PacketBatch) -> HesaiModel | None:
    """The Pandar model of a batch's stream, ``None`` for anything else (the router's test)."""
    if int(batch.payload_size) not in BY_SIZE:
        return None
    return detect_model(batch.payload)


def describe_stream(batch: PacketBatch) -> dict | None:
    """A JSON-ready description of a Pandar stream for ``lidarpkt info``, ``None`` if it is none:
    ``{"kind": "Hesai PandarXT32 data", "model": ..., "protocol": "6.1", "return_mode": "last_strongest",
    "return_labels": [...], "return_mode_byte": 0x39, "motor_speed_rpm": 600, "rotation_hz": 10.0,
    "factory_information": 0x42, "packets": N, "malformed_packets": ..., "first_utc": "2022-...Z"}``."""
    model = classify(batch)
    if model is None:
        return None
    from .decode import decode_packets  # the fields, not the frame assembly

    raw = decode_packets(batch.payload, model)
    good = raw.select(raw.valid)
    out: dict = {"kind": f"Hesai {model.name} data", "model": model.name,
                 "protocol": "{}.{}".format(*model.protocol) if model.protocol else "none (no version field)",
                 "packets": len(batch), "malformed_packets": int(np.count_nonzero(~raw.valid))}
    if len(good) == 0:
        return out
    modes = [int(m) for m in np.unique(good.return_mode)]
    names = [RETURN_MODE_NAMES[m] for m in modes]
    rpm = int(np.bincount(good.motor_speed_rpm).argmax())
    import datetime as _dt

    first = _dt.datetime.fromtimestamp(int(good.timestamp_ns[0]) / 1e9, _dt.timezone.utc)
    out.update({
        "return_mode": names[0] if len(names) == 1 else names,
        "return_labels": list(model.labels(modes[0])),
        "return_mode_byte": modes[0],
        "motor_speed_rpm": rpm,
        "rotation_hz": rpm / 60.0,
        "factory_information": int(good.factory_information[0]),
        "first_utc": first.isoformat().replace("+00:00", "Z"),
    })
    return out
