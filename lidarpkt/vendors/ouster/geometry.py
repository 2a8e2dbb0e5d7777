"""Ouster XYZ: the lookup table of ouster-sdk (``make_xyz_lut``), sensor frame, metres.

For column c of W (staggered: column = measurement id) and row u:

* encoder angle θe = 2π · (1 − c / W), beam azimuth θa = −beam_azimuth_deg[u], elevation φ = beam_altitude_deg[u];
* direction = (cos(θe + θa) cos φ, sin(θe + θa) cos φ, sin φ);
* n = beam_to_lidar_transform[0, 3] (√(x² + z²) when the z translation is non-zero);
  offset = (tx cos θe − dir_x n, tx sin θe − dir_y n, −dir_z n + tz), tx/tz the beam_to_lidar translation;
* point = (range_mm · direction + offset), rotated and translated by lidar_to_sensor_transform (mm),
  then × 0.001 → metres. A range of 0 (no return) gives (0, 0, 0).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from functools import cached_property

import numpy as np

from lidarpkt.core import kernels


class OusterGeometry:
    """XYZ of Ouster frames (implements :class:`lidarpkt.core.sensor.Geometry`)."""

    def __init__(self, metadata) -> None:
        self.metadata = metadata

    @cached_property
    def _tables(self) -> "_Tables":
        """The tables of this calibration, shared by every geometry of the same one (:func:`_shared_tables`),
        so that each ``lidarpkt.open`` of a sensor's captures does not build them again."""
        md = self.metadata
        key = (md.columns_per_frame, md.pixels_per_column,
               *(np.asarray(a, np.float64).tobytes() for a in (md.beam_to_lidar_transform, md.lidar_to_sensor_transform,
                                                                md.beam_azimuth_deg, md.beam_altitude_deg)))
        return _shared_tables(key, lambda: _Tables(self._make_lut))

    @property
    def lut(self) -> tuple[np.ndarray, np.ndarray]:
        """(direction, offset), each ``float64[H, W, 3]`` (read-only): metres per mm of range, and metres."""
        return self._tables.lut

    def _make_lut(self) -> tuple[np.ndarray, np.ndarray]:
        md = self.metadata
        w = md.columns_per_frame
        b2l = np.asarray(md.beam_to_lidar_transform, np.float64)
        l2s = np.asarray(md.lidar_to_sensor_transform, np.float64)
        encoder = 2.0 * np.pi * (1.0 - np.arange(w, dtype=np.float64) / w)  # [W]
        azimuth = -np.deg2rad(np.asarray(md.beam_azimuth_deg, np.float64))  # [H]
        altitude = np.deg2rad(np.asarray(md.beam_altitude_deg, np.float64))  # [H]
        n = b2l[0, 3]
        if b2l[2, 3] != 0:
            n = np.sqrt(b2l[0, 3] ** 2 + b2l[2, 3] ** 2)
        theta = encoder[None, :] + azimuth[:, None]  # [H, W]
        cos_phi = np.cos(altitude)[:, None]
        direction = np.stack(
            [np.cos(theta) * cos_phi, np.sin(theta) * cos_phi, np.broadcast_to(np.sin(altitude)[:, None], theta.shape)],
            axis=-1,
        )
        offset = np.stack(
            [
                np.cos(encoder)[None, :] * b2l[0, 3] - direction[..., 0] * n,
                np.sin(encoder)[None, :] * b2l[0, 3] - direction[..., 1] * n,
                -direction[..., 2] * n + b2l[2, 3],
            ],
            axis=-1,
        )
        rot = l2s[:3, :3]
        direction = direction @ rot.T
        offset = offset @ rot.T + l2s[:3, 3]
        return direction * 0.001, offset * 0.001

    @property
    def _planes(self) -> tuple[np.ndarray, np.ndarray]:
        return self._tables.planes

    @property
    def _planes32(self) -> tuple[np.ndarray, np.ndarray]:
        return self._tables.planes32

    def xyz(self, frame, dtype: "np.typing.DTypeLike" = np.float64) -> np.ndarray:
        """Points of ``frame`` as ``[R, H, W, 3]`` metres of ``dtype``; zeros where ``range_mm`` is 0.

        Each point is ``range_mm · direction + offset``: float64, the same double-precision products
        and sums as ouster-sdk's ``XYZLut``; float32, those of its ``XYZLutFloat`` (the float64 table
        rounded to float32, float32 products and sums), half the memory traffic. Computed in blocks
        of rows (bounded temporaries), one coordinate plane at a time with contiguous operands; pixels
        without a return are zeroed by AND-ing the bits with an all-ones/all-zeros mask in the same
        pass that writes the (interleaved) output: +0.0 exactly, no separate masking pass.
        """
        dtype = np.dtype(dtype)
        direction, offset = self._planes32 if dtype == np.float32 else self._planes
        rng = frame.range_mm
        r, h, w = rng.shape
        out = np.empty((r, h, w, 3), dtype)
        native = kernels.native
        if native is not None:
            native.xyz_lut(np.ascontiguousarray(rng, np.uint32), direction, offset, out)
            return out
        word = np.uint64 if dtype == np.float64 else np.uint32
        bits = out.view(word)
        rows = max(1, min(h, _BLOCK_PIXELS // max(1, r * w)))
        tmp = np.empty((r, rows, w), dtype)
        for a in range(0, h, rows):
            b = min(h, a + rows)
            t = tmp[:, : b - a]
            block = rng[:, a:b]
            scale = block.astype(dtype)
            keep = (block != 0).view(np.uint8).astype(word)
            np.negative(keep, out=keep)  # 1 → all ones, 0 → 0
            for k in range(3):
                np.multiply(scale, direction[k, a:b], out=t)
                t += offset[k, a:b]
                np.bitwise_and(t.view(word), keep, out=bits[:, a:b, :, k])
        return out


_BLOCK_PIXELS = 65536  # pixels per block of rows in xyz (512 KB float64 temporaries; smaller blocks measured slower in the pipeline: per-call overhead)


class _Tables:
    """One calibration's lookup tables, each made when first asked for (read-only arrays)."""

    def __init__(self, make_lut) -> None:
        self._make_lut = make_lut

    @cached_property
    def lut(self) -> tuple[np.ndarray, np.ndarray]:
        return _read_only(self._make_lut())

    @cached_property
    def planes(self) -> tuple[np.ndarray, np.ndarray]:
        """The lookup table as planes: direction and offset, each ``float64[3, H, W]`` (contiguous)."""
        return _read_only(tuple(np.ascontiguousarray(t.transpose(2, 0, 1)) for t in self.lut))

    @cached_property
    def planes32(self) -> tuple[np.ndarray, np.ndarray]:
        """:attr:`planes` rounded to float32: the table of ouster-sdk's ``XYZLutFloat`` (rounded from the table
        itself, so that asking only for float32 points makes no float64 planes)."""
        return _read_only(tuple(t.transpose(2, 0, 1).astype(np.float32, order="C") for t in self.lut))


def _read_only(tables: tuple) -> tuple:
    for t in tables:
        t.setflags(write=False)
    return tables


_TABLES: "OrderedDict[tuple, _Tables]" = OrderedDict()
_TABLES_KEPT = 4  # calibrations whose tables are kept (an OS-128 x 2048 sensor's are 32 MB, x 1024 16 MB)
_TABLES_LOCK = threading.Lock()


def _shared_tables(key: tuple, make) -> _Tables:
    """The tables of the calibration ``key``, made by ``make()`` the first time (the most recent few kept)."""
    with _TABLES_LOCK:
        tables = _TABLES.get(key)
        if tables is None:
            tables = _TABLES[key] = make()
            while len(_TABLES) > _TABLES_KEPT:
                _TABLES.popitem(last=False)
        _TABLES.move_to_end(key)
        return tables
