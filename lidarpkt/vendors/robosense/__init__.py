"""RoboSense (RS-LiDAR-16, RS-LiDAR-32, RS-Bpearl, RS-Helios, RS-Helios-16P, RS-Ruby, RS-Ruby Plus):
MSOP and DIFOP layouts, detection, frames, XYZ, calibration from the DIFOP or an angle CSV, stream
counting, ROS messages and the encoder.

Public names: :class:`RobosenseDecoder`, :func:`decode_packets`, :func:`detect_model`, :func:`classify`,
:func:`describe_stream`, :func:`decode_difop`, :func:`encode_packets`, :func:`encode_difop`,
:func:`load_calibration`, :func:`is_robosense_csv`, :class:`RobosenseCalibration`,
:class:`RobosenseModel`, :data:`MODELS`, :func:`model_named`, :class:`PacketCounter`,
:data:`MESSAGE_DEFINITIONS`, :data:`VENDOR` (its registry record).

Modules: ``packet`` (the byte layouts, declared once as NumPy dtypes), ``models`` (the model table: a
model is a row), ``timing`` (firing times), ``decode`` (raw MSOP fields of a batch), ``difop`` (device
information), ``detect`` (MSOP or DIFOP, family, model), ``columns`` (packets to range-image
columns), ``frames`` (:class:`RobosenseDecoder`), ``sensor`` (its ``SensorInfo``), ``calibration``
(the DIFOP's angles or the angle CSV), ``geometry`` (XYZ in rs_driver's and nebula's frame),
``stream`` (losses and rotations), ``describe`` (``info``), ``ros`` (``robosense_msgs``), ``encode``
(the inverse), ``vendor`` (the registry record).
"""

from __future__ import annotations

from lidarpkt.core.lazy import lazy_names

_LAZY: dict[str, str] = {
    "RobosenseCalibration": "calibration",
    "is_robosense_csv": "calibration",
    "load_calibration": "calibration",
    "parse_calibration": "calibration",
    "RobosensePackets": "decode",
    "decode_packets": "decode",
    "describe_stream": "describe",
    "classify": "detect",
    "detect_model": "detect",
    "DeviceInfo": "difop",
    "decode_difop": "difop",
    "encode_difop": "encode",
    "encode_packets": "encode",
    "DecoderStats": "stream",
    "RobosenseDecoder": "frames",
    "RobosenseGeometry": "geometry",
    "MODELS": "models",
    "RobosenseModel": "models",
    "model_named": "models",
    "MESSAGE_DEFINITIONS": "ros",
    "PacketCounter": "stream",
    "VENDOR": "vendor",
}

__all__ = [
    "MESSAGE_DEFINITIONS",
    "MODELS",
    "DecoderStats",
    "DeviceInfo",
    "PacketCounter",
    "RobosenseCalibration",
    "RobosenseDecoder",
    "RobosenseGeometry",
    "RobosenseModel",
    "RobosensePackets",
    "VENDOR",
    "classify",
    "decode_difop",
    "decode_packets",
    "describe_stream",
    "detect_model",
    "encode_difop",
    "encode_packets",
    "is_robosense_csv",
    "load_calibration",
    "model_named",
    "parse_calibration",
]

__getattr__, __dir__ = lazy_names(__name__, _LAZY, __all__)
