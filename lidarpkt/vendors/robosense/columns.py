"""RoboSense packets → range-image columns, one NumPy pass per batch.

A column is one firing sequence: a laser's return per slot, in laser order (the frame puts the rows in
elevation order). Which slots of which blocks make a column is the model's (:mod:`lidarpkt.vendors.robosense.models`):
a block holds one column, or two (RS-LiDAR-16, RS-Helios-16P in single return), or a block pair holds
one (dual return); RS-Ruby blocks carry the return they hold in ``ret_id`` and a dual-return column may
start in one packet and end in the next (:class:`RubyDualColumns`).

Times and azimuths follow the manuals and the two reference decoders (rs_driver, nebula): the group of
blocks that fired together starts ``g · period`` after the packet timestamp; a slot fires at the
model's offset after its group (:mod:`lidarpkt.vendors.robosense.timing`); its azimuth is the group's
azimuth plus the azimuth step to the next group of the packet times the slot's share of the period,
``trunc(step · offset / period)`` in float32, 0.01°, as both references compute it (the last group
of a packet, and a step over 1° across a blind sector, take the nominal step of the rotation rate).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from functools import lru_cache

import numpy as np

from .decode import RobosensePackets
from .models import RobosenseModel
from .timing import slot_offsets_ns

_BLIND_STEP_CDEG = 100  # a step between groups beyond 1°: a blind sector, not the rotation


@dataclass
class Columns:
    """C columns of L lasers, R returns (laser order).

    Attributes:
        distance: ``uint16[R, L, C]`` raw distance (0 = no return); reflectivity: ``uint8[R, L, C]``.
        unit_um: ``int32[C]`` µm per distance unit.
        pixel_azimuth_cdeg: ``uint16[L, C]`` the azimuth each laser fired at, 0.01° (before its offset).
        azimuth_cdeg: ``int32[C]`` the column's first firing's azimuth, 0.01°.
        block_azimuth_cdeg: ``int32[C]`` the azimuth of the column's (first) block: frames are cut at its wraps.
        timestamp_ns: ``int64[C]`` the column's first firing.
        time_key: ``int16[C]`` the column's row of the time table (firing time of each laser after the column's first).
        packet_index: ``int64[C]`` the ordinal of the column's packet in the source.
    """

    distance: np.ndarray
    reflectivity: np.ndarray
    unit_um: np.ndarray
    pixel_azimuth_cdeg: np.ndarray
    azimuth_cdeg: np.ndarray
    block_azimuth_cdeg: np.ndarray
    timestamp_ns: np.ndarray
    time_key: np.ndarray
    packet_index: np.ndarray

    @property
    def count(self) -> int:
        return int(self.timestamp_ns.shape[0])

    def take(self, sl: slice) -> Columns:
        """The columns ``sl`` (views)."""
        return Columns(**{f.name: getattr(self, f.name)[..., sl] for f in fields(self)})

    @staticmethod
    def concatenate(parts: list[Columns]) -> Columns:
        if len(parts) == 1:
            return parts[0]
        return Columns(**{f.name: np.concatenate([getattr(p, f.name) for p in parts], axis=-1) for f in fields(Columns)})


@dataclass(frozen=True, eq=False)  # one per model and mode (plan() keeps them): hashed by identity
class Plan:
    """Where the slots of each column of a packet are (a model in a return mode).

    Attributes:
        slot: ``int[Cp, R, L]`` index into the packet's ``B · S`` slots of column c, return r, laser l.
        group: ``int[Cp]`` the block group of each column; groups: block groups per packet.
        first_block: ``int[G]`` first block of each group.
        key: ``int[Cp]`` row of :attr:`time_table` of each column.
        start_ns: ``int64[Cp]`` the column's first firing after the packet timestamp.
        fraction: ``float32[Cp, L]`` share of the group period at which each laser of the column fires.
        time_table: ``int64[K, L]`` each laser's firing after its column's first.
        period_ns: time between groups.
    """

    slot: np.ndarray
    group: np.ndarray
    groups: int
    first_block: np.ndarray
    key: np.ndarray
    start_ns: np.ndarray
    fraction: np.ndarray
    time_table: np.ndarray
    period_ns: int


@lru_cache(maxsize=32)
def plan(model: RobosenseModel, n_returns: int) -> Plan:
    """The :class:`Plan` of ``model`` in a mode of ``n_returns`` returns (1 or 2)."""
    lasers, channels, blocks = model.lasers, model.channels, model.blocks
    offsets = slot_offsets_ns(model.timing, model.firings_per_block, n_returns)
    laser = np.arange(lasers)
    if n_returns == 1:
        k = model.firings_per_block
        block = np.repeat(np.arange(blocks), k)  # [Cp]
        firing = np.tile(np.arange(k), blocks)
        slot = (block * channels + firing * lasers)[:, None, None] + laser[None, None, :]
        group, first_block, key = block, np.arange(blocks), firing
    elif model.dual_layout == "in_block":
        block = np.arange(blocks)
        slot = block[:, None, None] * channels + np.arange(2)[None, :, None] * lasers + laser[None, None, :]
        group, first_block, key = block, block, np.zeros(blocks, np.int64)
    else:  # block pairs (RS-Ruby dual columns are built by RubyDualColumns)
        pairs = np.arange(blocks // 2)
        slot = (2 * pairs[:, None, None] + np.arange(2)[None, :, None]) * channels + laser[None, None, :]
        group, first_block, key = pairs, 2 * pairs, np.zeros(blocks // 2, np.int64)
    within = slot[:, 0, :] % channels  # the slot within its block of return 0
    t = offsets[within]  # [Cp, L]
    first = t.min(axis=1)
    period = model.group_period_ns(n_returns)
    keys = int(key.max()) + 1
    table = np.zeros((keys, lasers), np.int64)
    table[key] = t - first[:, None]
    fraction = (t.astype(np.float32) / np.float32(period)).astype(np.float32)
    return Plan(slot, group, int(first_block.size), first_block, key.astype(np.int16),
                group * period + first, fraction, table, period)


def nominal_step_cdeg(rotation_hz: int, period_ns: int) -> int:
    """The azimuth a rotation at ``rotation_hz`` turns in ``period_ns`` (0.01°, rounded), the step the
    references take for a packet's last group."""
    return int(round(36000 * rotation_hz * period_ns * 1e-9))


def group_steps(azimuth_cdeg: np.ndarray, nominal_cdeg: int) -> np.ndarray:
    """``int32[N, G]`` azimuth step from each group to the next of its packet (``azimuth_cdeg``: ``[N, G]``);
    the nominal one for the last group and across a blind sector."""
    az = azimuth_cdeg.astype(np.int32)
    step = np.empty_like(az)
    step[:, :-1] = (az[:, 1:] - az[:, :-1]) % 36000
    step[:, -1] = nominal_cdeg
    return np.where(step > _BLIND_STEP_CDEG, nominal_cdeg, step)


def pixel_azimuths(group_az: np.ndarray, step: np.ndarray, fraction: np.ndarray) -> np.ndarray:
    """``uint16[..., L]``: ``group_az + trunc(step · fraction)`` mod 36000 (float32, as the references)."""
    add = (step.astype(np.float32)[..., None] * fraction).astype(np.int32)
    return ((group_az.astype(np.int32)[..., None] + add) % 36000).astype(np.uint16)


@lru_cache(maxsize=32)
def _step_table(p: Plan) -> np.ndarray:
    """``uint16[L, (_BLIND_STEP_CDEG + 1) · Cp]``: ``trunc(step · fraction)`` of every laser for every step a
    group can take (0 to 1°) and column of the packet, so that a batch's pixel azimuths are one gather."""
    steps = np.arange(_BLIND_STEP_CDEG + 1, dtype=np.float32)
    add = (steps[:, None, None] * p.fraction[None]).astype(np.int32)  # [steps, Cp, L]
    return np.ascontiguousarray(add.reshape(-1, add.shape[2]).T).astype(np.uint16)


def pixel_azimuth_columns(group_az: np.ndarray, step: np.ndarray, p: Plan) -> np.ndarray:
    """``uint16[L, N · Cp]``: :func:`pixel_azimuths` of every column of N packets (``group_az``, ``step``:
    ``[N, G]``), laid out as the frame's rows take them."""
    cp = p.slot.shape[0]
    key = (step[:, p.group].astype(np.intp) * cp + np.arange(cp)).reshape(-1)
    out = _step_table(p)[:, key]
    out += group_az[:, p.group].reshape(-1).astype(np.uint16)
    np.subtract(out, 36000, out=out, where=out >= 36000)
    return out


def build_columns(raw: RobosensePackets, index: np.ndarray, model: RobosenseModel, n_returns: int,
                  nominal_cdeg: int) -> Columns:
    """The columns of packets ``raw`` (one mode, time order) with source ordinals ``index``."""
    p = plan(model, n_returns)
    n = len(raw)
    cp, r, lasers = p.slot.shape
    flat = p.slot.reshape(-1)
    dist = raw.distance.reshape(n, -1)[:, flat].reshape(n, cp, r, lasers)
    refl = raw.reflectivity.reshape(n, -1)[:, flat].reshape(n, cp, r, lasers)
    distance = np.ascontiguousarray(dist.transpose(2, 3, 0, 1)).reshape(r, lasers, n * cp)
    reflectivity = np.ascontiguousarray(refl.transpose(2, 3, 0, 1)).reshape(r, lasers, n * cp)
    group_az = raw.azimuth_cdeg[:, p.first_block]  # [N, G]
    steps = group_steps(group_az, nominal_cdeg)
    pix = pixel_azimuth_columns(group_az, steps, p)  # [L, N·Cp]
    first_laser = np.argmin(p.time_table[p.key], axis=1)  # the laser of each column's first firing
    col_az = pix[np.tile(first_laser, n), np.arange(n * cp)].astype(np.int32)
    return Columns(
        distance=distance, reflectivity=reflectivity, unit_um=np.repeat(raw.distance_unit_um, cp),
        pixel_azimuth_cdeg=pix, azimuth_cdeg=col_az,
        block_azimuth_cdeg=group_az[:, p.group].astype(np.int32).reshape(-1),
        timestamp_ns=(raw.timestamp_ns[:, None] + p.start_ns[None, :]).reshape(-1),
        time_key=np.tile(p.key, n), packet_index=np.repeat(np.asarray(index, np.int64), cp),
    )


class RubyDualColumns:
    """Dual-return columns of RS-Ruby packets, whose blocks each hold one return (``ret_id`` 1 or 2) and
    whose columns may straddle packets (blocks A A B, then A B B: rs_driver's reading). A column is a
    run of blocks of one azimuth with rising ``ret_id``; a column whose second return has not come yet
    waits for the next batch. Block times as rs_driver gives them: the blocks sharing the first
    block's azimuth at the packet timestamp, the others one period later."""

    def __init__(self, model: RobosenseModel) -> None:
        self.model = model
        self._carry: dict[str, np.ndarray] | None = None

    def reset(self) -> None:
        self._carry = None

    def build(self, raw: RobosensePackets, index: np.ndarray, nominal_cdeg: int, final: bool = False) -> Columns:
        model = self.model
        n, b = raw.azimuth_cdeg.shape
        period = model.block_period_ns
        az = raw.azimuth_cdeg.astype(np.int32)
        late = (az != az[:, :1]).astype(np.int64)  # blocks after the first azimuth of their packet
        blocks = {
            "az": az.reshape(-1), "ret": raw.ret_id.reshape(-1).astype(np.int16) if raw.ret_id is not None
            else np.ones(n * b, np.int16),
            "dist": raw.distance.reshape(n * b, model.channels), "refl": raw.reflectivity.reshape(n * b, model.channels),
            "time": (raw.timestamp_ns[:, None] + late * period).reshape(-1),
            "unit": np.repeat(raw.distance_unit_um, b), "packet": np.repeat(np.asarray(index, np.int64), b),
        }
        if self._carry is not None:
            blocks = {k: np.concatenate([self._carry[k], v]) for k, v in blocks.items()}
            self._carry = None
        m = blocks["az"].size
        if m == 0:
            return _empty_columns(model.lasers, 2)
        new = np.ones(m, bool)
        new[1:] = (blocks["az"][1:] != blocks["az"][:-1]) | (blocks["ret"][1:] <= blocks["ret"][:-1])
        col = np.cumsum(new) - 1
        if not final and blocks["ret"][-1] == 1 and new[-1]:  # its second return is in the next packet
            self._carry = {k: v[-1:] for k, v in blocks.items()}
            blocks = {k: v[:-1] for k, v in blocks.items()}
            new, col = new[:-1], col[:-1]
            if col.size == 0:
                return _empty_columns(model.lasers, 2)
        ncol = int(col[-1]) + 1
        lasers = model.lasers
        slot = np.clip(blocks["ret"] - 1, 0, 1)
        distance = np.zeros((2, lasers, ncol), np.uint16)
        reflectivity = np.zeros((2, lasers, ncol), np.uint8)
        distance[slot, :, col] = blocks["dist"]
        reflectivity[slot, :, col] = blocks["refl"]
        starts = np.flatnonzero(new)
        col_az = blocks["az"][starts]
        step = np.empty(ncol, np.int32)
        step[:-1] = (col_az[1:] - col_az[:-1]) % 36000
        step[-1:] = nominal_cdeg
        step = np.where(step > _BLIND_STEP_CDEG, nominal_cdeg, step)
        p = plan(model, 1)
        fraction = p.fraction[0]  # one column a block: every column fires as a single-return block
        pix = pixel_azimuths(col_az, step, fraction[None])
        return Columns(
            distance=distance, reflectivity=reflectivity, unit_um=blocks["unit"][starts].astype(np.int32),
            pixel_azimuth_cdeg=np.ascontiguousarray(pix.T), azimuth_cdeg=col_az.astype(np.int32),
            block_azimuth_cdeg=col_az.astype(np.int32), timestamp_ns=blocks["time"][starts],
            time_key=np.zeros(ncol, np.int16), packet_index=blocks["packet"][starts],
        )


def _empty_columns(lasers: int, returns: int) -> Columns:
    z = np.zeros(0, np.int64)
    return Columns(np.zeros((returns, lasers, 0), np.uint16), np.zeros((returns, lasers, 0), np.uint8),
                   np.zeros(0, np.int32), np.zeros((lasers, 0), np.uint16), np.zeros(0, np.int32),
                   np.zeros(0, np.int32), z, np.zeros(0, np.int16), z)
