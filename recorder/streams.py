"""What each received datagram is, and which ones are missing.

:func:`classify_size` names the stream of a payload from its size (and the Ouster
metadata when given). :class:`VelodyneLoss` and :class:`OusterLoss` count lost packets
from the packets themselves, one NumPy pass per batch:

* VLP-16: the device timestamp (µs past the hour) of consecutive data packets advances
  by exactly one packet period (1327.104 µs single return, 663.552 µs dual: manual,
  "Timing"); a gap of k periods means k − 1 packets lost. This holds whatever the
  rotation rate and whatever the replay speed, unlike host receive times. A rotation
  ends where the first block's azimuth wraps.
* Ouster: the (frame id, measurement id) of each packet's first column gives its place in
  the stream; a jump of k packets means k − 1 lost. A rotation ends where the frame id
  changes.

A step back (or a repeat) is counted as out of order, never as loss. A jump of more than a
second (forward or back) is an *interruption* (the sensor stopped, restarted, or the cable
was out): counted and reported on its own, not as packets lost.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidarpkt.ouster.profiles import IMU_PACKET_SIZE, LEGACY
from lidarpkt.velodyne import packet as vlp

VELODYNE_DATA = "velodyne_data"
VELODYNE_POSITION = "velodyne_position"
OUSTER_LIDAR = "ouster_lidar"
OUSTER_IMU = "ouster_imu"
OTHER = "other"

# LEGACY lidar packets of 16, 32, 64, 128 beams: recognisable without metadata
_LEGACY_SIZES = {LEGACY.packet_size(h) for h in (16, 32, 64, 128)}


def classify_size(size: int, ouster_metadata=None) -> str:
    """Stream kind of a ``size``-byte payload: one of the module constants.

    ``ouster_metadata`` (:class:`lidarpkt.ouster.metadata.OusterMetadata`) makes the
    non-legacy Ouster profiles recognisable; without it only LEGACY sizes are.
    """
    if size == vlp.DATA_PACKET_SIZE:
        return VELODYNE_DATA
    if size == vlp.POSITION_PACKET_SIZE:
        return VELODYNE_POSITION
    if ouster_metadata is not None and size == ouster_metadata.packet_size:
        return OUSTER_LIDAR
    if size == IMU_PACKET_SIZE:
        return OUSTER_IMU
    if ouster_metadata is None and size in _LEGACY_SIZES:
        return OUSTER_LIDAR
    return OTHER


@dataclass
class LossCount:
    """Counts of one stream: packets seen, lost (gaps), out of order, rotations completed."""

    packets: int = 0
    lost: int = 0
    out_of_order: int = 0
    frames: int = 0
    interruptions: int = 0  # jumps of more than INTERRUPTION_S in the stream's own counters


INTERRUPTION_S = 1.0


class VelodyneLoss:
    """Loss and rotation counting of one VLP-16 data stream (feed batches in arrival order).

    ``single_period_us`` is the packet period in single-return modes (half of it in dual
    mode): the VLP-16's by default, the HDL-32E's for that sensor; ``None`` for a model whose
    timing is not known here (then packets and rotations are counted, gaps are not).
    """

    HOUR_US = 3_600_000_000

    def __init__(self, single_period_us: float | None = vlp.SINGLE_PACKET_PERIOD_US) -> None:
        self.single_period_us = single_period_us
        self.count = LossCount()
        self._last_ts: int | None = None
        self._last_az: int | None = None

    def update(self, payload: np.ndarray) -> np.ndarray:
        """Count ``uint8[N, 1206]`` payloads; returns ``bool[N]``, True where a packet starts a new
        rotation (its first azimuth is below the previous packet's)."""
        p = vlp.as_data_packets(payload)
        n = len(p)
        self.count.packets += n
        if n == 0:
            return np.zeros(0, bool)
        ts = p["timestamp_us"].astype(np.int64)
        az = p["blocks"]["azimuth_cdeg"][:, 0].astype(np.int64)
        single = self.single_period_us or 1.0
        period = np.where(p["return_mode"] == vlp.RETURN_MODE_CODES["dual"], single / 2, single)
        prev_ts = np.concatenate([[ts[0] if self._last_ts is None else self._last_ts], ts[:-1]])
        prev_az = np.concatenate([[az[0] if self._last_az is None else self._last_az], az[:-1]])
        dt = (ts - prev_ts) % self.HOUR_US
        dt = np.where(dt > self.HOUR_US // 2, dt - self.HOUR_US, dt)  # a step back stays negative
        steps = np.rint(dt / period).astype(np.int64)
        if self._last_ts is None:
            steps[0] = 1
        jump = np.abs(dt) > INTERRUPTION_S * 1e6
        self.count.interruptions += int(np.count_nonzero(jump))
        steps[jump] = 1
        if self.single_period_us is not None:
            self.count.lost += int(np.clip(steps - 1, 0, None).sum())
            self.count.out_of_order += int(np.count_nonzero(steps <= 0))
        new_rotation = az < prev_az
        self.count.frames += int(np.count_nonzero(new_rotation))
        self._last_ts, self._last_az = int(ts[-1]), int(az[-1])
        return new_rotation


class OusterLoss:
    """Loss and frame counting of one Ouster lidar stream, from its metadata."""

    def __init__(self, metadata) -> None:
        from lidarpkt.ouster import profiles

        self.md = metadata
        self.count = LossCount()
        prof = metadata.profile
        self._dtype = prof.packet_dtype(metadata.pixels_per_column, metadata.columns_per_packet)
        self._frame_field = None if prof.legacy else next(f for f in prof.header_fields if f.name == "frame_id")
        self._read_bits = profiles.read_bits
        first, last = metadata.column_window
        w = metadata.columns_per_frame
        self._first = first
        self._per_frame = -(-(((last - first) % w) + 1) // metadata.columns_per_packet)
        self._frame_modulus = 1 << (16 if self._frame_field is None else self._frame_field.width)
        self._last: tuple[int, int] | None = None  # (unwrapped frame id, packet index in frame)

    def update(self, payload: np.ndarray) -> np.ndarray:
        """Count ``uint8[N, L]`` lidar payloads; returns ``bool[N]``, True where the frame id changes."""
        n = payload.shape[0]
        self.count.packets += n
        if n == 0:
            return np.zeros(0, bool)
        pk = np.ascontiguousarray(payload).view(self._dtype)[:, 0]
        first_col = pk["columns"][:, 0]
        mid = first_col["measurement_id"].astype(np.int64)
        if self._frame_field is None:
            fid = first_col["frame_id"].astype(np.int64)
        else:
            fid = self._read_bits(pk["header"], self._frame_field).astype(np.int64)
        idx = ((mid - self._first) % self.md.columns_per_frame) // self.md.columns_per_packet
        m = self._frame_modulus
        prev_fid = np.concatenate([[fid[0] if self._last is None else self._last[0] % m], fid[:-1]])
        dfid = (fid - prev_fid) % m
        dfid = np.where(dfid > m // 2, dfid - m, dfid)
        base = fid[0] if self._last is None else self._last[0]
        fid_unwrapped = base + np.cumsum(dfid)
        pos = fid_unwrapped * self._per_frame + idx
        prev_pos = np.concatenate([[pos[0] - 1 if self._last is None else
                                    self._last[0] * self._per_frame + self._last[1]], pos[:-1]])
        steps = pos - prev_pos
        # frames per second: 10 or 20 (lidar_mode); unknown → 10
        limit = INTERRUPTION_S * (self.md.frequency_hz or 10) * self._per_frame
        jump = np.abs(steps) > limit
        self.count.interruptions += int(np.count_nonzero(jump))
        steps[jump] = 1
        self.count.lost += int(np.clip(steps - 1, 0, None).sum())
        self.count.out_of_order += int(np.count_nonzero(steps <= 0))
        new_frame = dfid > 0
        self.count.frames += int(np.count_nonzero(new_frame))
        self._last = (int(fid_unwrapped[-1]), int(idx[-1]))
        return new_frame
