"""Velodyne spinning lidars (VLP-16, Puck LITE and Hi-Res, HDL-32E, VLP-32A/B/C, VLS-128 / Alpha Prime,
HDL-64E S2/S3): packet layouts, batch decoding, frames, XYZ, calibration and the encoder.

Public names (others rely on them): :data:`DATA_PACKET_SIZE`, :data:`POSITION_PACKET_SIZE`,
:func:`classify`, :func:`describe_stream`, :class:`VelodyneDecoder`, :func:`decode_packets`,
:func:`decode_position_packets`, :func:`encode_data_packets`, :func:`encode_position_packets`,
:func:`encode_frames`, :func:`load_calibration`, :func:`frame_points`, :class:`VelodyneModel`,
:data:`VLP16`.

Modules: ``models`` (the model table: lasers, product ids, firing timing, per model), ``layout`` (each
model's per-block, per-channel tables in each return mode), ``hdl64e`` (the HDL-64E's status cycle
and the calibration it carries), ``packet``
(the byte layouts, declared once as NumPy dtypes), ``decode`` (raw fields of a batch), ``encode``
(the inverse), ``timing`` (firing times, per-firing azimuth, rotation rate), ``clock`` (the hour of
a packet stamp), ``stream`` (size classifier; loss, rotation and
whole-rotation rules shared by the decoder and the recorder), ``frames`` (:class:`VelodyneDecoder`:
frames, absolute time, losses; the dual-return mark is :mod:`lidarpkt.core.dual`), ``detect`` (which
model), ``calibration`` (stock, ROS YAML,
VeloView XML), ``geometry`` (XYZ), ``points`` (flat point lists in velodyne_decoder's layout),
``accounting`` (what the decoder counts), ``columns`` (the column runs of a frame), ``ros`` (its ROS messages),
``vendor`` (its registry record, :data:`VENDOR`). The NMEA sentences of its position packets are read by
:mod:`lidarpkt.core.nmea`.
"""

from __future__ import annotations

from lidarpkt.core.lazy import lazy_names

# public name -> its module, imported on first use (lidarpkt/core/lazy.py)
_LAZY: dict[str, str] = {
    "VENDOR": "vendor",
    "VelodyneCalibration": "calibration",
    "load_calibration": "calibration",
    "stock_calibration": "calibration",
    "DataPackets": "decode",
    "PositionPackets": "decode",
    "decode_packets": "decode",
    "decode_position_packets": "decode",
    "Hdl32eInertial": "decode",
    "hdl32e_inertial": "decode",
    "classify": "detect",
    "describe_stream": "detect",
    "encode_data_packets": "encode",
    "encode_frames": "encode",
    "encode_position_packets": "encode",
    "DecoderStats": "accounting",
    "VelodyneDecoder": "frames",
    "VelodyneGeometry": "geometry",
    "MODELS": "models",
    "VLP16": "models",
    "VelodyneModel": "models",
    "model_for_product": "models",
    "DATA_PACKET_SIZE": "packet",
    "POSITION_PACKET_SIZE": "packet",
    "POINT_DTYPE": "points",
    "frame_points": "points",
}

__all__ = [
    "VENDOR",
    "DATA_PACKET_SIZE",
    "POSITION_PACKET_SIZE",
    "DataPackets",
    "PositionPackets",
    "decode_packets",
    "decode_position_packets",
    "hdl32e_inertial",
    "Hdl32eInertial",
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
    "frame_points",
    "POINT_DTYPE",
    "VelodyneModel",
    "VLP16",
    "MODELS",
    "model_for_product",
]


__getattr__, __dir__ = lazy_names(__name__, _LAZY, __all__)
