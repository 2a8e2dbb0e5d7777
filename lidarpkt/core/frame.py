"""Frames: one rotation of one sensor as a range image, and its points.

Shapes use R = return slots, H = rows (beams, row 0 = highest elevation), W = columns.
Every array with a trailing W axis is per column; ``[R, H, W]`` arrays are per pixel and slot.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from lidarpkt.errors import AnalysisError, CalibrationError, UsageError
from .grid import _grid_bins, _grid_positions, default_grid_deg, destagger
from .sensor import SensorInfo


@dataclass
class FrameCounters:
    """What went wrong while a frame was assembled, counted (never silently dropped)."""

    lost_packets: int = 0  # packets missing inside the frame (gaps in azimuth / measurement id)
    duplicate_packets: int = 0
    out_of_order_packets: int = 0
    late_packets: int = 0  # packets of this frame that arrived after it was released (dropped)
    malformed_packets: int = 0  # wrong size, bad flag, bad CRC: skipped
    grid_collisions: int = 0  # on_grid: firings that fell in an occupied bin (first kept)

    def add(self, other: "FrameCounters") -> "FrameCounters":
        return FrameCounters(**{f.name: getattr(self, f.name) + getattr(other, f.name) for f in fields(self)})


_PER_COLUMN = ("column_valid", "column_timestamp_ns", "azimuth_deg", "measurement_id", "status", "encoder_count")
_PER_PIXEL = ("range_mm", "reflectivity", "signal", "near_ir", "flags", "pixel_time_offset_ns")


@dataclass(eq=False)
class Frame:
    """One rotation of one sensor as a range image.

    Attributes:
        sensor: the :class:`SensorInfo` of the sensor that sent it.
        frame_id: Ouster: the frame id of its packets. VLP-16 and Hesai: rotation counter from the
            start of the input (0 = the first, possibly partial, rotation).
        range_mm: ``uint32[R, H, W]`` range in millimetres (exact sensor units converted);
            0 = the sensor fired and reported no return.
        reflectivity: ``uint8[R, H, W]`` as the sensor reports it.
        signal: Ouster ``uint16[R, H, W]`` signal photons, else ``None``.
        near_ir: Ouster ``uint16[H, W]`` ambient near-infrared, else ``None``.
        flags: Ouster ``uint8[R, H, W]`` per-pixel flags, else ``None``.
        return_labels: tuple of R labels (``"strongest"``, ``"last"``, ``"second_strongest"``...).
        column_valid: ``bool[W]``; False where no packet delivered this column (**no
            sample**, not the same as no return).
        column_timestamp_ns: ``int64[W]`` time of each column's first firing, ns since
            the Unix epoch; 0 for invalid columns.
        azimuth_deg: ``float64[W]`` measured (VLP-16) or nominal encoder (Ouster) azimuth
            of each column, degrees in [0, 360).
        measurement_id: Ouster ``uint16[W]``, else ``None``.
        status: Ouster ``uint32[W]`` column status, else ``None``.
        encoder_count: Ouster legacy ``uint32[W]``, else ``None``.
        pixel_time_offset_ns: ``int64[H, W]`` firing time of each pixel after its
            column timestamp, where the sensor defines it (VLP-16), else ``None``.
        partial: True for a frame that does not cover a whole rotation (start or end
            of a capture, or cut by a lost stretch of packets).
        counters: :class:`FrameCounters` of this frame.
        extra: vendor-specific arrays, by name (a field the sensor's manual names, in lower case:
            ``window``, ``zone_mask``...); those with a trailing W axis are per column (gathered with
            the columns by :meth:`on_grid`), the others per packet or per frame. Each vendor module
            documents its keys.
    """

    sensor: SensorInfo
    frame_id: int
    range_mm: np.ndarray
    reflectivity: np.ndarray
    return_labels: tuple[str, ...]
    column_valid: np.ndarray
    column_timestamp_ns: np.ndarray
    azimuth_deg: np.ndarray
    signal: np.ndarray | None = None
    near_ir: np.ndarray | None = None
    flags: np.ndarray | None = None
    measurement_id: np.ndarray | None = None
    status: np.ndarray | None = None
    encoder_count: np.ndarray | None = None
    pixel_time_offset_ns: np.ndarray | None = None
    partial: bool = False
    counters: FrameCounters = field(default_factory=FrameCounters)
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    # ------------------------------------------------------------------ shape
    @property
    def shape(self) -> tuple[int, int, int]:
        """(R, H, W)."""
        r, h, w = self.range_mm.shape
        return int(r), int(h), int(w)

    @property
    def timestamp_ns(self) -> int:
        """Time of the first valid column, ns since the Unix epoch (0 if no column is valid)."""
        valid = self.column_timestamp_ns[self.column_valid]
        return int(valid[0]) if valid.size else 0

    @property
    def n_returns(self) -> int:
        """Number of pixels (over all slots) that hold a return."""
        return int(np.count_nonzero(self.range_mm))

    # ---------------------------------------------------------------- geometry
    def xyz(self, dtype: "np.typing.DTypeLike" = np.float64) -> np.ndarray:
        """Points as ``[R, H, W, 3]`` metres in the reference tools' frame, zeros where there is no
        return.

        ``dtype``: float64 (the default), or float32 for half the memory: Ouster, ouster-sdk's
        ``XYZLutFloat`` values (float32 table, products and sums); VLP-16, the float64 points rounded.

        Raises:
            CalibrationError: the sensor has no calibration.
            UsageError: ``dtype`` is neither float64 nor float32.
        """
        try:
            point_dtype: np.dtype | None = np.dtype(dtype)
        except TypeError:
            point_dtype = None
        if point_dtype not in (np.float64, np.float32):
            raise UsageError("xyz(dtype=...): not float64 or float32; give numpy.float64 or numpy.float32")
        if self.sensor.geometry is None:
            raise CalibrationError(
                f"no calibration for {self.sensor.model} from {self.sensor.source}: "
                "pass the sensor's metadata/calibration file to compute points"
            )
        return self.sensor.geometry.xyz(self, point_dtype)

    def has_return(self) -> np.ndarray:
        """``bool[R, H, W]``: the pixels that hold a return (range > 0 in a column a packet delivered).

        The one mask every point output uses: :meth:`points` has a row for each True pixel."""
        return (self.range_mm > 0) & np.asarray(self.column_valid, bool)[None, None, :]

    def points(self, dtype: "np.typing.DTypeLike" = np.float64) -> np.ndarray:
        """The frame's returns as a structured array, one row per return, the source of every point
        output (Parquet, LAS/LAZ, PLY, PCD, PointCloud2, Foxglove).

        A row for each return slot of each pixel that holds a return (:meth:`has_return`), in C
        order of ``[R, H, W]``: slot, then row, then column (Ouster columns staggered, as sent).
        A dual-return pixel whose two slots repeat one return is two rows. Fields (:func:`points_dtype`):

        ============  =========  ==============================================================
        field         type       meaning
        ============  =========  ==============================================================
        x, y, z       ``dtype``  metres, :meth:`xyz` (float64, or float32 as ``xyz(float32)``)
        range_mm      uint32     range in millimetres (> 0)
        reflectivity  uint8      the sensor's reflectivity
        row           uint16     beam, 0 = the highest elevation
        column        uint16     column of the frame's arrays
        return_slot   uint8      index in ``return_labels``
        timestamp_ns  int64      the return's firing time, ns since the Unix epoch (column time +
                                 ``pixel_time_offset_ns`` where the sensor defines it)
        signal        uint16     Ouster: signal photons (only when the frame has ``signal``)
        near_ir       uint16     Ouster: ambient near-IR of the pixel (only when it has ``near_ir``)
        ============  =========  ==============================================================

        Raises:
            CalibrationError: the sensor has no calibration.
            UsageError: ``dtype`` is neither float64 nor float32.
        """
        xyz = self.xyz(dtype)
        r, h, w = self.shape
        # flat indices once, then takes: cheaper than a boolean mask per array
        flat = np.flatnonzero(self.has_return())
        pixel = flat % (h * w)  # index into [H, W]
        slot, col = flat // (h * w), flat % w
        out = np.empty(flat.size, points_dtype(self, xyz.dtype))
        sel = xyz.reshape(-1, 3)[flat]
        out["x"], out["y"], out["z"] = sel[:, 0], sel[:, 1], sel[:, 2]
        out["range_mm"] = self.range_mm.reshape(-1)[flat]
        out["reflectivity"] = self.reflectivity.reshape(-1)[flat]
        out["row"], out["column"], out["return_slot"] = pixel // w, col, slot
        t = self.column_timestamp_ns[col]
        if self.pixel_time_offset_ns is not None:
            t = t + self.pixel_time_offset_ns.reshape(-1)[pixel]
        out["timestamp_ns"] = t
        if self.signal is not None:
            out["signal"] = self.signal.reshape(-1)[flat]
        if self.near_ir is not None:
            out["near_ir"] = self.near_ir.reshape(-1)[pixel]
        return out

    def on_grid(self, resolution_deg: float | None = None) -> "Frame":
        """This frame on a fixed azimuth grid, so that pixel (i, j) is the same raypath in every frame.

        Column j covers azimuths [j·res, (j+1)·res); a firing is placed by its azimuth smoothed
        over neighbouring firings (the encoder's jitter would otherwise empty some bins and double
        others on a grid as fine as the firings), and keeps its measured ``azimuth_deg``. Where two
        firings fall in one bin the first is kept and the collision is counted in
        ``counters.grid_collisions``; an empty bin is an invalid column (no sample: a packet was
        lost). Per-column and per-pixel arrays, and every per-column array in ``extra``, move with their
        columns.

        ``resolution_deg`` defaults to :func:`default_grid_deg` of the sensor, the one grid that
        ``FrameStack.from_frames``, ``lidarpkt decode -o x.npz`` and ``lidarpkt analyze`` use. A
        frame whose columns already are that grid (columns by measurement id, as Ouster's) is returned
        unchanged.
        """
        res = resolution_deg if resolution_deg is not None else default_grid_deg(self.sensor)
        if res is None:
            return self
        n_bins = int(round(360.0 / res))
        if abs(n_bins * res - 360.0) > 1e-9:
            near = 360.0 / max(1, n_bins)
            raise AnalysisError(f"grid resolution {res:g}° does not divide 360°; give one that does, e.g. {near:g} "
                                f"(360/{max(1, n_bins)})")
        w = self.shape[2]
        if self.measurement_id is not None and n_bins == w:  # its columns are the encoder's: the grid itself
            return self

        valid_cols = np.flatnonzero(self.column_valid)
        pos = _grid_positions(self.azimuth_deg[valid_cols], self.column_timestamp_ns[valid_cols], res)
        uniq_bins, first = np.unique(_grid_bins(pos, n_bins), return_index=True)
        source_col = valid_cols[first]  # first firing in each occupied bin (column order = firing order)
        collisions = int(valid_cols.size - uniq_bins.size)

        def gather(arr: np.ndarray | None, fill: Any = 0) -> np.ndarray | None:
            if arr is None:
                return None
            out = np.full(arr.shape[:-1] + (n_bins,), fill, dtype=arr.dtype)
            out[..., uniq_bins] = arr[..., source_col]
            return out

        azimuth = (np.arange(n_bins) + 0.5) * res
        azimuth[uniq_bins] = self.azimuth_deg[source_col]
        updates: dict[str, Any] = {name: gather(getattr(self, name)) for name in _PER_COLUMN + _PER_PIXEL}
        updates["column_valid"] = gather(self.column_valid, False)
        updates["azimuth_deg"] = azimuth
        # per-column arrays move with their columns; per-packet or per-frame ones (OSF, Ouster headers) stay
        updates["extra"] = {k: gather(v) if np.ndim(v) and np.shape(v)[-1] == w else v for k, v in self.extra.items()}
        counters = replace(self.counters, grid_collisions=self.counters.grid_collisions + collisions)
        return replace(self, counters=counters, **updates)

    def destaggered(self, image: np.ndarray) -> np.ndarray:
        """A staggered ``[..., H, W]`` image of this frame destaggered for display (Ouster);
        see :func:`destagger`. Returns the image unchanged for sensors without a stagger."""
        shift = self.sensor.pixel_shift_by_row
        return image if shift is None else destagger(image, np.asarray(shift))


POINT_FIELDS = (("range_mm", "<u4"), ("reflectivity", "u1"), ("row", "<u2"), ("column", "<u2"),
                ("return_slot", "u1"), ("timestamp_ns", "<i8"))
VENDOR_POINT_FIELDS = (("signal", "<u2"), ("near_ir", "<u2"))  # present when the frame carries them


def points_dtype(frame: Frame, xyz_dtype: "np.typing.DTypeLike" = np.float64) -> np.dtype:
    """The structured dtype of ``frame.points(xyz_dtype)``: x, y, z, :data:`POINT_FIELDS`, then the
    :data:`VENDOR_POINT_FIELDS` the frame carries (not None)."""
    if frame.shape[2] > np.iinfo(np.uint16).max + 1:
        raise UsageError(f"frame {frame.frame_id}: {frame.shape[2]} columns do not fit the points' uint16 column")
    xyz = np.dtype(xyz_dtype).newbyteorder("<")
    extra = [(name, typ) for name, typ in VENDOR_POINT_FIELDS if getattr(frame, name) is not None]
    return np.dtype([("x", xyz), ("y", xyz), ("z", xyz), *POINT_FIELDS, *extra])
