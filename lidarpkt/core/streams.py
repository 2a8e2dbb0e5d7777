"""What each received datagram is, and which ones are missing: the cheap path of recording and
writing raw packets (no decoding).

:func:`classify_size` names the stream of a payload from its size (and the Ouster metadata when
given); :class:`VelodyneLoss` and :class:`OusterLoss` count lost packets and rotations from the
packets themselves, one NumPy pass per batch. The rules are the vendor packages' own
(:mod:`lidarpkt.vendors.velodyne.stream`, :mod:`lidarpkt.vendors.ouster.stream`), the ones their decoders use, so
that the recorder and the decoder cannot disagree about packet periods and rotations:

* VLP-16: the device timestamp (µs past the hour) of consecutive data packets advances by exactly
  one packet period (1327.104 µs single return, 663.552 µs dual: manual, "Timing"); a gap of k
  periods means k − 1 packets lost. A rotation ends where the first block's azimuth wraps.
* Hesai Pandar (sizes only these models send; the content is checked by the counter): the UDP
  sequence number, else the packet time (:mod:`lidarpkt.vendors.hesai.stream`).
* Ouster: the (frame id, measurement id) of each packet's first column gives its place in the
  stream; a jump of k packets means k − 1 lost. A rotation ends where the frame id changes.

A step back (or a repeat) is counted as out of order, never as loss. A jump of more than a second
(forward or back) is an *interruption*: counted and reported on its own, not as packets lost.
"""

from __future__ import annotations

from enum import Enum

from lidarpkt.core.decoder import INTERRUPTION_S, StreamCounts
from lidarpkt.vendors.hesai import stream as hesai_stream
from lidarpkt.vendors.ouster import stream as ouster_stream
from lidarpkt.vendors.velodyne import stream as velodyne_stream


class StreamKind(str, Enum):
    """What a stream of datagrams is. A ``str`` (its value) so that it reads and prints as the word."""

    VELODYNE_DATA = "velodyne_data"
    VELODYNE_POSITION = "velodyne_position"
    OUSTER_LIDAR = "ouster_lidar"
    OUSTER_IMU = "ouster_imu"
    HESAI_DATA = "hesai_data"
    OTHER = "other"

    def __str__(self) -> str:
        return self.value

    def __format__(self, spec: str) -> str:
        return format(self.value, spec)

    @classmethod
    def of(cls, vendor: str, kind: str) -> "StreamKind":
        """The kind of a vendor's stream by the vendor's own name of it (``("velodyne", "data")``, the
        :class:`lidarpkt.pipeline.router.Match` fields); :attr:`OTHER` for a pair this table does not name."""
        return _KINDS.get((vendor, kind), cls.OTHER)

    @property
    def vendor(self) -> str | None:
        """``"velodyne"``, ``"ouster"``, ``"hesai"``, or None for :attr:`OTHER`."""
        return None if self is StreamKind.OTHER else self.value.split("_")[0]

    @property
    def is_lidar(self) -> bool:
        """A stream of range measurements (the one frames are made of)."""
        return self in (StreamKind.VELODYNE_DATA, StreamKind.OUSTER_LIDAR, StreamKind.HESAI_DATA)


VELODYNE_DATA = StreamKind.VELODYNE_DATA
VELODYNE_POSITION = StreamKind.VELODYNE_POSITION
OUSTER_LIDAR = StreamKind.OUSTER_LIDAR
OUSTER_IMU = StreamKind.OUSTER_IMU
HESAI_DATA = StreamKind.HESAI_DATA
OTHER = StreamKind.OTHER

_KINDS = {("velodyne", "data"): VELODYNE_DATA, ("velodyne", "position"): VELODYNE_POSITION,
          ("ouster", "lidar"): OUSTER_LIDAR, ("ouster", "imu"): OUSTER_IMU, ("hesai", "data"): HESAI_DATA}


def classify_size(size: int, ouster_metadata=None) -> StreamKind:
    """Stream kind of a ``size``-byte payload.

    ``ouster_metadata`` (:class:`lidarpkt.vendors.ouster.metadata.OusterMetadata`) makes the
    non-legacy Ouster profiles recognisable; without it only LEGACY sizes are.
    """
    kind = velodyne_stream.stream_kind(size)
    if kind is not None:
        return _KINDS["velodyne", kind]
    kind = ouster_stream.stream_kind(size, ouster_metadata)
    if kind is not None:
        return _KINDS["ouster", kind]
    return HESAI_DATA if hesai_stream.stream_kind(size) else OTHER


#: The counts of one stream (the vendor counters' own).
LossCount = StreamCounts
#: Loss and rotation counting of one VLP-16 data stream: :class:`lidarpkt.vendors.velodyne.stream.PacketCounter`.
VelodyneLoss = velodyne_stream.PacketCounter
#: Loss and frame counting of one Ouster lidar stream: :class:`lidarpkt.vendors.ouster.stream.PacketCounter`.
OusterLoss = ouster_stream.PacketCounter
#: Loss and rotation counting of one Hesai Pandar stream: :class:`lidarpkt.vendors.hesai.stream.PacketCounter`.
HesaiLoss = hesai_stream.PacketCounter

__all__ = ["StreamKind", "VELODYNE_DATA", "VELODYNE_POSITION", "OUSTER_LIDAR", "OUSTER_IMU", "HESAI_DATA", "OTHER",
           "INTERRUPTION_S", "classify_size", "LossCount", "VelodyneLoss", "OusterLoss", "HesaiLoss"]
