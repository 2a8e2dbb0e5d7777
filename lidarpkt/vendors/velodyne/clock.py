"""VLP-16 time resolution, defined once: µs past the hour → ns since the epoch.

A VLP-16 stamps each packet with the µs past the top of the hour (manual, "Timestamp"); the hour
comes from a reference (GPS time of a position packet's NMEA fix, :func:`lidarpkt.core.nmea.fix_time_ns`;
the capture clock; the previous packet). The decoder (:mod:`lidarpkt.vendors.velodyne.frames`), detection
and the recorder's sink all use these functions, so that they cannot disagree about which hour a stamp is in.
"""

from __future__ import annotations

import numpy as np

HOUR_US = 3_600_000_000
HOUR_NS = HOUR_US * 1000


def in_nearest_hour_ns(timestamp_us: np.ndarray | int, reference_ns: np.ndarray | int) -> np.ndarray:
    """``int64`` ns since the epoch of µs-past-the-hour stamps, in the hour that puts each nearest
    its reference time (``reference_ns``, ns since the epoch; broadcast against ``timestamp_us``).

    Integer arithmetic (exact to the ns for any epoch time); a stamp exactly half an hour from its
    reference goes to the later hour.
    """
    toh_ns = np.asarray(timestamp_us, np.int64) * 1000
    ref = np.asarray(reference_ns, np.int64)
    return toh_ns + (ref - toh_ns + HOUR_NS // 2) // HOUR_NS * HOUR_NS


def hour_steps_us(timestamp_us: np.ndarray, previous_us: int | None = None) -> np.ndarray:
    """``int64[N]`` signed steps between consecutive µs-past-the-hour stamps, each taken within half
    an hour (so the top of the hour is crossed); the first is from ``previous_us`` (0 when ``None``)."""
    ts = np.asarray(timestamp_us, np.int64)
    prev = np.concatenate([[ts[0] if previous_us is None else previous_us], ts[:-1]]) if ts.size else ts
    return (ts - prev + HOUR_US // 2) % HOUR_US - HOUR_US // 2


class SensorClock:
    """The hour of one VLP-16's packet stamps, kept across batches.

    The hour is the one that puts a packet nearest its reference time: the GPS time of the last
    position packet with a fix (:meth:`anchor`, carried forward by the capture clock), else the
    capture time, else (no capture times, e.g. raw payload files) the previous packet, so that the
    top of the hour is crossed correctly in every case.
    """

    def __init__(self) -> None:
        self.last_ns: int | None = None  # sensor time of the last packet seen
        self.gps_anchor: tuple[int, int] | None = None  # (host ns, sensor ns) of a position packet with a fix

    def anchor(self, host_ns: int, timestamp_us: int, utc_ns: int) -> bool:
        """A position packet stamped ``timestamp_us``, captured at ``host_ns``, carried a fix at ``utc_ns``.

        Returns False, and keeps the clock, when packets are already placed and the fix would move
        their hour (a capture replayed or recorded long after its GPS fixes): a stream's times never
        jump back or forward by hours mid-stream, which would make every later packet "late"."""
        sensor_ns = int(in_nearest_hour_ns(timestamp_us, utc_ns))
        if self.last_ns is not None and host_ns:
            current = host_ns if self.gps_anchor is None else self.gps_anchor[1] + (host_ns - self.gps_anchor[0])
            if sensor_ns != int(in_nearest_hour_ns(timestamp_us, current)):  # another hour or day
                return False
        self.gps_anchor = (int(host_ns), sensor_ns)
        return True

    def absolute_ns(self, timestamp_us: np.ndarray, host_ns: np.ndarray) -> np.ndarray:
        """``int64[N]`` ns since the epoch of packets stamped ``timestamp_us`` (µs past the hour) and
        captured at ``host_ns`` (``int64[N]``, 0 where unknown)."""
        ts = np.asarray(timestamp_us, np.int64)
        host_ns = np.asarray(host_ns, dtype=np.int64)
        if host_ns.size and np.all(host_ns != 0):
            ref = host_ns
            if self.gps_anchor is not None:
                ref = self.gps_anchor[1] + (host_ns - self.gps_anchor[0])
            out = in_nearest_hour_ns(ts, ref)
        elif ts.size:
            if self.last_ns is not None:
                start = self.last_ns
            elif self.gps_anchor is not None:
                start = int(in_nearest_hour_ns(ts[0], self.gps_anchor[1]))
            else:
                start = int(ts[0]) * 1000
            out = start + np.cumsum(hour_steps_us(ts, start // 1000 % HOUR_US)) * 1000
        else:
            out = np.zeros(0, np.int64)
        if out.size:
            self.last_ns = int(out[-1])
        return out
