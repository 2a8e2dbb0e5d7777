"""Where each firing of a model sits in a packet: the per-block, per-channel tables a model row implies.

For a model (:mod:`lidarpkt.vendors.velodyne.models`) and a return mode, :func:`packet_layout` gives, for
each of the 12 × 32 channels of a packet: its frame column inside the packet, its laser id, its
return slot (dual: 0 = last, 1 = strongest), the block whose azimuth it takes, its firing time after
the packet timestamp, and the delay after the firing the block azimuth was measured at (for the
azimuth interpolation). Single-return layouts, by model:

* 16-laser Pucks: block b holds columns 2b and 2b + 1 (channels 0–15, 16–31), laser = channel % 16;
* HDL-32E, VLP-32: block b is column b, laser = channel;
* HDL-64E: blocks 2c (upper, 0xEEFF, lasers 0–31) and 2c + 1 (lower, 0xDDFF, lasers 32–63) are column c;
* VLS-128: blocks 4c … 4c + 3 (banks 0xEEFF, 0xDDFF, 0xCCFF, 0xBBFF, lasers 32k + channel) are column c.

Dual-return layouts (``VelodyneModel.dual_layout``):

* ``pairs``: blocks 2k (last) and 2k + 1 (strongest) hold the same firings, those of single block k;
* ``upper_lower`` (HDL-64E): blocks 4k, 4k + 1 hold the strongest returns (upper, lower) of column k,
  blocks 4k + 2, 4k + 3 the last ones;
* ``banks`` (VLS-128): blocks 2k (last) and 2k + 1 (strongest) hold bank k of the packet's one column;
  blocks 8–11 are unused.

The azimuth tables follow velodyne_decoder 3.1.0 (its float32 firing-time table, the delay taken
from the first firing of a block's column, or of its block on the 16-laser Pucks), so that both give
the same 0.01° for every firing.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from .models import BANK_FLAGS, VelodyneModel

BLOCKS, CHANNELS = 12, 32


@dataclass(frozen=True, eq=False)
class PacketLayout:
    """The channels of one packet of a model in one return mode; every array is ``[12, 32]`` unless said.

    Attributes:
        columns: frame columns one packet carries.
        slots: return slots (2 in dual mode).
        column: column of each channel inside the packet, −1 for an unused block.
        laser: laser id of each channel.
        slot: return slot of each channel.
        azimuth_block: the block whose azimuth the channel's firing is interpolated from.
        flag: the block flag each block must carry, ``[12]`` (0 for an unused block).
        firing_ns: firing time after the packet timestamp, ns, float64.
        dt_s32: delay after the firing its block azimuth belongs to, float32 seconds (velodyne_decoder's).
        rate_span_s32: float32 seconds between the first block's azimuth and the last used block's.
        source: ``int64[slots, lasers, columns]`` channel index (block · 32 + channel) of every pixel.
    """

    columns: int
    slots: int
    column: np.ndarray
    laser: np.ndarray
    slot: np.ndarray
    azimuth_block: np.ndarray
    flag: np.ndarray
    firing_ns: np.ndarray
    dt_s32: np.ndarray
    rate_span_s32: np.float32
    source: np.ndarray

    @property
    def last_block(self) -> int:
        """The last block whose azimuth is read (11, or 6 in the VLS-128's dual mode)."""
        return int(self.azimuth_block.max())


def single_timing(model: VelodyneModel) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Single-return mode tables ``[12, 32]``: column, laser, firing time after the packet stamp (ns,
    float64) and the same in float32 seconds as velodyne_decoder tabulates it (double → float)."""
    b, j = np.meshgrid(np.arange(BLOCKS), np.arange(CHANNELS), indexing="ij")
    lasers_per_block = CHANNELS // model.sequences_per_block
    column = b // model.blocks_per_column * model.sequences_per_block + j // lasers_per_block
    laser = (b % model.blocks_per_column) * CHANNELS + j % lasers_per_block
    offsets = np.asarray(model.laser_offsets_ns, np.float64)
    firing = model.column_offset_ns + column * float(model.sequence_ns) + offsets[laser]
    return column, laser, firing, (firing * 1e-9).astype(np.float32)


@functools.lru_cache(maxsize=32)
def packet_layout(model: VelodyneModel, mode: str) -> PacketLayout:
    """The :class:`PacketLayout` of ``model`` in return mode ``mode`` (``"strongest"``, ``"last"``, ``"dual"``)."""
    col1, las1, fire1, t32 = single_timing(model)
    b = np.arange(BLOCKS)[:, None] * np.ones(CHANNELS, np.int64)[None, :]
    j = np.arange(CHANNELS)[None, :] * np.ones(BLOCKS, np.int64)[:, None]
    bpc = model.blocks_per_column
    if mode != "dual":
        time_block = b
        ref_block = b // bpc * bpc  # the column's first block (each block of a Puck: its own)
        az_block = b
        slot = np.zeros_like(b)
        flag = np.array([BANK_FLAGS[i % bpc] for i in range(BLOCKS)])
        slots = 1
    elif model.dual_layout == "pairs":
        time_block = b // 2
        ref_block = time_block
        az_block = b - b % 2
        slot = b % 2  # block 2k: last, 2k + 1: strongest
        flag = np.full(BLOCKS, BANK_FLAGS[0])
        slots = 2
    elif model.dual_layout == "upper_lower":
        k, first = b // 4, b % 4 < 2  # 4k, 4k+1 strongest (upper, lower); 4k+2, 4k+3 last
        time_block = k * 2 + b % 2
        ref_block = k * 2
        az_block = np.where(first, b, b - 2)
        slot = np.where(first, 1, 0)
        flag = np.array([BANK_FLAGS[i % 2] for i in range(BLOCKS)])
        slots = 2
    else:  # banks: one column, bank k in blocks 2k (last) and 2k + 1 (strongest)
        time_block = np.minimum(b // 2, bpc - 1)
        ref_block = np.zeros_like(b)
        az_block = b - b % 2
        slot = b % 2
        flag = np.array([BANK_FLAGS[i // 2] if i < 2 * bpc else 0 for i in range(BLOCKS)])
        slots = 2
    column = col1[time_block, j]
    laser = las1[time_block, j]
    firing = fire1[time_block, j]
    dt = t32[time_block, j] - t32[ref_block, 0]
    if mode == "dual" and model.dual_layout == "banks":
        column = np.where(b < 2 * bpc, column, -1)
    columns = model.columns_per_packet(mode)
    used_az = az_block[column[:, 0] >= 0, 0]
    last = int(used_az.max())
    span = t32[time_block[last, 0], 0] - t32[0, 0]
    if model.dual_layout == "banks":  # the VLS-128 measures its rate between packets: one packet's time
        span = np.float32(t32[4, 0] - t32[0, 0]) * np.float32(1 if mode == "dual" else 3)
    source = np.full((slots, model.lasers, columns), -1, np.int64)
    used = column >= 0
    source[slot[used], laser[used], column[used]] = (b * CHANNELS + j)[used]
    if np.any(source < 0):  # a layout typo, caught when the table is first asked for
        raise AssertionError(f"{model.name} {mode}: the layout leaves pixels without a channel")
    for a in (column, laser, slot, az_block, flag, firing, dt, source):
        a.flags.writeable = False
    return PacketLayout(columns=columns, slots=slots, column=column, laser=laser, slot=slot, azimuth_block=az_block,
                        flag=flag, firing_ns=firing, dt_s32=dt.astype(np.float32), rate_span_s32=np.float32(span),
                        source=source)
