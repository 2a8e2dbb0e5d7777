"""Firing times of Hesai Pandar lasers relative to their packet's timestamp, per model.

A packet's timestamp (UTC second of the tail + ``timestamp_us``) is one instant of its firings;
each laser of each block fires at a fixed offset from it ("Laser Firing Time" / "Point Time
Calculation" of each user manual). The offsets are the sum of a block term (which firing
sequence of the packet) and a channel term (which laser of the sequence), both in ns; a block of
a dual- or triple-return packet shares its firing sequence with the other returns of its group.

The tables (as the manuals give them; nebula's ``get_packet_relative_point_time_offset`` uses the
same numbers):

* Pandar40P / Pandar64: block ``base − 55 560 · ⌊(B − b − 1) / n⌋`` (base −28 580 / −42 580 ns),
  channel from a per-laser table (negative: the timestamp is taken after the firings).
* PandarQT64: block ``25 710 + ⌊500 000 · ⌊b / n⌋ / 3⌋``, channel from a table.
* PandarQT128: block ``9 000 + ⌊111 110 · (1 − b) / n⌋``; channel from one of two loop tables
  (single return: block 0 loop 1, block 1 loop 2; dual: ``mode_flag`` bit 0 set → loop 1).
* PandarXT16 / XT32 / XT32M: block ``5 632 − 50 000 · ⌊(S − b − 1) / n⌋`` (S = 8, on the XT32M in
  triple mode 6), channel ``368 + step · (c mod m)`` (step 3 024 / 1 512 / 2 888 ns; m = 16 on the
  XT32M, whose two banks of 16 fire together).

``b`` is the block index, ``n`` the returns per firing, ``c`` the channel (0-based).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .models import HesaiModel

# Pandar40P user manual, "Laser Firing Time" (ns after the block's start, written as offsets from the timestamp)
P40_CHANNEL_NS = (
    -42220, -28470, -16040, -3620, -45490, -31740, -47460, -54670, -20620, -33710,
    -40910, -8190, -20620, -27160, -50730, -8190, -14740, -36980, -45490, -52700,
    -23890, -31740, -38950, -11470, -18650, -25190, -48760, -6230, -12770, -35010,
    -21920, -9500, -43520, -29770, -17350, -4920, -42220, -28470, -16040, -3620,
)
P64_CHANNEL_NS = (
    -23180, -21876, -20572, -19268, -17964, -16660, -11444, -46796, -7532, -36956, -50732,
    -54668, -40892, -44828, -31052, -34988, -48764, -52700, -38924, -42860, -29084, -33020,
    -46796, -25148, -36956, -50732, -27116, -40892, -44828, -31052, -34988, -48764, -25148,
    -38924, -42860, -29084, -33020, -52700, -6228, -54668, -15356, -27116, -10140, -23180,
    -4924, -21876, -14052, -17964, -8836, -19268, -3620, -20572, -12748, -16660, -7532,
    -11444, -6228, -15356, -10140, -4924, -3620, -14052, -8836, -12748,
)
# Channel 56 (index 55) fires at 129 600 ns: the table climbs by ~2 050 ns a laser (127 540, ?, 132 050);
# nebula's copy reads 12 960, a digit lost (tests/hesai/test_hesai_timing.py pins it).
QT64_CHANNEL_NS = (
    12310, 14370, 16430, 18490, 20540, 22600, 24660, 26710, 29160, 31220, 33280,
    35340, 37390, 39450, 41500, 43560, 46610, 48670, 50730, 52780, 54840, 56900,
    58950, 61010, 63450, 65520, 67580, 69630, 71690, 73740, 75800, 77860, 80900,
    82970, 85020, 87080, 89140, 91190, 93250, 95300, 97750, 99820, 101870, 103930,
    105980, 108040, 110100, 112150, 115200, 117260, 119320, 121380, 123430, 125490, 127540,
    129600, 132050, 134110, 136170, 138220, 140280, 142340, 144390, 146450,
)
QT128_LOOP1_NS = (
    *(0,) * 32,
    27656, 53000, 2312, 78344, 81512, 5480, 56168, 30824, 33992, 59336, 8648, 84680, 87848, 11816, 62504, 37160,
    40328, 65672, 14984, 91016, 94184, 18152, 68840, 43496, 46664, 72008, 21320, 97352, 100520, 24488, 75176, 49832,
    1456, 77488, 26800, 52144, 55312, 29968, 80656, 4624, 7792, 83824, 33136, 58480, 61648, 36304, 86992, 10960,
    14128, 90160, 39472, 64816, 67984, 42640, 93328, 17296, 20464, 96496, 45808, 71152, 74320, 48976, 99664, 23632,
    25944, 51288, 600, 76632, 79800, 3768, 54456, 29112, 32280, 57624, 6936, 82968, 86136, 10104, 60792, 35448,
    38616, 63960, 13272, 89304, 92472, 16440, 67128, 41784, 44952, 70296, 19608, 95640, 98808, 22776, 73464, 48120,
)
QT128_LOOP2_NS = (
    2312, 78344, 27656, 53000, 56168, 30824, 81512, 5480, 8648, 84680, 33992, 59336, 62504, 37160, 87848, 11816,
    14984, 91016, 40328, 65672, 68840, 43496, 94184, 18152, 21320, 97352, 46664, 72008, 75176, 49832, 100520, 24488,
    *(0,) * 32,
    600, 76632, 25944, 51288, 54456, 29112, 79800, 3768, 6936, 82968, 32280, 57624, 60792, 35448, 86136, 10104,
    13272, 89304, 38616, 63960, 67128, 41784, 92472, 16440, 19608, 95640, 44952, 70296, 73464, 48120, 98808, 22776,
    26800, 52144, 1456, 77488, 80656, 4624, 55312, 29968, 33136, 58480, 7792, 83824, 86992, 10960, 61648, 36304,
    39472, 64816, 14128, 90160, 93328, 17296, 67984, 42640, 45808, 71152, 20464, 96496, 99664, 23632, 74320, 48976,
)


def firing_offsets_ns(model: HesaiModel, n_returns: int, mode_flag: np.ndarray | None = None) -> np.ndarray:
    """``int64[N or 1, G, C]``: firing time of each channel of each firing group (G = blocks / n_returns)
    after the packet timestamp, ns. ``mode_flag`` (``uint8[N]``, the QT128 tail's) selects the QT128's
    loop in dual mode; other models give one row for every packet."""
    b = np.arange(0, model.blocks, n_returns, dtype=np.int64)  # first block of each group
    c = np.arange(model.channels, dtype=np.int64)
    kind = model.timing
    if kind in ("p40", "p64"):
        base = -28580 if kind == "p40" else -42580
        block = base - 55560 * ((model.blocks - b - 1) // n_returns)
        chan = np.array(P40_CHANNEL_NS if kind == "p40" else P64_CHANNEL_NS, np.int64)
    elif kind == "qt64":
        block = 25710 + (500000 * (b // n_returns)) // 3
        chan = np.array(QT64_CHANNEL_NS, np.int64)
    elif kind == "qt128":
        block = 9000 + (111110 * (1 - b)) // n_returns
        loops = np.array([QT128_LOOP1_NS, QT128_LOOP2_NS], np.int64)  # [2, C]
        if n_returns == 1:
            return (block[:, None] + loops[b % 2])[None]
        flag = np.zeros(1, np.uint8) if mode_flag is None else np.asarray(mode_flag)
        loop = np.where((flag & 1) == 1, 0, 1)  # [N]
        return block[None, :, None] + loops[loop][:, None, :]
    else:  # XT family
        span = 6 if (kind == "xt32m" and n_returns == 3) else 8
        block = 5632 - 50000 * ((span - b - 1) // n_returns)
        step = {"xt16": 3024, "xt32": 1512, "xt32m": 2888}[kind]
        chan = 368 + step * (c % 16 if kind == "xt32m" else c)
    return (block[:, None] + chan[None, :])[None]
