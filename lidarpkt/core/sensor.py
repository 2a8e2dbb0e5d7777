"""What a sensor is: :class:`SensorInfo` (the description every frame carries) and the
:class:`Geometry` protocol its vendor's XYZ implements."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any, Protocol

import numpy as np


class Geometry(Protocol):
    """Turns a frame's ranges into points; each vendor module provides one."""

    def xyz(self, frame: Any, dtype: "np.typing.DTypeLike" = np.float64) -> np.ndarray:
        """Points of ``frame`` (a :class:`~lidarpkt.core.frame.Frame` of this sensor) as ``[R, H, W, 3]``
        metres of ``dtype`` (float64 or float32), zeros where there is no return."""
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
