"""Hesai Pandar (40P, 64, QT64, QT128, XT16, XT32, XT32M): packet layouts, detection, frames, XYZ,
calibration and the encoder.

Public names: :class:`HesaiDecoder`, :func:`decode_packets`, :func:`detect_model`, :func:`classify`,
:func:`describe_stream`, :func:`encode_packets`, :func:`load_calibration`, :class:`HesaiCalibration`,
:class:`HesaiModel`, :data:`MODELS`, :func:`model_named`, :data:`RETURN_MODES`.

Modules: ``packet`` (the byte layouts, declared once as NumPy dtypes), ``models`` (the model table:
a model is a row; return modes and the dual mark rule), ``decode`` (raw fields of a batch),
``detect`` (which model sent a stream), ``timing`` (firing time of each laser), ``frames``
(:class:`HesaiDecoder`), ``calibration`` (angle-correction CSV), ``geometry`` (XYZ in nebula's
frame: x = r·cos(el)·sin(az), y = r·cos(el)·cos(az), z = r·sin(el)), ``encode`` (the inverse), ``stream`` (the recorder's packet counter), ``ros`` (its ROS messages),
``vendor`` (its registry record, :data:`VENDOR`).
"""

from __future__ import annotations

from lidarpkt.core.lazy import lazy_names

_LAZY: dict[str, str] = {
    "VENDOR": "vendor",
    "HesaiCalibration": "calibration",
    "load_calibration": "calibration",
    "parse_calibration": "calibration",
    "HesaiPackets": "decode",
    "decode_packets": "decode",
    "classify": "detect",
    "describe_stream": "detect",
    "detect_model": "detect",
    "encode_packets": "encode",
    "DecoderStats": "frames",
    "HesaiDecoder": "frames",
    "HesaiGeometry": "geometry",
    "MODELS": "models",
    "HesaiModel": "models",
    "RETURN_MODES": "models",
    "model_named": "models",
}

__all__ = [
    "VENDOR",
    "MODELS",
    "RETURN_MODES",
    "DecoderStats",
    "HesaiCalibration",
    "HesaiDecoder",
    "HesaiGeometry",
    "HesaiModel",
    "HesaiPackets",
    "classify",
    "decode_packets",
    "describe_stream",
    "detect_model",
    "encode_packets",
    "load_calibration",
    "model_named",
    "parse_calibration",
]

__getattr__, __dir__ = lazy_names(__name__, _LAZY, __all__)
