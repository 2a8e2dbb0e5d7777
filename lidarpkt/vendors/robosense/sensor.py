"""The :class:`~lidarpkt.core.frame.SensorInfo` of a RoboSense sensor in one return mode: model, rows,
return slots and their labels, calibration and its source, rotation rate, the DIFOP's serial number
and firmware."""

from __future__ import annotations

import numpy as np

from lidarpkt.core.sensor import SensorInfo
from .calibration import RobosenseCalibration
from .difop import DeviceInfo
from .geometry import RobosenseGeometry
from .models import RobosenseModel


def return_mode_name(labels: tuple[str, ...]) -> str:
    """``"strongest"`` for one return, ``"dual"`` for two."""
    return labels[0] if len(labels) == 1 else "dual"


def describe_sensor(model: RobosenseModel, n_returns: int, mode_byte: int | None,
                    calibration: RobosenseCalibration | None, unit_um: int, rotation_hz: int | None,
                    device: DeviceInfo | None, source: str | None) -> SensorInfo:
    """The :class:`SensorInfo` of a RoboSense sensor in one mode (see :class:`RobosenseDecoder`)."""
    labels = model.labels(mode_byte, n_returns)
    hz = rotation_hz or 10
    grid = model.grid_resolution_deg(hz)
    if n_returns == 2:
        grid = round(360.0 * hz * model.column_period_ns(2) * 1e-9, 3)
    rows = calibration.rows() if calibration is not None else np.arange(model.lasers)
    nan = np.full(model.lasers, np.nan)
    geometry = None
    if calibration is not None:
        geometry = RobosenseGeometry(calibration, rows, unit_um, model.lens_rx_m, model.lens_rz_m)
    metadata = {"calibration_source": calibration.source if calibration is not None else None,
                "distance_unit_mm": unit_um / 1000.0, "return_mode_byte": mode_byte,
                "row_laser": rows.tolist()}
    if device is not None:
        metadata["difop"] = device.describe()
    return SensorInfo(
        vendor="robosense", model=model.name, rows=model.lasers, columns_per_frame=int(round(360.0 / grid)),
        return_mode=return_mode_name(labels), return_labels=labels,
        beam_altitude_deg=calibration.elevation_deg[rows] if calibration is not None else nan,
        beam_azimuth_deg=calibration.azimuth_offset_deg[rows] if calibration is not None else nan,
        frequency_hz=float(rotation_hz) if rotation_hz else None, grid_resolution_deg=grid, geometry=geometry,
        serial=device.serial_number if device is not None else None,
        firmware=device.firmware.get("top_firmware_version") if device is not None else None,
        profile=return_mode_name(labels), source=source, metadata=metadata,
    )
