"""Ouster OS0/OS1/OS2 lidar packets: metadata, byte-exact decoding and encoding, frames, XYZ.

Supported lidar profiles: LEGACY (any channel count), RNG19_RFL8_SIG16_NIR16,
RNG19_RFL8_SIG16_NIR16_DUAL, RNG15_RFL8_NIR8 and FUSA_RNG15_RFL8_NIR8_DUAL; LEGACY IMU packets.

Modules: :mod:`.profiles` (every layout as bit-field tables, once), :mod:`.metadata` (JSON, both
layouts, defaults), :mod:`.decode` / :mod:`.encode` (batch fields <-> packet bytes, exact inverse),
:mod:`.crc` (CRC-64/XZ over a batch), :mod:`.frames` (:class:`OusterDecoder`), :mod:`.geometry`
(ouster-sdk's XYZ lookup table), :mod:`.detect` (:func:`classify`, :func:`describe_stream`),
:mod:`.imu`, :mod:`.digest` (ouster-sdk style MD5 digests), :mod:`.stream` (size classifier and the
packet/loss/frame counter the recorder runs live).

>>> md = load_metadata("sensor.json")                                   # doctest: +SKIP
>>> fields = decode_packets(batch.payload, md)      # raw fields, [N, 16, H] pixels   # doctest: +SKIP
>>> assert (encode_packets(fields, md) == batch.payload).all()          # doctest: +SKIP
>>> dec = OusterDecoder(md); frames = dec.push(batch) + dec.finish()    # doctest: +SKIP
"""

from __future__ import annotations

from .crc import crc64_xz
from .decode import OusterPacketFields, decode_packets
from .detect import classify, describe_stream
from .encode import empty_fields, encode_frame, encode_packets, frame_fields
from .frames import OusterDecoder, OusterDecoderStats
from .geometry import OusterGeometry
from .imu import decode_imu, encode_imu
from .metadata import OusterMetadata, load_metadata
from .profiles import PROFILES, BitField, Profile, get_profile

__all__ = [
    "BitField",
    "OusterDecoder",
    "OusterDecoderStats",
    "OusterGeometry",
    "OusterMetadata",
    "OusterPacketFields",
    "PROFILES",
    "Profile",
    "classify",
    "crc64_xz",
    "describe_stream",
    "decode_imu",
    "decode_packets",
    "empty_fields",
    "encode_frame",
    "encode_imu",
    "encode_packets",
    "frame_fields",
    "get_profile",
    "load_metadata",
]
