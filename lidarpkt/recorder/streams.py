"""What each received datagram is, and which ones are missing: the recorder's cheap live path.

:func:`classify_size` names the stream of a payload from its size (and the Ouster metadata when
given); :class:`VelodyneLoss` and :class:`OusterLoss` count lost packets and rotations from the
packets themselves, one NumPy pass per batch. The rules are the vendor packages' own
(:mod:`lidarpkt.velodyne.stream`, :mod:`lidarpkt.ouster.stream`), the ones their decoders use, so
that the recorder and the decoder cannot disagree about packet periods and rotations:

* VLP-16: the device timestamp (µs past the hour) of consecutive data packets advances by exactly
  one packet period (1327.104 µs single return, 663.552 µs dual: manual, "Timing"); a gap of k
  periods means k − 1 packets lost. A rotation ends where the first block's azimuth wraps.
* Ouster: the (frame id, measurement id) of each packet's first column gives its place in the
  stream; a jump of k packets means k − 1 lost. A rotation ends where the frame id changes.

A step back (or a repeat) is counted as out of order, never as loss. A jump of more than a second
(forward or back) is an *interruption*: counted and reported on its own, not as packets lost.
"""

from __future__ import annotations

from lidarpkt.decoder import INTERRUPTION_S, StreamCounts
from lidarpkt.ouster import stream as ouster_stream
from lidarpkt.velodyne import stream as velodyne_stream

VELODYNE_DATA = "velodyne_data"
VELODYNE_POSITION = "velodyne_position"
OUSTER_LIDAR = "ouster_lidar"
OUSTER_IMU = "ouster_imu"
OTHER = "other"

_KINDS = {("velodyne", "data"): VELODYNE_DATA, ("velodyne", "position"): VELODYNE_POSITION,
          ("ouster", "lidar"): OUSTER_LIDAR, ("ouster", "imu"): OUSTER_IMU}


def classify_size(size: int, ouster_metadata=None) -> str:
    """Stream kind of a ``size``-byte payload: one of the module constants.

    ``ouster_metadata`` (:class:`lidarpkt.ouster.metadata.OusterMetadata`) makes the
    non-legacy Ouster profiles recognisable; without it only LEGACY sizes are.
    """
    kind = velodyne_stream.stream_kind(size)
    if kind is not None:
        return _KINDS["velodyne", kind]
    kind = ouster_stream.stream_kind(size, ouster_metadata)
    return OTHER if kind is None else _KINDS["ouster", kind]


#: The counts of one stream (the vendor counters' own).
LossCount = StreamCounts
#: Loss and rotation counting of one VLP-16 data stream: :class:`lidarpkt.velodyne.stream.PacketCounter`.
VelodyneLoss = velodyne_stream.PacketCounter
#: Loss and frame counting of one Ouster lidar stream: :class:`lidarpkt.ouster.stream.PacketCounter`.
OusterLoss = ouster_stream.PacketCounter

__all__ = ["VELODYNE_DATA", "VELODYNE_POSITION", "OUSTER_LIDAR", "OUSTER_IMU", "OTHER", "INTERRUPTION_S",
           "classify_size", "LossCount", "VelodyneLoss", "OusterLoss"]
