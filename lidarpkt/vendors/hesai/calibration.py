"""Hesai angle-correction files: the per-channel elevation and azimuth offset of a Pandar.

The CSV Hesai ships with each sensor (and serves over its PTC port) has a header line
(``Laser id,Elevation,Azimuth`` or ``Channel,Elevation,Azimuth``) and one line per channel,
1-based, in degrees: the channel's elevation, and the azimuth offset added to its block's azimuth.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lidarpkt.errors import CalibrationError


@dataclass(frozen=True, eq=False)
class HesaiCalibration:
    """Angles of each channel (index = channel − 1), degrees.

    Attributes:
        elevation_deg: ``float64[C]``.
        azimuth_offset_deg: ``float64[C]``.
        source: the file it came from, for messages.
    """

    elevation_deg: np.ndarray
    azimuth_offset_deg: np.ndarray
    source: str = "calibration"

    @property
    def channels(self) -> int:
        return int(self.elevation_deg.shape[0])


def parse_calibration(text: str, source: str = "calibration") -> HesaiCalibration:
    """A :class:`HesaiCalibration` from the text of an angle-correction CSV.

    Raises :class:`~lidarpkt.errors.CalibrationError` naming ``source`` and the line that is wrong.
    """
    rows: list[tuple[int, float, float]] = []
    lines: list[tuple[int, str]] = []  # (line number, text) of each row, for the errors
    for number, line in enumerate(text.splitlines(), 1):
        line = line.strip().lstrip("\ufeff")
        if not line or (number == 1 and not line[0].isdigit()):
            continue  # the header line, blank lines
        cells = [c.strip() for c in line.split(",")]
        try:
            channel, elevation, azimuth = int(cells[0]), float(cells[1]), float(cells[2])
        except (IndexError, ValueError):
            raise CalibrationError(f"{source}: line {number} is not 'channel,elevation,azimuth': {line[:60]!r}") from None
        if not (np.isfinite(elevation) and np.isfinite(azimuth) and -90 <= elevation <= 90 and -360 < azimuth < 360):
            raise CalibrationError(f"{source}: line {number}: angles out of range ({elevation}, {azimuth})")
        rows.append((channel, elevation, azimuth))
        lines.append((number, line))
    if not rows:
        raise CalibrationError(f"{source}: no channel lines; a Hesai angle-correction CSV has 'channel,elevation,azimuth'")
    channels = [r[0] for r in rows]
    if channels != list(range(1, len(rows) + 1)):
        i = next(i for i, c in enumerate(channels) if c != i + 1)
        number, line = lines[i]
        raise CalibrationError(f"{source}: line {number} {line[:60]!r} is channel {channels[i]} where channel {i + 1} "
                               f"should be; the channels are numbered 1..{len(rows)} in order, one line each")
    arr = np.array([(r[1], r[2]) for r in rows], np.float64)
    return HesaiCalibration(arr[:, 0].copy(), arr[:, 1].copy(), source)


def load_calibration(calibration: HesaiCalibration | str | os.PathLike[str]) -> HesaiCalibration:
    """A loaded calibration passes through; a path is read as an angle-correction CSV.

    Raises :class:`~lidarpkt.errors.CalibrationError` for a file that cannot be read or parsed.
    """
    if isinstance(calibration, HesaiCalibration):
        return calibration
    path = Path(calibration)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise CalibrationError(f"{path}: cannot read the Hesai calibration: {exc}") from exc
    return parse_calibration(text, str(path))
