"""Velodyne VLP-16: packet layouts, batch decoding, frames, XYZ, calibration and the encoder.

Public names (others rely on them): :data:`DATA_PACKET_SIZE`, :data:`POSITION_PACKET_SIZE`,
:func:`classify`, :func:`describe_stream`, :class:`VelodyneDecoder`, :func:`decode_packets`,
:func:`decode_position_packets`, :func:`encode_data_packets`, :func:`encode_position_packets`,
:func:`encode_frames`, :func:`load_calibration`, :func:`frame_points`, :class:`VelodyneModel`,
:data:`VLP16`.

Modules: ``models`` (the model table: lasers, product ids, firing timing, per model), ``packet``
(the byte layouts, declared once as NumPy dtypes), ``decode`` (raw fields of a batch), ``encode``
(the inverse), ``timing`` (firing times, per-firing azimuth, rotation rate), ``clock`` (the hour of
a packet stamp, the day of an NMEA time), ``stream`` (size classifier; loss, rotation and
whole-rotation rules shared by the decoder and the recorder), ``frames`` (:class:`VelodyneDecoder`:
frames, absolute time, losses), ``detect`` (VLP-16 or not), ``calibration`` (stock, ROS YAML,
VeloView XML), ``geometry`` (XYZ), ``points`` (flat point lists in velodyne_decoder's layout),
``nmea`` ($GPRMC/$GPGGA).
"""

from __future__ import annotations

import importlib
from typing import Any

# public name -> its module; imported on first use, so that a verb imports only the modules it
# needs (``lidarpkt info`` reads ``detect`` and not the frame assembly, the encoder or XYZ)
_LAZY: dict[str, str] = {
    "VelodyneCalibration": "calibration",
    "load_calibration": "calibration",
    "stock_calibration": "calibration",
    "DataPackets": "decode",
    "PositionPackets": "decode",
    "decode_packets": "decode",
    "decode_position_packets": "decode",
    "classify": "detect",
    "describe_stream": "detect",
    "encode_data_packets": "encode",
    "encode_frames": "encode",
    "encode_position_packets": "encode",
    "DecoderStats": "frames",
    "VelodyneDecoder": "frames",
    "VelodyneGeometry": "geometry",
    "MODELS": "models",
    "VLP16": "models",
    "VelodyneModel": "models",
    "model_for_product": "models",
    "NMEAFix": "nmea",
    "parse_nmea": "nmea",
    "DATA_PACKET_SIZE": "packet",
    "POSITION_PACKET_SIZE": "packet",
    "POINT_DTYPE": "points",
    "frame_points": "points",
}

__all__ = [
    "DATA_PACKET_SIZE",
    "POSITION_PACKET_SIZE",
    "DataPackets",
    "PositionPackets",
    "decode_packets",
    "decode_position_packets",
    "encode_data_packets",
    "encode_position_packets",
    "encode_frames",
    "classify",
    "describe_stream",
    "VelodyneDecoder",
    "DecoderStats",
    "VelodyneGeometry",
    "VelodyneCalibration",
    "load_calibration",
    "stock_calibration",
    "NMEAFix",
    "parse_nmea",
    "frame_points",
    "POINT_DTYPE",
    "VelodyneModel",
    "VLP16",
    "MODELS",
    "model_for_product",
]


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:  # a submodule not imported yet (``lidarpkt.velodyne.frames``)
        try:
            return importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{name}":
                raise
            raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
