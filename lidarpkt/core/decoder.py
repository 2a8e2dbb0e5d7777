"""What every vendor decoder offers (:class:`Decoder`), and what every vendor's cheap stream counter
offers (:class:`StreamCounter`, :class:`StreamCounts`).

A :class:`Decoder` turns the packet batches of one sensor into frames: the packet source
(:func:`lidarpkt.open`) makes one per sensor, pushes it the sensor's lidar batches (:meth:`push`)
and its auxiliary ones (:meth:`push_auxiliary`: Velodyne position packets, Ouster IMU packets),
and calls :meth:`finish` at the end of the capture. Each vendor package has one (its registry record's
``classify`` makes it). A decoder whose frames do not list their packets' ordinals
(``frame.extra["packet_index"]``) also answers ``holds_packet(frame, batch)``: whether a frame holds
the first packet of a batch (reading a segment of a capture needs it).

A :class:`StreamCounter` is the recorder's live path: no frames, only packets, losses and
rotations counted from the packets' own counters, one NumPy pass per batch. Each vendor package
has one (its registry record's ``counter``), built on the same packet periods and rotation rules as
its decoder.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, runtime_checkable

if TYPE_CHECKING:
    import numpy as np

    from .frame import Frame
    from .packet import PacketBatch
    from .sensor import SensorInfo


class DecoderCounts(Protocol):
    """The counters every decoder's ``stats`` has (each vendor adds its own)."""

    packets: int  # lidar packets pushed
    frames: int  # frames released


@runtime_checkable
class Decoder(Protocol):
    """Frames of one sensor from its packet batches."""

    source: str | None  # where the packets come from, for reports ("192.168.1.201:2368")

    @property
    def stats(self) -> DecoderCounts: ...

    def push(self, batch: PacketBatch) -> list[Frame]:
        """Decode a batch of lidar packets (one stream, one payload size, capture order); return
        the frames it completed. Bad packets are counted in :attr:`stats` and skipped."""
        ...

    def push_auxiliary(self, batch: PacketBatch) -> None:
        """Take a batch of the sensor's auxiliary packets (Velodyne position, Ouster IMU)."""
        ...

    def finish(self) -> list[Frame]:
        """The frame still being filled, if any, at the end of the capture."""
        ...

    def sensor_info(self, mode: str | None = None) -> SensorInfo:
        """The sensor's description (``mode``: a Velodyne return mode; the current one by default)."""
        ...


@dataclass
class StreamCounts:
    """Counts of one stream: packets seen, lost (gaps), out of order, rotations completed, restarts
    (``interruptions``) and corrupted packets (see :mod:`lidarpkt.core.continuity`)."""

    packets: int = 0
    lost: int = 0
    out_of_order: int = 0
    frames: int = 0
    interruptions: int = 0  # restarts: a jump in the stream's counters the capture time cannot explain, then agreement
    corrupted: int = 0  # packets off both neighbours by such a jump: skipped


@runtime_checkable
class StreamCounter(Protocol):
    """Counts one lidar stream from its payloads, batch after batch, in arrival order."""

    count: StreamCounts

    def update(self, payload: np.ndarray, host_ns: np.ndarray | None = None) -> np.ndarray:
        """Count ``uint8[N, L]`` payloads captured at ``host_ns`` (``int64[N]``, ns; ``None`` or 0:
        unknown); returns ``bool[N]``, True where a packet starts a new rotation."""
        ...
