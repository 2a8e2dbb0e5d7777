"""lidarpkt: byte-exact decoding and recording of Velodyne VLP-16 and Ouster OS1 lidar packets.

>>> import lidarpkt
>>> for frame in lidarpkt.open("capture.pcap"):            # doctest: +SKIP
...     print(frame.frame_id, frame.range_mm.shape, frame.xyz().shape)
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any

from .errors import LidarpktError
from .frame import Frame, FrameCounters, FrameStack, SensorInfo
from .packet import Endpoint, Packet, PacketBatch
from . import _moved

_moved.install()  # old paths of moved modules (lidarpkt.pcapwrite, recorder.mcap_writer ...)

if TYPE_CHECKING:
    from .source import FrameReader

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


def open(  # noqa: A001 - the public name is part of the API contract
    path: str | os.PathLike[str],
    *,
    metadata: str | os.PathLike[str] | list[str | os.PathLike[str]] | None = None,
    **options: Any,
) -> FrameReader:
    """Frames from a capture: pcap/pcapng, an MCAP file, or a ROS bag holding raw packet topics.

    Returns a :class:`~lidarpkt.source.FrameReader`: iterate it for frames; its ``stats`` say
    what was routed where and what was skipped; ``close()`` (or ``with``) stops reading early.

    Args:
        path: the capture file (or rosbag2 directory).
        metadata: Ouster metadata JSON path (a list of paths for several sensors); VLP-16 needs none.
        **options: see :func:`lidarpkt.source.open_frames` (calibration, cut angle, read-ahead,
            packet filters...).

    Yields:
        :class:`Frame` objects in the order their last packet arrived.

    Raises:
        lidarpkt.errors.LidarpktError: subclasses say what is wrong with the input.
    """
    from .source import open_frames

    return open_frames(path, metadata=metadata, **options)
