"""What a RoboSense stream is, from its packets alone: MSOP or DIFOP, the header family, the model.

Every RoboSense packet is 1248 bytes. A DIFOP starts A5 FF 00 5A 11 11 55 55. An MSOP starts
55 AA 05 0A 5A A5 50 A0 (family ``v1``: RS-LiDAR-16/32, RS-Bpearl) or 55 AA 05 5A, then either a
block flag FF EE at byte 42 (family ``helios``) or a block flag FE at byte 80 (family ``ruby``).

The model within a family comes from the header's model fields where units send them
(:func:`type_and_model`; the RS-LiDAR-16 manual's "LiDAR model" byte, the later manuals' LiDAR type
and model). Where they are zero, as in the RS-Helios capture here, the returns tell a model that fires
its lasers twice a block (RS-LiDAR-16, RS-Helios-16P: slot s and slot s+16 are one laser, 0.1° apart
in single return or one firing's two returns in dual) from one that fires 32 lasers once
(:func:`firings_per_block`); failing both, the family's first model (RS-LiDAR-32, RS-Helios,
RS-Ruby) is taken, and ``model=`` says otherwise.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from lidarpkt.core.packet import PacketBatch
from . import packet as P
from .models import FAMILIES, RobosenseModel

_LOOK = 16  # packets looked at to classify a batch
_DIFOP_ID = np.frombuffer(P.DIFOP_ID, np.uint8)
_V1_ID = np.frombuffer(P.MSOP_ID_V1, np.uint8)
_V2_ID = np.frombuffer(P.MSOP_ID_V2, np.uint8)
FAMILY_NAMES = ("v1", "helios", "ruby")


class StreamMatch(NamedTuple):
    """A RoboSense stream: ``kind`` ``"msop"`` or ``"difop"``; ``family`` of an MSOP stream, else ``None``."""

    kind: str
    family: str | None


def is_difop(payload: np.ndarray) -> np.ndarray:
    """``bool[N]``: the rows of ``uint8[N, L]`` that are DIFOP packets."""
    if payload.ndim != 2 or payload.shape[1] != P.PACKET_SIZE:
        return np.zeros(len(payload), bool)
    return np.all(payload[:, :8] == _DIFOP_ID, axis=1)


def msop_family(payload: np.ndarray) -> np.ndarray:
    """``int8[N]``: the family of each MSOP row, an index into :data:`FAMILY_NAMES`; -1 for other rows."""
    out = np.full(len(payload), -1, np.int8)
    if payload.ndim != 2 or payload.shape[1] != P.PACKET_SIZE or len(payload) == 0:
        return out
    flag42 = (payload[:, 42] == 0xFF) & (payload[:, 43] == 0xEE)
    v2 = np.all(payload[:, :4] == _V2_ID, axis=1)
    out[np.all(payload[:, :8] == _V1_ID, axis=1) & flag42] = 0
    out[v2 & flag42] = 1
    out[v2 & ~flag42 & (payload[:, 80] == P.RUBY_BLOCK_FLAG)] = 2
    return out


def classify(batch: PacketBatch) -> StreamMatch | None:
    """The RoboSense stream of a batch (most of its first packets decide), ``None`` for anything else
    (the router's test). A batch of MSOP with a DIFOP among them (a ROS scan message) is MSOP."""
    payload = batch.payload
    if batch.payload_size != P.PACKET_SIZE or len(batch) == 0:
        return None
    head = payload[:_LOOK]
    family = msop_family(head)
    known = family[family >= 0]
    if known.size * 2 > len(head):
        return StreamMatch("msop", FAMILY_NAMES[int(np.bincount(known).argmax())])
    if np.count_nonzero(is_difop(head)) * 2 > len(head):
        return StreamMatch("difop", None)
    return None


def type_and_model(payload: np.ndarray, family: str) -> dict[str, np.ndarray]:
    """The header's model fields of ``uint8[N, 1248]`` MSOP rows, by name: ``lidar_model_flag``,
    ``lidar_type``, ``lidar_model`` (family ``v1``: bytes 30, 31, 32); the Helios and Ruby families'
    ``lidar_type`` and ``lidar_model`` at bytes 30 and 31 where byte 30 is set (as units send them),
    else at 31 and 32 (as the manuals' tables place them)."""
    b30, b31, b32 = (payload[:, k].astype(np.int16) for k in (30, 31, 32))
    if family == "v1":
        return {"lidar_model_flag": b30, "lidar_type": b31, "lidar_model": b32}
    at30 = b30 != 0
    return {"lidar_type": np.where(at30, b30, b31), "lidar_model": np.where(at30, b31, b32)}


def model_from_header(payload: np.ndarray, family: str) -> RobosenseModel | None:
    """The model whose header codes most of the first rows carry, ``None`` if none does."""
    head = payload[:_LOOK]
    if len(head) == 0:
        return None
    values = type_and_model(head, family)
    for model in FAMILIES[family]:
        for alternative in model.codes:
            hit = np.ones(len(head), bool)
            for field, value in alternative:
                hit &= values[field] == value
            if np.count_nonzero(hit) * 2 > len(head):
                return model
    return None


def firings_per_block(distance: np.ndarray, min_pairs: int = 200) -> int | None:
    """Whether blocks of 32 slots (``uint16[N, B, 32]`` distances) hold two firings of 16 lasers (2) or
    one of 32 (1), from the returns; ``None`` when too few slots hold returns to tell.

    Slot s and slot s+16 of one block are one laser 0.1° apart (or one firing's two returns) on a
    two-firing model, so their ranges agree (within 2 %) at least as often as slot s of consecutive
    blocks, 0.2° apart; on a 32-laser model they are lasers at other elevations and agree far less
    often (in the RS-Helios capture here: 0-10 % against 33-62 %)."""
    d = np.asarray(distance, np.int32)
    if d.ndim != 3 or d.shape[2] != 32 or d.shape[1] < 2:
        return None

    def agree(a: np.ndarray, b: np.ndarray) -> tuple[float, int]:
        both = (a > 0) & (b > 0)
        n = int(np.count_nonzero(both))
        if n == 0:
            return 0.0, 0
        close = np.abs(a - b) * 50 <= np.maximum(a, b)
        return float(np.count_nonzero(close & both)) / n, n

    pair, n_pair = agree(d[..., :16], d[..., 16:])
    nxt, n_next = agree(d[:, :-1, :16], d[:, 1:, :16])
    if n_pair < min_pairs or n_next < min_pairs or nxt == 0.0:
        return None
    return 2 if pair >= 0.5 * nxt else 1


def detect_model(payload: np.ndarray, family: str | None = None) -> RobosenseModel | None:
    """The model of ``uint8[N, 1248]`` MSOP payloads of one stream (see the module docstring), ``None``
    if they are no RoboSense MSOP packets."""
    if payload.ndim != 2 or payload.shape[1] != P.PACKET_SIZE or len(payload) == 0:
        return None
    if family is None:
        codes = msop_family(payload[:_LOOK])
        codes = codes[codes >= 0]
        if codes.size * 2 <= min(len(payload), _LOOK):
            return None
        family = FAMILY_NAMES[int(np.bincount(codes).argmax())]
    found = model_from_header(payload, family)
    if found is not None or family == "ruby":
        return found or FAMILIES[family][0]
    rows = payload[msop_family(payload) == FAMILY_NAMES.index(family)]
    blocks = rows[:, 42:1242].reshape(len(rows), 12, 100)
    distance = (blocks[:, :, 4:].reshape(len(rows), 12, 32, 3)[..., :2].astype(np.uint16) @ np.array([256, 1], np.uint16))
    two = firings_per_block(distance)
    if two == 2:
        return next(m for m in FAMILIES[family] if m.firings_per_block == 2)
    return FAMILIES[family][0]
