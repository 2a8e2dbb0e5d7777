"""RoboSense calibrations: the elevation and azimuth offset of each laser, from a DIFOP or an angle CSV.

A sensor sends its own calibration in every DIFOP (:mod:`lidarpkt.vendors.robosense.difop`); the
decoder takes it from there when the capture holds one, and from the angle CSV RoboSense ships
(rs_driver's ``angle.csv``, nebula's ``RobosenseHelios16P.csv``) otherwise. That CSV has no header:
one line per laser in channel order, ``elevation,azimuth_offset`` in degrees (the azimuth offset may
be missing: 0). It is told apart from other vendors' CSVs by content (:func:`is_robosense_csv`, which the
vendor registry asks of a ``metadata=`` file):
Hesai's angle-correction CSV starts with a header line and has three columns.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lidarpkt.errors import CalibrationError

LASER_COUNTS = (16, 32, 128)  # the models' lasers: a CSV of another length is no RoboSense one


@dataclass(frozen=True, eq=False)
class RobosenseCalibration:
    """Angles of each laser (index = laser, 0-based), degrees.

    Attributes:
        elevation_deg: ``float64[L]``.
        azimuth_offset_deg: ``float64[L]``, added to the firing's azimuth (positive clockwise, as the azimuth).
        source: ``"DIFOP"`` or the file it came from, for messages and ``info``.
    """

    elevation_deg: np.ndarray
    azimuth_offset_deg: np.ndarray
    source: str = "calibration"

    @property
    def lasers(self) -> int:
        return int(self.elevation_deg.shape[0])

    def rows(self) -> np.ndarray:
        """``int[L]`` laser of each frame row: highest elevation first (ties in laser order)."""
        return np.argsort(-self.elevation_deg, kind="stable")

    def first(self, lasers: int) -> RobosenseCalibration:
        """The angles of the first ``lasers`` lasers.

        Raises :class:`~lidarpkt.errors.CalibrationError` if it has fewer."""
        if self.lasers < lasers:
            raise CalibrationError(f"{self.source}: a calibration of {self.lasers} lasers for a sensor of {lasers}; "
                                   "pass the sensor's own angle CSV")
        if self.lasers == lasers:
            return self
        return RobosenseCalibration(self.elevation_deg[:lasers], self.azimuth_offset_deg[:lasers], self.source)


@dataclass(frozen=True, eq=False)
class DifopPacket:
    """A sensor's DIFOP packet given as its sensor file (the one of a capture's first packets, for the reader of
    a later segment): the decoder takes it as if it came first.

    Attributes:
        payload: the packet (1248 bytes).
        address: the sensor's IP address (``None`` in a capture that keeps no addresses).
    """

    payload: bytes
    address: str | None = None
    source: str = "DIFOP"


def _rows(text: str) -> list[tuple[float, float]] | None:
    rows = []
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().lstrip("\ufeff").split(",")]
        if cells == [""]:
            continue
        if len(cells) > 2:
            return None
        try:
            values = [float(c) for c in cells]
        except ValueError:
            return None
        rows.append((values[0], values[1] if len(values) == 2 else 0.0))
    return rows


def is_robosense_csv(text: str) -> bool:
    """Whether ``text`` is a RoboSense angle CSV: 16, 32 or 128 lines of one or two numbers, no header."""
    rows = _rows(text)
    return rows is not None and len(rows) in LASER_COUNTS


def parse_calibration(text: str, source: str = "calibration") -> RobosenseCalibration:
    """A :class:`RobosenseCalibration` from the text of an angle CSV.

    Raises :class:`~lidarpkt.errors.CalibrationError` naming ``source`` when it is not one.
    """
    rows = _rows(text)
    if rows is None or len(rows) not in LASER_COUNTS:
        found = "lines that are not 'elevation,azimuth'" if rows is None else f"{len(rows)} lines"
        raise CalibrationError(f"{source}: not a RoboSense angle CSV ({found}); it has one 'elevation,azimuth' line "
                               f"(degrees) per laser, {', '.join(map(str, LASER_COUNTS))} lines")
    arr = np.array(rows, np.float64)
    if not (np.all(np.isfinite(arr)) and np.all(np.abs(arr[:, 0]) <= 90) and np.all(np.abs(arr[:, 1]) < 180)):
        raise CalibrationError(f"{source}: angles out of range (elevation within ±90°, azimuth offset within ±180°)")
    return RobosenseCalibration(arr[:, 0].copy(), arr[:, 1].copy(), source)


def load_calibration(calibration: RobosenseCalibration | str | os.PathLike[str]) -> RobosenseCalibration:
    """A loaded calibration passes through; a path is read as an angle CSV.

    Raises :class:`~lidarpkt.errors.CalibrationError` for a file that cannot be read or parsed.
    """
    if isinstance(calibration, RobosenseCalibration):
        return calibration
    path = Path(calibration)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise CalibrationError(f"{path}: cannot read the RoboSense angle CSV: {exc}") from exc
    return parse_calibration(text, str(path))


def from_device(elevation_deg: np.ndarray, azimuth_offset_deg: np.ndarray) -> RobosenseCalibration:
    """The calibration a DIFOP carries."""
    return RobosenseCalibration(np.asarray(elevation_deg, np.float64), np.asarray(azimuth_offset_deg, np.float64),
                                "DIFOP")
