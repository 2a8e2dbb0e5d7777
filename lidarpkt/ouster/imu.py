"""Ouster LEGACY IMU packets (48 bytes): three timestamps, acceleration and angular velocity.

Layout (:data:`~lidarpkt.ouster.profiles.IMU_DTYPE`): system, accelerometer and gyroscope
timestamps (uint64, ns), linear acceleration x/y/z (float32, g), angular velocity x/y/z
(float32, deg/s), in the IMU frame (``imu_to_sensor_transform`` of the metadata).
"""

from __future__ import annotations

import numpy as np

from ..errors import PacketFormatError
from .profiles import IMU_DTYPE, IMU_PACKET_SIZE


def decode_imu(payload: np.ndarray) -> np.ndarray:
    """IMU packets ``uint8[N, 48]`` (or one ``uint8[48]`` / bytes) → structured ``IMU_DTYPE[N]`` (a copy).

    Raises :class:`PacketFormatError` when the packets are not 48 bytes.
    """
    if isinstance(payload, (bytes, bytearray, memoryview)):
        payload = np.frombuffer(payload, np.uint8)
    arr = np.asarray(payload)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.dtype != np.uint8 or arr.ndim != 2 or arr.shape[1] != IMU_PACKET_SIZE:
        raise PacketFormatError(
            f"Ouster IMU packets are {IMU_PACKET_SIZE} bytes; got an array {arr.dtype}{list(arr.shape)}"
        )
    return np.ascontiguousarray(arr).view(IMU_DTYPE)[:, 0].copy()


def encode_imu(samples: np.ndarray | dict) -> np.ndarray:
    """The inverse of :func:`decode_imu`: ``IMU_DTYPE[N]`` (or a dict of ``[N]`` arrays by field name) → ``uint8[N, 48]``.

    Raises :class:`PacketFormatError` on unknown or missing field names or mismatched lengths.
    """
    if isinstance(samples, dict):
        missing = set(IMU_DTYPE.names or ()) - set(samples)  # a structured dtype: names is set
        extra = set(samples) - set(IMU_DTYPE.names or ())
        if missing or extra:
            raise PacketFormatError(f"IMU fields: missing {sorted(missing)}, unknown {sorted(extra)}")
        lengths = {np.shape(v) for v in samples.values()}
        if len(lengths) != 1 or len(next(iter(lengths))) != 1:
            raise PacketFormatError(f"IMU fields must be 1-D arrays of one length, got shapes {sorted(lengths)}")
        rec = np.zeros(next(iter(lengths))[0], IMU_DTYPE)
        for k, v in samples.items():
            rec[k] = v
    else:
        rec = np.asarray(samples)
        if rec.dtype != IMU_DTYPE:
            raise PacketFormatError(f"IMU samples must have dtype IMU_DTYPE, got {rec.dtype}")
    return np.ascontiguousarray(rec).view(np.uint8).reshape(len(rec), IMU_PACKET_SIZE).copy()
