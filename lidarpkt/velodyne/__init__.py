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
frames, absolute time, losses), ``dual`` (which dual-return firings hold the second strongest), ``detect`` (VLP-16 or not), ``calibration`` (stock, ROS YAML,
VeloView XML), ``geometry`` (XYZ), ``points`` (flat point lists in velodyne_decoder's layout),
``nmea`` ($GPRMC/$GPGGA).
"""

from __future__ import annotations

from .calibration import VelodyneCalibration, load_calibration, stock_calibration
from .decode import DataPackets, PositionPackets, decode_packets, decode_position_packets
from .detect import classify, describe_stream
from .encode import encode_data_packets, encode_frames, encode_position_packets
from .frames import DecoderStats, VelodyneDecoder
from .geometry import VelodyneGeometry
from .models import MODELS, VLP16, VelodyneModel, model_for_product
from .nmea import NMEAFix, parse_nmea
from .packet import DATA_PACKET_SIZE, POSITION_PACKET_SIZE
from .points import POINT_DTYPE, frame_points

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
