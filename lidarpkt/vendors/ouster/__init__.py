"""Ouster OS0/OS1/OS2 lidar packets: metadata, byte-exact decoding and encoding, frames, XYZ.

Supported lidar profiles: every one of the firmware manual: LEGACY (any channel count),
RNG19_RFL8_SIG16_NIR16(_DUAL), RNG15_RFL8_NIR8(_DUAL), the ZONE16 and RGB16 variants,
RNG15_RFL8_WIN8, FIVE_WORD_PIXEL, under a STANDARD or FUSA packet header (``header_type``; the
deprecated FUSA_RNG15_RFL8_NIR8_DUAL name too). IMU profiles LEGACY and ACCEL32_GYRO32_NMEA;
zone-monitoring packets.

Modules: :mod:`.bitfield` (bit-field tables, read and written in NumPy), :mod:`.profiles` (every lidar
packet layout, once), :mod:`.auxiliary` (the IMU and zone-monitoring layouts), :mod:`.metadata` (the
parsed metadata), :mod:`.metadata_json` (reading its JSON: both layouts, defaults), :mod:`.decode` / :mod:`.encode` (batch fields <-> packet bytes, exact inverse),
:mod:`.crc` (CRC-64/XZ over a batch), :mod:`.frames` (:class:`OusterDecoder`; :mod:`.fieldplan` where
a frame's fields come from, for its C and NumPy paths), :mod:`.geometry`
(ouster-sdk's XYZ lookup table), :mod:`.detect` (:func:`classify`, :func:`describe_stream`),
:mod:`.imu` (both IMU profiles, :func:`imu_samples` in SI units), :mod:`.zone` (zone-monitoring
packets), :mod:`.digest` (ouster-sdk style MD5 digests), :mod:`.stream` (the
packet/loss/frame counter the recorder runs live), :mod:`.osf` (ouster-sdk's OSF files of decoded
frames, read by ``lidarpkt.open``), :mod:`.ros` (its ROS messages), :mod:`.builder` (a frame being filled),
:mod:`.vendor` (its registry record, :data:`VENDOR`).

>>> md = load_metadata("sensor.json")                                   # doctest: +SKIP
>>> fields = decode_packets(batch.payload, md)      # raw fields, [N, 16, H] pixels   # doctest: +SKIP
>>> assert (encode_packets(fields, md) == batch.payload).all()          # doctest: +SKIP
>>> dec = OusterDecoder(md); frames = dec.push(batch) + dec.finish()    # doctest: +SKIP
"""

from __future__ import annotations

from lidarpkt.core.lazy import lazy_names

# public name -> its module, imported on first use (lidarpkt/core/lazy.py)
_LAZY: dict[str, str] = {
    "VENDOR": "vendor",
    "crc64_xz": "crc",
    "OusterPacketFields": "decode",
    "decode_packets": "decode",
    "classify": "detect",
    "describe_stream": "detect",
    "empty_fields": "encode",
    "encode_frame": "encode",
    "encode_packets": "encode",
    "frame_fields": "encode",
    "OusterDecoder": "frames",
    "OusterDecoderStats": "frames",
    "OusterGeometry": "geometry",
    "decode_imu": "imu",
    "decode_imu_nmea": "imu",
    "encode_imu": "imu",
    "imu_samples": "imu",
    "OusterZoneStates": "zone",
    "decode_zone_packets": "zone",
    "OusterMetadata": "metadata",
    "OsfFile": "osf",
    "OsfReader": "osf",
    "load_metadata": "metadata_json",
    "PROFILES": "profiles",
    "BitField": "bitfield",
    "Profile": "profiles",
    "get_profile": "profiles",
    "with_header": "profiles",
}

__all__ = [
    "VENDOR",
    "BitField",
    "OusterDecoder",
    "OusterDecoderStats",
    "OusterGeometry",
    "OusterMetadata",
    "OusterPacketFields",
    "OusterZoneStates",
    "OsfFile",
    "OsfReader",
    "PROFILES",
    "Profile",
    "classify",
    "crc64_xz",
    "describe_stream",
    "decode_imu",
    "decode_imu_nmea",
    "decode_packets",
    "decode_zone_packets",
    "empty_fields",
    "encode_frame",
    "encode_imu",
    "encode_packets",
    "frame_fields",
    "get_profile",
    "imu_samples",
    "load_metadata",
    "with_header",
]


__getattr__, __dir__ = lazy_names(__name__, _LAZY, __all__)
