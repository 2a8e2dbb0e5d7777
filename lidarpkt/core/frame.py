"""Frames (one rotation as a range image), the sensor description they carry, and stacks of frames.

Shapes use R = return slots, H = rows (beams, row 0 = highest elevation), W = columns.
Every array with a trailing W axis is per column; ``[R, H, W]`` arrays are per pixel and slot.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import TYPE_CHECKING, Any, Iterable, Iterator, Protocol

import numpy as np

from lidarpkt.errors import AnalysisError, CalibrationError, UsageError

if TYPE_CHECKING:
    from typing_extensions import Self  # typing.Self is Python 3.11+


class Geometry(Protocol):
    """Turns a frame's ranges into points; each vendor module provides one."""

    def xyz(self, frame: "Frame", dtype: "np.typing.DTypeLike" = np.float64) -> np.ndarray:
        """Points of ``frame`` as ``[R, H, W, 3]`` metres of ``dtype`` (float64 or float32), zeros where
        there is no return."""
        ...


@dataclass(eq=False)
class SensorInfo:
    """What a sensor is and how to read its packets.

    Built from the packets themselves where they say enough (VLP-16 factory bytes,
    Ouster legacy packet size) and from the Ouster metadata JSON otherwise.

    Attributes:
        vendor: ``"velodyne"``, ``"ouster"`` or ``"hesai"``.
        model: e.g. ``"VLP-16"``, ``"OS-1-64"``.
        rows: H, beams per column.
        columns_per_frame: W of a full frame. Ouster: exact (512/1024/2048). VLP-16:
            firing sequences in one rotation at the nominal rate, a guide only (frames vary).
        return_mode: ``"strongest"``, ``"last"``, ``"dual"`` (VLP-16) or ``"single"``,
            ``"dual"``, ``"low_data_rate"`` (Ouster).
        return_labels: the label of each return slot, e.g. ``("last", "strongest")``.
        beam_altitude_deg: ``float64[H]`` elevation of each row, degrees, row order.
        beam_azimuth_deg: ``float64[H]`` azimuth offset of each row, degrees, row order.
        frequency_hz: rotation rate, 10 or 20 typically; ``None`` if unknown.
        grid_resolution_deg: the finest column grid of the sensor (VLP-16: 0.2°, its firing
            sequence at 10 Hz; Ouster: 360° / W). :func:`default_grid_deg` derives from it and the
            rotation rate the grid every part of lidarpkt uses by default.
        geometry: computes XYZ for frames of this sensor; ``None`` if no calibration.
        serial, firmware, profile, product_id, init_id: as the sensor reports them, ``None`` if unknown.
        return_order: Ouster ``return_order`` (``STRONGEST_TO_WEAKEST``, ``FARTHEST_TO_NEAREST``,
            ``NEAREST_TO_FARTHEST``): what orders the return slots; ``None`` otherwise.
        pixel_shift_by_row: ``int[H]`` Ouster stagger shifts (destaggering), ``None`` otherwise.
        source: where the packets came from (``"192.168.1.201:2368"``), for reports.
        metadata: the raw metadata document (Ouster JSON as a dict), empty if none.
    """

    vendor: str
    model: str
    rows: int
    columns_per_frame: int
    return_mode: str
    return_labels: tuple[str, ...]
    beam_altitude_deg: np.ndarray
    beam_azimuth_deg: np.ndarray
    frequency_hz: float | None = None
    grid_resolution_deg: float | None = None
    geometry: Geometry | None = None
    serial: str | None = None
    firmware: str | None = None
    profile: str | None = None
    product_id: int | None = None
    init_id: int | None = None
    pixel_shift_by_row: np.ndarray | None = None
    source: str | None = None
    metadata: dict[str, Any] = field(default_factory=dict)
    return_order: str | None = None

    def describe(self) -> dict[str, Any]:
        """A JSON-ready summary (for ``info`` and MCAP metadata records)."""
        out: dict[str, Any] = {}
        for f in fields(self):
            if f.name in ("geometry", "metadata"):
                continue
            value = getattr(self, f.name)
            if isinstance(value, np.ndarray):
                value = value.tolist()
            elif isinstance(value, tuple):
                value = list(value)
            out[f.name] = value
        return out


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
        frame whose columns already are that grid (Ouster) is returned unchanged.
        """
        res = resolution_deg if resolution_deg is not None else default_grid_deg(self.sensor)
        if res is None:
            return self
        n_bins = int(round(360.0 / res))
        if abs(n_bins * res - 360.0) > 1e-9:
            raise AnalysisError(f"grid resolution {res}° does not divide 360°")
        w = self.shape[2]
        if self.sensor.vendor == "ouster" and n_bins == w:
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


_SMOOTH_FIRINGS = 15  # firings averaged to tell the sensor's turn from its encoder's jitter


def _grid_positions(azimuth_deg: np.ndarray, timestamp_ns: np.ndarray, res: float) -> np.ndarray:
    """Position of each firing on a grid of ``res`` degrees (in bins), from its azimuths against time
    smoothed over a few firings rather than from each measured azimuth: the sensor turns steadily,
    but its encoder readings jitter (a VLP-16 at 19.98 Hz fires every 0.3996°, read as 0.39, 0.40 and
    0.41°), and on a grid as fine as the firings that jitter puts two firings in one bin beside an
    empty one, a column marked invalid though no packet was lost. A firing whose measured azimuth is
    more than half a bin from the line (the rate changed) keeps its measured azimuth."""
    measured = np.mod(azimuth_deg, 360.0)
    if measured.size < 8:
        return measured / res + 1e-9
    steps = measured / res
    if np.all(np.abs(steps - np.rint(steps)) < 1e-6):
        # a sensor that reports its firings on the grid itself (Hesai XT and QT: 0.18° and 0.4° steps): each
        # firing is its bin; a line fitted through their times (µs jitter) would only move some across an edge
        return np.rint(steps) + 1e-9
    turns = np.concatenate([[0], np.cumsum(np.diff(measured) < -180.0)])  # unwrap through 0°
    unwrapped = measured + 360.0 * turns
    t = (timestamp_ns - timestamp_ns[0]).astype(np.float64)
    if not np.all(np.diff(t) >= 0) or t[-1] <= 0:
        return measured / res + 1e-9
    # least-squares line azimuth = a + b·t, in closed form (np.polyfit costs ~0.2 ms a frame)
    t_mean, az_mean = t.mean(), unwrapped.mean()
    dt = t - t_mean
    slope = float(dt @ (unwrapped - az_mean)) / float(dt @ dt)
    line = az_mean + slope * dt
    # the slow wander of the rate about the line (up to ~0.06° a rotation) is kept, the jitter averaged out:
    # a running mean of the residual over _SMOOTH_FIRINGS firings (fewer at the ends)
    residual = unwrapped - line
    half = _SMOOTH_FIRINGS // 2
    csum = np.concatenate([[0.0], np.cumsum(residual)])
    idx = np.arange(residual.size)
    lo, hi = np.maximum(idx - half, 0), np.minimum(idx + half + 1, residual.size)
    fitted = line + (csum[hi] - csum[lo]) / (hi - lo)
    steady = np.abs(fitted - unwrapped) < 0.5 * res
    # the epsilon keeps an azimuth on a bin edge (187.6° / 0.4 = 468.99999...) in its bin
    return np.mod(np.where(steady, fitted, unwrapped), 360.0) / res + 1e-9


def _grid_bins(pos: np.ndarray, n_bins: int, tolerance: float = 0.1) -> np.ndarray:
    """Bins of firings at ``pos`` (in bins, firing order): floor, except that where two consecutive
    firings share a bin beside an empty one, the one within ``tolerance`` of the empty bin's edge
    moves into it (what smoothing leaves of the jitter). Vectorised: one pass each way."""
    bins = np.floor(pos).astype(np.int64) % n_bins
    frac = pos - np.floor(pos)
    for step in (1, -1):
        occupied = np.zeros(n_bins, bool)
        occupied[bins] = True
        pairs = np.flatnonzero(bins[1:] == bins[:-1])
        mover = pairs + 1 if step == 1 else pairs  # the later firing moves up, the earlier down
        near = frac[mover] > 1.0 - tolerance if step == 1 else frac[mover] < tolerance
        target = (bins[mover] + step) % n_bins
        ok = near & ~occupied[target]
        _, once = np.unique(target[ok], return_index=True)  # one firing per empty bin
        bins[mover[ok][once]] = target[ok][once]
    return bins


def default_grid_deg(sensor: SensorInfo) -> float | None:
    """The azimuth grid (degrees per column) frames of ``sensor`` are put on by default, from its firing rate.

    The sensor's ``grid_resolution_deg``, coarsened for a VLP-16 spinning faster than 10 Hz so that
    each column still holds a firing: at 20 Hz firing sequences are 0.4° apart, and a 0.2° grid
    would leave every other column empty (``column_valid`` False although no packet was lost).
    ``None`` when the sensor has no grid. One grid for :meth:`Frame.on_grid`,
    :meth:`FrameStack.from_frames`, ``lidarpkt decode -o x.npz`` and the analysis verbs.
    """
    res = sensor.grid_resolution_deg
    if res is None or sensor.vendor != "velodyne" or not sensor.frequency_hz:
        return res
    factor = max(1, int(round(float(sensor.frequency_hz) / 10.0)))
    while factor > 1 and abs(round(360.0 / (res * factor)) * res * factor - 360.0) > 1e-9:
        factor -= 1  # keep a grid that divides 360°
    return res * factor


def destagger(image: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """``[..., H, W]`` staggered (Ouster: columns = measurement ids) → destaggered, where adjacent
    columns are adjacent azimuths: ``destaggered[u, (c + shift[u]) % W] = staggered[u, c]``, as
    ouster-sdk does it. ``shift``: ``int[H]`` (``SensorInfo.pixel_shift_by_row``)."""
    return _roll_rows(image, np.asarray(shift))


def restagger(image: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """Inverse of :func:`destagger`."""
    return _roll_rows(image, -np.asarray(shift))


def _roll_rows(image: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """``out[..., u, (c + shift[u]) % W] = image[..., u, c]``: one roll per distinct shift (a sensor has a few), not
    a gather of every pixel (4x slower on an OS-128 image)."""
    if not np.any(shift):
        return image
    out = np.empty_like(image)
    for s in np.unique(shift).tolist():
        rows = np.flatnonzero(shift == s)
        out[..., rows, :] = np.roll(image[..., rows, :], s, axis=-1)
    return out


class FrameIterator:
    """What every frame reader of :func:`lidarpkt.open` shares: iterate it for :class:`Frame` objects;
    ``close()`` it (or use ``with``) to stop early. A subclass sets ``_iter``, its frames, and ``close()``."""

    _iter: Iterator[Frame]

    def __iter__(self) -> Self:
        return self

    def __next__(self) -> Frame:
        return next(self._iter)

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass(eq=False)
class FrameStack:
    """K frames of one sensor on one column grid, stacked along a first axis: the input of
    the temporal analysis. Pixel (i, j) is the same raypath in every frame.

    Attributes:
        sensor, return_labels: as in :class:`Frame`.
        frame_id: ``int64[K]``.
        range_mm: ``uint32[K, R, H, W]``; reflectivity: ``uint8[K, R, H, W]``.
        column_valid: ``bool[K, W]``; column_timestamp_ns: ``int64[K, W]``;
        azimuth_deg: ``float64[K, W]``.
    """

    sensor: SensorInfo
    return_labels: tuple[str, ...]
    frame_id: np.ndarray
    range_mm: np.ndarray
    reflectivity: np.ndarray
    column_valid: np.ndarray
    column_timestamp_ns: np.ndarray
    azimuth_deg: np.ndarray

    def __len__(self) -> int:
        return int(self.range_mm.shape[0])

    @classmethod
    def from_frames(
        cls, frames: Iterable[Frame], *, resolution_deg: float | None = None, include_partial: bool = False
    ) -> "FrameStack":
        """Stack frames after putting each on the grid (see :meth:`Frame.on_grid`; by default
        :func:`default_grid_deg`, the grid of ``lidarpkt decode -o x.npz`` and ``lidarpkt analyze``).

        Partial frames are left out unless ``include_partial``. Raises
        :class:`~lidarpkt.errors.AnalysisError` if no frame is left or the frames differ in
        shape or return labels.
        """
        gridded = [f.on_grid(resolution_deg) for f in frames if include_partial or not f.partial]
        if not gridded:
            raise AnalysisError("no complete frames to stack (pass include_partial=True to use partial ones)")
        first = gridded[0]
        for f in gridded[1:]:
            if f.shape != first.shape or f.return_labels != first.return_labels:
                raise AnalysisError(
                    f"frame {f.frame_id} has shape {f.shape} and returns {f.return_labels}, "
                    f"unlike frame {first.frame_id} ({first.shape}, {first.return_labels}): "
                    "stack frames of one sensor and mode only"
                )
        return cls(
            sensor=first.sensor,
            return_labels=first.return_labels,
            frame_id=np.array([f.frame_id for f in gridded], dtype=np.int64),
            range_mm=np.stack([f.range_mm for f in gridded]),
            reflectivity=np.stack([f.reflectivity for f in gridded]),
            column_valid=np.stack([f.column_valid for f in gridded]),
            column_timestamp_ns=np.stack([f.column_timestamp_ns for f in gridded]),
            azimuth_deg=np.stack([f.azimuth_deg for f in gridded]),
        )
