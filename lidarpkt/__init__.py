"""lidarpkt: byte-exact decoding and recording of Velodyne VLP-16 and Ouster OS1 lidar packets.

>>> import lidarpkt
>>> for frame in lidarpkt.open("capture.pcap"):            # doctest: +SKIP
...     print(frame.frame_id, frame.range_mm.shape, frame.xyz().shape)

``lidarpkt.open`` is :func:`lidarpkt.source.open_frames`; its typed keyword options are declared once,
in :class:`lidarpkt.options.OpenOptions`, and listed by ``help(lidarpkt.open)``. The names below are imported on first use, so that ``lidarpkt --help`` and ``--version``
start without NumPy.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from . import _moved
from .errors import LidarpktError

_moved.install()  # old paths of moved modules (lidarpkt.pcapwrite, recorder.mcap_writer ...)

if TYPE_CHECKING:
    from .frame import Frame, FrameCounters, FrameStack, SensorInfo
    from .packet import Endpoint, Packet, PacketBatch
    from .source import open_frames as open  # noqa: A001

# public name -> (module, attribute)
_LAZY: dict[str, tuple[str, str]] = {
    "open": ("source", "open_frames"),
    "Frame": ("frame", "Frame"), "FrameCounters": ("frame", "FrameCounters"), "FrameStack": ("frame", "FrameStack"),
    "SensorInfo": ("frame", "SensorInfo"),
    "Endpoint": ("packet", "Endpoint"), "Packet": ("packet", "Packet"), "PacketBatch": ("packet", "PacketBatch"),
}


def __getattr__(name: str) -> Any:
    target = _LAZY.get(name)
    if target is None:
        raise AttributeError(f"module 'lidarpkt' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(f".{target[0]}", __name__), target[1])
    globals()[name] = value
    return value


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
