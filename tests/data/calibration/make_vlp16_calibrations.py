"""Writes vlp16_corrected.yaml (ROS driver) and vlp16_corrected.xml (VeloView) beside this script.

A per-unit-like VLP-16 calibration in which every correction is non-zero, so that a wrong sign
or a dropped term moves points by centimetres: elevations from the VLP-16 manual, vertical
offsets from the stock beam-origin lever arm (0.04191 m · tan(−ω)) plus a few millimetres,
azimuth offsets of up to ±1.5°, distance offsets of −45…+60 mm and horizontal offsets of
±25.9 mm. Two-point (dist_correction_x/y) and focal corrections stay 0: lidarpkt refuses the
first and reports raw intensities (the second only changes intensity).

    python tests/data/calibration/make_vlp16_calibrations.py
"""

from __future__ import annotations

from pathlib import Path

HERE = Path(__file__).resolve().parent
ELEVATION_DEG = [-15, 1, -13, 3, -11, 5, -9, 7, -7, 9, -5, 11, -3, 13, -1, 15]  # manual, laser id order


def corrections() -> list[dict[str, float]]:
    """Per laser id: rot_deg, vert_deg, dist_cm, vert_offset_cm, horiz_offset_cm (decimal, exact in text)."""
    import math

    rows = []
    for i, elev in enumerate(ELEVATION_DEG):
        rows.append({
            "rot_deg": round((-1.5 + 0.2 * i) if i % 2 else (1.5 - 0.13 * i), 4),
            "vert_deg": float(elev),
            "dist_cm": round(-4.5 + 0.7 * i if i != 6 else 2.0, 4),
            "vert_offset_cm": round(4.191 * math.tan(math.radians(-elev)) + 0.3 * ((i % 3) - 1) + 0.1, 4),
            "horiz_offset_cm": 2.59 if i % 2 == 0 else -2.59,
        })
    return rows


def write_yaml(path: Path) -> None:
    import math

    lines = ["distance_resolution: 0.002", "num_lasers: 16", "lasers:"]
    for i, c in enumerate(corrections()):
        lines.append(
            f"- {{laser_id: {i}, rot_correction: {math.radians(c['rot_deg'])!r}, "
            f"vert_correction: {math.radians(c['vert_deg'])!r}, dist_correction: {c['dist_cm'] / 100!r}, "
            f"dist_correction_x: 0.0, dist_correction_y: 0.0, focal_distance: 0.0, focal_slope: 0.0, "
            f"vert_offset_correction: {c['vert_offset_cm'] / 100!r}, "
            f"horiz_offset_correction: {c['horiz_offset_cm'] / 100!r}}}"
        )
    path.write_text("\n".join(lines) + "\n")


def write_xml(path: Path) -> None:
    items = []
    for i, c in enumerate(corrections()):
        items.append(
            f"\t\t<item>\n\t\t\t<px class_id_reference=\"9\" object_id=\"_{i + 1}\">\n"
            f"\t\t\t\t<id_>{i}</id_>\n"
            f"\t\t\t\t<rotCorrection_>{c['rot_deg']!r}</rotCorrection_>\n"
            f"\t\t\t\t<vertCorrection_>{c['vert_deg']!r}</vertCorrection_>\n"
            f"\t\t\t\t<distCorrection_>{c['dist_cm']!r}</distCorrection_>\n"
            "\t\t\t\t<distCorrectionX_>0</distCorrectionX_>\n\t\t\t\t<distCorrectionY_>0</distCorrectionY_>\n"
            f"\t\t\t\t<vertOffsetCorrection_>{c['vert_offset_cm']!r}</vertOffsetCorrection_>\n"
            f"\t\t\t\t<horizOffsetCorrection_>{c['horiz_offset_cm']!r}</horizOffsetCorrection_>\n"
            "\t\t\t\t<focalDistance_>0</focalDistance_>\n\t\t\t\t<focalSlope_>0</focalSlope_>\n"
            "\t\t\t</px>\n\t\t</item>\n"
        )
    path.write_text(
        '<?xml version="1.0" encoding="UTF-8" standalone="yes" ?>\n<!DOCTYPE boost_serialization>\n'
        '<boost_serialization signature="serialization::archive" version="4">\n'
        '<DB class_id="0" tracking_level="1" version="0" object_id="_0">\n\t<distLSB_>0.2</distLSB_>\n'
        f"\t<points_ class_id=\"7\" tracking_level=\"0\" version=\"0\">\n\t\t<count>16</count>\n"
        "\t\t<item_version>1</item_version>\n" + "".join(items) + "\t</points_>\n</DB>\n</boost_serialization>\n"
    )


if __name__ == "__main__":
    write_yaml(HERE / "vlp16_corrected.yaml")
    write_xml(HERE / "vlp16_corrected.xml")
