"""When each laser of a RoboSense block fires, per model: the tables every time and azimuth of a pixel
derives from.

A block's slots fire at fixed offsets from the block's first firing; blocks follow each other at the
model's block period. The packet timestamp is the time of its first block's first firing (the
manuals' "time of the first data point in the packet"). Offsets in ns:

* RS-LiDAR-16 (user manual, Appendix A): 16 lasers 2.8 µs apart, a firing sequence every 55.5 µs; a
  block holds two sequences in single return (slots 16-31: the second), one in dual.
* RS-LiDAR-32: rs_driver's table (32 lasers in two interleaved banks 1.44 µs apart, 55.52 µs period).
* RS-Bpearl (user manual, Appendix A): 2.56 µs steps, the second bank 1.28 µs later, channels 9-16
  and 25-32 another 5.2 µs later; 55.52 µs period. RS-Bpearl V4: 1.67 µs steps, 55.56 µs (rs_driver).
* RS-Helios and RS-Helios-16P: 32 slots 1.73 µs apart, a block every 55.56 µs (rs_driver's table
  since March 2024). It replaced a table spread over 45.15 µs (RS-Helios) and, for the 16P, one
  whose second sequence started 55.56 µs after the first: that older table cannot hold for packets
  whose blocks come 55.56 µs apart, as they do in the real capture (12 blocks every 666.7 µs, 0.2°
  apart at 600 rpm), so two sequences of 16 firings must share the 55.56 µs.
* RS-Ruby (RS128 in rs_driver): lasers in groups of four, 3.236 µs apart; lasers 64-127 fire with
  0-63; 55.55 µs period.
* RS-Ruby Plus: groups of four over 50.53 µs (rs_driver's March 2024 table, read as the 32 groups it
  lists: its copy repeats one entry, which moves the second half one laser late, and keeps a stale
  last value; the groups of four are restored here), 55.56 µs period.
"""

from __future__ import annotations

import numpy as np

_US = 1000  # ns


def _steps(step_ns: int, n: int, start_ns: int = 0) -> tuple[int, ...]:
    return tuple(start_ns + step_ns * k for k in range(n))


RS16 = _steps(2800, 16) + _steps(2800, 16, 55500)
RS32 = tuple(round(v * _US) for v in (
    0.00, 2.88, 5.76, 8.64, 11.52, 14.40, 17.28, 20.16, 23.04, 25.92, 28.80, 31.68, 34.56, 37.44, 40.32, 44.64,
    1.44, 4.32, 7.20, 10.08, 12.96, 15.84, 18.72, 21.60, 24.48, 27.36, 30.24, 33.12, 36.00, 38.88, 41.76, 46.08))
BPEARL = tuple(2560 * (s % 16) + 1280 * (s // 16) + (5200 if s % 16 >= 8 else 0) for s in range(32))
BPEARL_V4 = tuple(round(v * _US) for v in (
    0.00, 1.67, 3.34, 5.00, 6.67, 8.34, 10.01, 11.68, 13.34, 15.01, 16.68, 18.35, 20.02, 21.68, 23.35, 25.02,
    26.69, 28.36, 30.02, 31.69, 33.36, 35.03, 36.70, 38.36, 40.03, 41.70, 43.37, 45.04, 46.70, 48.37, 50.04, 51.71))
HELIOS = _steps(1730, 32)
_RUBY_GROUPS = tuple(round(3.236 * k * _US) for k in range(16))
RUBY = tuple(g for g in _RUBY_GROUPS for _ in range(4)) * 2
_RUBY_PLUS_GROUPS = tuple(round(v * _US) for v in (
    0.0, 1.13, 2.13, 3.26, 4.26, 5.38, 6.38, 7.51, 8.51, 10.01, 11.38, 13.31, 15.11, 17.04, 18.85, 21.14,
    23.31, 25.61, 27.78, 30.07, 32.24, 34.54, 36.7, 38.64, 40.44, 41.94, 43.3, 44.8, 46.17, 47.66, 49.03, 50.53))
RUBY_PLUS = tuple(g for g in _RUBY_PLUS_GROUPS for _ in range(4))

#: key of :attr:`RobosenseModel.timing` → firing time of each block slot after the block's first firing (ns)
TABLES: dict[str, tuple[int, ...]] = {
    "rs16": RS16, "rs32": RS32, "bpearl": BPEARL, "bpearl_v4": BPEARL_V4, "helios": HELIOS, "ruby": RUBY,
    "ruby_plus": RUBY_PLUS,
}
for _key, _table in TABLES.items():
    if len(_table) not in (32, 128) or min(_table) != 0:
        raise ImportError(f"RoboSense firing table {_key}: {len(_table)} slots")


def slot_offsets_ns(timing: str, firings_per_block: int, n_returns: int) -> np.ndarray:
    """``int64[S]``: firing time of each block slot after the block's first firing. In dual return a
    block that holds two returns of one sequence (``firings_per_block`` 2: RS-LiDAR-16, RS-Helios-16P)
    gives both halves the first sequence's times."""
    table = np.asarray(TABLES[timing], np.int64)
    if n_returns == 2 and firings_per_block == 2:
        half = table.size // 2
        return np.concatenate([table[:half], table[:half]])
    return table
