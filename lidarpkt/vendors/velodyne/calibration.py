"""VLP-16 calibration: the stock one built in, the ROS driver's YAML and VeloView's XML.

A calibration gives, for each laser id 0–15 (firing order), its elevation
(``vert_correction``), azimuth offset (``rot_correction``), and the small offsets of
the ROS driver model. :func:`load_calibration` detects the format from the content.

Stock calibration: the manual's elevations (−15, 1, −13, … 15°), no azimuth offsets, and
the vertical offsets velodyne_decoder 3.1.0 ships for the VLP-16
(``vert_offset = 0.04191 m · tan(−ω)``: the beams leave the sensor from a common point
41.91 mm in front of the rotation axis, so each beam's origin sits off the axis' z = 0
plane), so that stock XYZ agrees with velodyne_decoder's default.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from lidarpkt.errors import CalibrationError
from .models import VLP16, VelodyneModel



@dataclass(eq=False)
class VelodyneCalibration:
    """Per-laser corrections, indexed by laser id (firing order), in SI units.

    Attributes (one value per laser: 16 on a VLP-16; the corrections default to zeros):
        vert_correction_rad: ``float64[L]`` elevation ω of each laser.
        rot_correction_rad: ``float64[L]`` azimuth offset subtracted from the firing azimuth.
        vert_offset_m, horiz_offset_m: ``float64[L]`` beam origin offsets (ROS driver model).
        dist_correction_m: ``float64[L]`` added to every distance (ROS driver model).
        distance_resolution_m: metres per raw distance unit (0.002 for the VLP-16).
        source: where it came from (``"stock"`` or the file path).
    """

    vert_correction_rad: np.ndarray
    rot_correction_rad: np.ndarray | None = None
    vert_offset_m: np.ndarray | None = None
    horiz_offset_m: np.ndarray | None = None
    dist_correction_m: np.ndarray | None = None
    distance_resolution_m: float = VLP16.distance_resolution_m
    source: str = "stock"
    dist_correction_x_m: np.ndarray | None = None
    dist_correction_y_m: np.ndarray | None = None
    focal_distance_m: np.ndarray | None = None
    focal_slope: np.ndarray | None = None
    min_intensity: np.ndarray | None = None
    max_intensity: np.ndarray | None = None

    def __post_init__(self) -> None:
        lasers = int(np.size(self.vert_correction_rad))
        if self.max_intensity is None:
            self.max_intensity = np.full(lasers, 255.0)
        for name in ("vert_correction_rad", "rot_correction_rad", "vert_offset_m", "horiz_offset_m", "dist_correction_m",
                     "dist_correction_x_m", "dist_correction_y_m", "focal_distance_m", "focal_slope", "min_intensity",
                     "max_intensity"):
            value = getattr(self, name)
            arr = np.zeros(lasers) if value is None else np.asarray(value, dtype=np.float64)
            if arr.shape != (lasers,):
                raise CalibrationError(f"{self.source}: {name} must have {lasers} values (one per laser), got {arr.shape}")
            setattr(self, name, arr)

    @property
    def lasers(self) -> int:
        """Number of lasers described."""
        return int(self.vert_correction_rad.shape[0])

    @property
    def elevation_deg(self) -> np.ndarray:
        """``float64[16]`` elevation of each laser id, degrees."""
        return np.degrees(self.vert_correction_rad)

    @property
    def two_point(self) -> np.ndarray:
        """``bool[L]``: lasers with a two-point distance correction (dist_correction_x and _y both set; the
        HDL-64E manual's near-range interpolation)."""
        assert self.dist_correction_x_m is not None and self.dist_correction_y_m is not None  # __post_init__ fills them
        return (self.dist_correction_x_m != 0) & (self.dist_correction_y_m != 0)

    @property
    def rows_to_laser(self) -> np.ndarray:
        """Laser id of each frame row (row 0 = highest elevation)."""
        return np.argsort(-self.vert_correction_rad, kind="stable")


def stock_calibration(model: VelodyneModel = VLP16) -> VelodyneCalibration:
    """The built-in calibration of ``model`` (the VLP-16's: see the module docstring), from the model table."""
    if not model.default_calibration:
        raise CalibrationError(
            f"a {model.name} has no stock calibration: each unit's is its own (its data packets carry it in their "
            "status bytes, which the decoder reads); pass calibration= (--calibration) with the unit's ROS YAML or "
            "VeloView XML")
    # float32 angles as velodyne_decoder tabulates its stock ones (float(deg · π / 180))
    omega = np.radians(np.asarray(model.elevation_deg, dtype=np.float64))
    omega = omega.astype(np.float32).astype(np.float64) if model is not VLP16 else omega
    rot = np.radians(np.asarray(model.azimuth_offset_deg or (0.0,) * model.lasers, dtype=np.float64))
    rot = rot.astype(np.float32).astype(np.float64)
    voff = (np.asarray(model.vert_offset_m, np.float64) if model.vert_offset_m is not None
            else model.beam_origin_forward_m * np.tan(-omega))
    return VelodyneCalibration(
        vert_correction_rad=omega,
        rot_correction_rad=rot,
        vert_offset_m=voff,
        distance_resolution_m=model.distance_resolution_m,
        source="stock",
    )


def load_calibration(path: str | os.PathLike[str] | VelodyneCalibration | Sequence[str | os.PathLike[str] |
                                                                                  VelodyneCalibration] | None,
                     model: VelodyneModel = VLP16) -> VelodyneCalibration:
    """A calibration of ``model`` (the VLP-16) from a ROS driver YAML or a VeloView XML file (detected by content).

    ``None`` gives the model's stock calibration; a :class:`VelodyneCalibration` is returned as is; of
    several (a list or tuple: one per sensor of a capture), the first that is ``model``'s.

    Raises:
        CalibrationError: unreadable file, unknown format, or not the model's number of lasers (16); of
            several, the first one's error when none is the model's.
    """
    if path is None:
        return stock_calibration(model)
    if isinstance(path, (list, tuple)):
        errors: list[CalibrationError] = []
        for candidate in path:
            try:
                return load_calibration(candidate, model)
            except CalibrationError as exc:
                errors.append(exc)
        if not errors:
            return stock_calibration(model)
        raise errors[0]
    if isinstance(path, VelodyneCalibration):
        return path
    if not isinstance(path, (str, os.PathLike)):
        raise CalibrationError(f"calibration={path!r}: not a calibration file's path nor a loaded calibration")
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise CalibrationError(f"cannot read {model.name} calibration {p}: {exc.strerror}") from None
    head = text.lstrip()[:400]
    if head.startswith("<?xml") or "<boost_serialization" in head or head.startswith("<"):
        return _from_veloview_xml(text, str(p), model)
    return _from_ros_yaml(text, str(p), model)


def _refuse_two_point(x: np.ndarray, y: np.ndarray, source: str) -> None:
    """Two-point distance correction (dist_correction_x and _y both set on a laser, the HDL-64E
    manual's near-range interpolation) is not modelled: refuse it rather than decode it wrongly."""
    both = np.flatnonzero((x != 0) & (y != 0))
    if both.size:
        raise CalibrationError(
            f"{source}: lasers {both.tolist()} set dist_correction_x and dist_correction_y (two-point distance "
            "correction), which lidarpkt's VLP-16 geometry does not model; set them to 0 or use velodyne_decoder"
        )


def _from_ros_yaml(text: str, source: str, model: VelodyneModel) -> VelodyneCalibration:
    from ruamel.yaml import YAML, YAMLError

    try:
        doc = YAML(typ="safe", pure=True).load(text)
    except YAMLError as exc:
        raise CalibrationError(f"{source} is neither VeloView XML nor valid ROS calibration YAML: {exc}") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("lasers"), list):
        raise CalibrationError(f"{source}: no 'lasers' list: not a ROS velodyne calibration YAML")
    lasers = doc["lasers"]
    n = doc.get("num_lasers", len(lasers))
    count = model.lasers
    if n != count or len(lasers) != count:
        raise CalibrationError(f"{source} describes {len(lasers)} lasers (num_lasers {n}): a {model.name} has {count}")
    values = {k: np.zeros(count) for k in ("vert", "rot", "voff", "hoff", "dist", "dx", "dy", "fd", "fs", "imin")}
    values["imax"] = np.full(count, 255.0)
    seen = set()
    keys = {"vert": "vert_correction", "rot": "rot_correction", "voff": "vert_offset_correction",
            "hoff": "horiz_offset_correction", "dist": "dist_correction",
            "dx": "dist_correction_x", "dy": "dist_correction_y", "fd": "focal_distance", "fs": "focal_slope",
            "imin": "min_intensity", "imax": "max_intensity"}
    for entry in lasers:
        try:
            i = int(entry["laser_id"])
            if not 0 <= i < count or i in seen:
                raise ValueError(f"laser_id {i} out of range or repeated")
            seen.add(i)
            values["vert"][i] = float(entry["vert_correction"])
            for k in ("rot", "voff", "hoff", "dist", "dx", "dy", "fd", "fs", "imin", "imax"):
                values[k][i] = float(entry.get(keys[k], values[k][i]))
        except (KeyError, TypeError, ValueError) as exc:
            raise CalibrationError(f"{source}: bad laser entry {entry!r}: {exc}") from None
    if model.sequences_per_block == 2:
        _refuse_two_point(values["dx"], values["dy"], source)
    return _checked(VelodyneCalibration(
        vert_correction_rad=values["vert"], rot_correction_rad=values["rot"], vert_offset_m=values["voff"],
        horiz_offset_m=values["hoff"], dist_correction_m=values["dist"],
        distance_resolution_m=float(doc.get("distance_resolution", model.distance_resolution_m)), source=source,
        dist_correction_x_m=values["dx"], dist_correction_y_m=values["dy"], focal_distance_m=values["fd"],
        focal_slope=values["fs"], min_intensity=values["imin"], max_intensity=values["imax"],
    ), model)


def _from_veloview_xml(text: str, source: str, model: VelodyneModel) -> VelodyneCalibration:
    import xml.etree.ElementTree as ET  # here: only VeloView's files are XML, and every read imports this module

    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise CalibrationError(f"{source}: malformed VeloView XML: {exc}") from None
    px = root.findall(".//points_/item/px")
    count = model.lasers
    if len(px) < count:
        raise CalibrationError(f"{source}: VeloView XML with {len(px)} <px> laser entries; a {model.name} needs {count}")
    lsb = root.findtext(".//distLSB_")
    values = {k: np.zeros(count) for k in ("vert", "rot", "voff", "hoff", "dist", "dx", "dy", "fd", "fs", "imin")}
    values["imax"] = np.full(count, 255.0)
    # VeloView stores angles in degrees and lengths in centimetres
    tags = {"vert": "vertCorrection_", "rot": "rotCorrection_", "voff": "vertOffsetCorrection_",
            "hoff": "horizOffsetCorrection_", "dist": "distCorrection_",
            "dx": "distCorrectionX_", "dy": "distCorrectionY_", "fd": "focalDistance_", "fs": "focalSlope_"}
    try:
        for node in px:
            i = int(node.findtext("id_", default=""))  # a missing id is a ValueError, as a bad one
            if i >= count:
                continue  # the XML's table has at least 64 entries; only the model's first ids exist
            for k, tag in tags.items():
                values[k][i] = float(node.findtext(tag) or 0.0)
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"{source}: bad <px> entry: {exc}") from None
    if model.sequences_per_block == 2:
        _refuse_two_point(values["dx"], values["dy"], source)
    return _checked(VelodyneCalibration(
        vert_correction_rad=np.radians(values["vert"]), rot_correction_rad=np.radians(values["rot"]),
        vert_offset_m=values["voff"] / 100.0, horiz_offset_m=values["hoff"] / 100.0,
        dist_correction_m=values["dist"] / 100.0,
        distance_resolution_m=float(lsb) / 100.0 if lsb else model.distance_resolution_m, source=source,
        dist_correction_x_m=values["dx"] / 100.0, dist_correction_y_m=values["dy"] / 100.0,
        focal_distance_m=values["fd"] / 100.0, focal_slope=values["fs"],
    ), model)


def _checked(cal: VelodyneCalibration, model: VelodyneModel) -> VelodyneCalibration:
    """A calibration whose elevations are another model's (an HDL-32E's file for a VLP-32C: both have 32
    lasers) raises :class:`CalibrationError`: a unit's elevations stay within a degree or two of its model's.
    The 16-laser Pucks are left as the VLP-16 always was (any 16 elevations)."""
    if not model.default_calibration or model.sequences_per_block == 2:
        return cal
    stock = np.sort(np.asarray(model.elevation_deg))
    ours = np.sort(cal.elevation_deg)
    worst = float(np.max(np.abs(stock - ours)))
    if worst > 3.0:
        from .models import MODELS

        like = [m.name for m in MODELS if m.lasers == model.lasers and m.default_calibration and
                float(np.max(np.abs(np.sort(np.asarray(m.elevation_deg)) - ours))) <= 3.0]
        raise CalibrationError(
            f"{cal.source}: elevations {ours.min():.1f}°…{ours.max():.1f}° are not a {model.name}'s "
            f"({stock.min():.1f}°…{stock.max():.1f}°)" + (f"; it looks like a {like[0]} calibration" if like else "")
            + ": pass the sensor's own calibration")
    return cal
