"""Inertial samples of any vendor: one small type shared by every decoder that reads an IMU.

:class:`ImuSamples` holds N samples in SI units (what ``sensor_msgs/Imu`` carries): the sensor's
own clock in ns, linear acceleration in m/s² and angular velocity in rad/s, each axis in the IMU's
frame as the sensor reports it (no gravity removed, no transform applied).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lidarpkt.errors import PacketFormatError

#: Standard gravity (m/s²): converts accelerations reported in g.
STANDARD_GRAVITY_MPS2 = 9.80665


@dataclass(eq=False)
class ImuSamples:
    """N IMU samples.

    Attributes:
        timestamp_ns: ``int64[N]`` time of each sample, ns, the sensor's clock (Unix time only when the
            sensor is synchronised).
        acceleration_mps2: ``float64[N, 3]`` linear acceleration x, y, z, m/s².
        angular_velocity_radps: ``float64[N, 3]`` angular velocity x, y, z, rad/s.
        source: the sensor the samples came from (``"192.168.1.10:7503"``), for reports.
        extra: vendor-specific ``[N, ...]`` arrays (each vendor module documents its keys).
    """

    timestamp_ns: np.ndarray
    acceleration_mps2: np.ndarray
    angular_velocity_radps: np.ndarray
    source: str | None = None
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = np.shape(self.timestamp_ns)[0] if np.ndim(self.timestamp_ns) == 1 else -1
        if (n < 0 or np.shape(self.acceleration_mps2) != (n, 3) or np.shape(self.angular_velocity_radps) != (n, 3)
                or any(np.shape(v)[:1] != (n,) for v in self.extra.values())):
            raise PacketFormatError(
                "ImuSamples: timestamp_ns must be [N], acceleration_mps2 and angular_velocity_radps [N, 3], "
                f"extra [N, ...]; got {np.shape(self.timestamp_ns)}, {np.shape(self.acceleration_mps2)}, "
                f"{np.shape(self.angular_velocity_radps)}")

    def __len__(self) -> int:
        return int(self.timestamp_ns.shape[0])

    @classmethod
    def empty(cls, source: str | None = None) -> ImuSamples:
        return cls(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), source)

    @classmethod
    def concatenate(cls, parts: list[ImuSamples]) -> ImuSamples:
        """The samples of ``parts`` one after the other (extra keys: those of the first part)."""
        if not parts:
            return cls.empty()
        keys = parts[0].extra.keys()
        return cls(np.concatenate([p.timestamp_ns for p in parts]),
                   np.concatenate([p.acceleration_mps2 for p in parts]),
                   np.concatenate([p.angular_velocity_radps for p in parts]),
                   parts[0].source,
                   {k: np.concatenate([p.extra[k] for p in parts]) for k in keys})

    def select(self, rows) -> ImuSamples:
        """The chosen samples (mask, slice or indices)."""
        return ImuSamples(self.timestamp_ns[rows], self.acceleration_mps2[rows], self.angular_velocity_radps[rows],
                          self.source, {k: v[rows] for k, v in self.extra.items()})
