"""Ouster IMU packets, both profiles of the metadata's ``udp_profile_imu``.

* LEGACY (48 bytes, :data:`~lidarpkt.vendors.ouster.auxiliary.IMU_DTYPE`): system, accelerometer and
  gyroscope timestamps (uint64, ns), linear acceleration x/y/z (float32, g), angular velocity
  x/y/z (float32, deg/s). :func:`decode_imu` / :func:`encode_imu`.
* ACCEL32_GYRO32_NMEA (firmware 3.x, :func:`~lidarpkt.vendors.ouster.auxiliary.imu_packet_dtype`): the
  lidar packet header, an NMEA block (timestamp and the last sentence received), then
  ``imu_measurements_per_packet`` measurements (timestamp, measurement id, status, acceleration
  in m/s², angular velocity in rad/s), the footer. :func:`decode_imu_nmea`.

:func:`imu_samples` gives either as :class:`lidarpkt.core.imu.ImuSamples` in SI units. Axes are those
of the IMU frame (``imu_to_sensor_transform`` of the metadata).
"""

from __future__ import annotations

import numpy as np

from lidarpkt.errors import PacketFormatError
from lidarpkt.core.imu import STANDARD_GRAVITY_MPS2, ImuSamples
from lidarpkt.core.packet import payload_rows
from .profiles import HEADER_TYPES
from .auxiliary import IMU_DTYPE, IMU_PACKET_SIZE, imu_packet_dtype
from .bitfield import read_bits


def decode_imu(payload: np.ndarray) -> np.ndarray:
    """IMU packets ``uint8[N, 48]`` (or one ``uint8[48]`` / bytes) → structured ``IMU_DTYPE[N]`` (a copy).

    Raises :class:`PacketFormatError` when the packets are not 48 bytes.
    """
    arr = payload_rows(payload, IMU_PACKET_SIZE, "Ouster IMU packets")
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


# --------------------------------------------------------------------------- both profiles, SI units


def decode_imu_nmea(payload: np.ndarray, measurements: int, header_type: str = "STANDARD") -> dict[str, np.ndarray]:
    """ACCEL32_GYRO32_NMEA packets ``uint8[N, L]`` → their fields (copies).

    Returns a dict: the packet-header fields by the manual's names (``packet_type``, ``frame_id``,
    ``init_id``, ``prod_sn``, ``alert_flags`` ..., each ``[N]``), ``nmea_timestamp_ns`` ``uint64[N]``,
    ``nmea_sentence`` ``S85[N]`` (NUL-padded ASCII), ``measurements`` ``IMU_MEASUREMENT_DTYPE[N, M]``
    (acceleration m/s², angular velocity rad/s) and ``footer`` ``uint8[N, 32]``.

    Raises:
        PacketFormatError: the packets are not the size ``measurements`` makes, or not a ``uint8[N, L]`` array.
    """
    dtype = imu_packet_dtype(measurements)
    arr = _rows(payload)
    if arr.shape[1] != dtype.itemsize:
        raise PacketFormatError(
            f"ACCEL32_GYRO32_NMEA packets of {measurements} measurements are {dtype.itemsize} bytes; got {arr.shape[1]}")
    pk = np.ascontiguousarray(arr).view(dtype)[:, 0]
    out: dict[str, np.ndarray] = {f.name: read_bits(pk["header"], f) for f in HEADER_TYPES[header_type] if not f.reserved}
    out["nmea_timestamp_ns"] = pk["nmea"]["nmea_timestamp_ns"].copy()
    out["nmea_sentence"] = pk["nmea"]["nmea_sentence"].copy()
    out["measurements"] = pk["measurements"].copy()
    out["footer"] = pk["footer"].copy()
    return out


def imu_samples(payload: np.ndarray, metadata, source: str | None = None) -> ImuSamples:
    """IMU packets of the sensor of ``metadata`` → :class:`~lidarpkt.core.imu.ImuSamples` (m/s², rad/s, ns).

    LEGACY: one sample per packet, at its gyroscope timestamp (ouster-sdk's ``ImuPacket.timestamp``);
    g × 9.80665 and deg/s × π/180; ``extra``: ``sys_timestamp_ns``, ``accel_timestamp_ns``,
    ``gyro_timestamp_ns``. ACCEL32_GYRO32_NMEA: the measurements whose status says valid (bit 0), at
    their own timestamps, in the units they travel in; ``extra``: ``measurement_id``, ``status``,
    ``frame_id`` and ``nmea_timestamp_ns`` / ``nmea_sentence`` of their packet. Both: ``packet_index``,
    the row of ``payload`` each sample came from.

    Raises:
        PacketFormatError: the packets are not the size of the metadata's IMU profile.
    """
    arr = _rows(payload)
    if metadata.imu_profile == "LEGACY":
        rec = decode_imu(arr)
        accel = np.stack([rec[k] for k in ("accel_x_g", "accel_y_g", "accel_z_g")], axis=-1).astype(np.float64)
        gyro = np.stack([rec[k] for k in ("gyro_x_deg_per_s", "gyro_y_deg_per_s", "gyro_z_deg_per_s")], axis=-1)
        extra = {k: rec[k].astype(np.int64) for k in ("sys_timestamp_ns", "accel_timestamp_ns", "gyro_timestamp_ns")}
        extra["packet_index"] = np.arange(len(rec), dtype=np.int64)
        return ImuSamples(rec["gyro_timestamp_ns"].astype(np.int64), accel * STANDARD_GRAVITY_MPS2,
                          np.deg2rad(gyro.astype(np.float64)), source, extra)
    f = decode_imu_nmea(arr, metadata.imu_measurements_per_packet, metadata.profile.header_type or "STANDARD")
    m = f["measurements"]
    valid = (m["status"] & 1).astype(bool)
    per_packet = np.broadcast_to(np.arange(len(m))[:, None], m.shape)[valid]
    m = m[valid]
    accel = np.stack([m[k] for k in ("accel_x_mps2", "accel_y_mps2", "accel_z_mps2")], axis=-1).astype(np.float64)
    gyro = np.stack([m[k] for k in ("gyro_x_radps", "gyro_y_radps", "gyro_z_radps")], axis=-1).astype(np.float64)
    extra = {"measurement_id": m["measurement_id"], "status": m["status"],
             "frame_id": f["frame_id"][per_packet], "nmea_timestamp_ns": f["nmea_timestamp_ns"][per_packet],
             "nmea_sentence": f["nmea_sentence"][per_packet], "packet_index": per_packet.astype(np.int64)}
    return ImuSamples(m["timestamp_ns"].astype(np.int64), accel, gyro, source, extra)


def _rows(payload) -> np.ndarray:
    return payload_rows(payload, None, "Ouster IMU packets")
