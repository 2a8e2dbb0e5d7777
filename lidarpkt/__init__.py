"""lidarpkt: byte-exact decoding and recording of spinning-lidar packets (Velodyne, Ouster, Hesai).

>>> import lidarpkt
>>> for frame in lidarpkt.open("capture.pcap"):            # doctest: +SKIP
...     print(frame.frame_id, frame.range_mm.shape, frame.xyz().shape)

``lidarpkt.open`` is :func:`lidarpkt.pipeline.reader.open_frames`; its keyword options are declared once, in
:class:`lidarpkt.pipeline.options.OpenOptions`, and typed for static checkers. The names below are imported on
first use, so that ``lidarpkt --help`` and ``--version`` start without NumPy.

Everything lidarpkt installs lives under this one name: :mod:`lidarpkt.recorder` (live capture,
replay, GPS), :mod:`lidarpkt.analysis` (the multi-return analysis), :mod:`lidarpkt.fixtures` (the
synthetic scene and its canned captures), ``lidarpkt._native`` (the optional compiled kernels).
"""

from __future__ import annotations

from pkgutil import extend_path
from typing import TYPE_CHECKING

from lidarpkt.core.lazy import lazy_names
from ._version import __version__
from .errors import LidarpktError

# A source checkout on sys.path (``python -m pytest`` from the repository) imports its own modules, and
# the compiled extension, which only an install builds, from the installed copy of this package.
__path__ = extend_path(__path__, __name__)

if TYPE_CHECKING:
    from lidarpkt.core.frame import Frame, FrameCounters
    from lidarpkt.core.sequence import FrameStack
    from lidarpkt.core.sensor import SensorInfo
    from lidarpkt.core.packet import Endpoint, Packet, PacketBatch
    from lidarpkt.pipeline.reader import open_frames as open  # noqa: A001
    from lidarpkt.containers.pcap_reader import read_packets

__all__ = [
    "__version__",
    "open",
    "read_packets",
    "Frame",
    "FrameCounters",
    "FrameStack",
    "SensorInfo",
    "Packet",
    "PacketBatch",
    "Endpoint",
    "LidarpktError",
]

_lazy_getattr, __dir__ = lazy_names(__name__, {
    "Frame": "core.frame", "FrameCounters": "core.frame", "FrameStack": "core.sequence", "SensorInfo": "core.sensor",
    "Endpoint": "core.packet", "Packet": "core.packet", "PacketBatch": "core.packet",
    "read_packets": "containers.pcap_reader",
}, __all__)


def __getattr__(name: str) -> object:
    if name == "open":  # lidarpkt.open is source.open_frames, imported on first use
        from lidarpkt.pipeline.reader import open_frames

        globals()["open"] = open_frames
        return open_frames
    return _lazy_getattr(name)
