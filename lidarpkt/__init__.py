"""lidarpkt: byte-exact decoding and recording of Velodyne VLP-16 and Ouster OS1 lidar packets.

>>> import lidarpkt
>>> for frame in lidarpkt.open("capture.pcap"):            # doctest: +SKIP
...     print(frame.frame_id, frame.range_mm.shape, frame.xyz().shape)
"""

from __future__ import annotations

from .errors import LidarpktError
from .frame import Frame, FrameCounters, FrameStack, SensorInfo
from .packet import Endpoint, Packet, PacketBatch
from .source import open_frames as open  # noqa: A001 - lidarpkt.open: typed keyword options, documented there

__all__ = [
    "open",
    "Frame",
    "FrameCounters",
    "FrameStack",
    "SensorInfo",
    "Packet",
    "PacketBatch",
    "Endpoint",
    "LidarpktError",
]
