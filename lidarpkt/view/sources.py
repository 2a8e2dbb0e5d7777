"""Where the view's frames come from: a capture played at its own pace, or live packet batches.

* :func:`play_capture`: ``lidarpkt.open``'s frames, released at the pace of their sensor
  timestamps divided by ``rate`` (optionally looping).
* :class:`LiveDecoder`: packet batches as they arrive from the network (any stream mix)
  routed to one frame decoder per sensor by ``lidarpkt.open``'s own router (:mod:`lidarpkt.pipeline.router`):
  VLP-16 streams by their packets, Ouster streams by the metadata given.

Live VLP-16 frame times take the hour from the host clock (the sensor gives µs past the hour),
as the ROS driver stamps them; position packets are counted but not used for it: a GPS fix
arriving mid-stream whose time disagrees with the host clock (no NTP, or a replayed capture)
would move the decoder's clock back and every later packet would be dropped as late.
"""

from __future__ import annotations

import os
import threading
import time
from typing import Iterator

from lidarpkt.core.decoder import Decoder
from lidarpkt.core.frame import Frame
from lidarpkt.core.packet import PacketBatch
from lidarpkt.pipeline.router import MAX_SENSORS, RouteOptions, Router


def play_capture(path: str | os.PathLike[str], *, metadata=None, rate: float = 1.0, loop: bool = False,
                 stop: threading.Event | None = None, on_reader=None, before_first=None,
                 **options) -> Iterator[Frame]:
    """Frames of a capture (``lidarpkt.open(path, metadata=metadata, **options)``) at their own pace.

    A frame is yielded once ``(its timestamp_ns − the first's) / rate`` seconds have passed since
    the start of the round; ``loop`` starts again at the end until ``stop`` is set (``stop`` also
    ends the wait between frames). ``on_reader(reader)`` sees each round's
    :class:`lidarpkt.pipeline.reader.FrameReader` (for its packet counts); ``before_first(frame)`` is
    called with the very first frame before the clock starts (to wait for a viewer).

    Raises what ``lidarpkt.open`` raises; :class:`lidarpkt.errors.LidarpktError` if ``rate`` ≤ 0.
    """
    from lidarpkt.errors import LidarpktError
    from lidarpkt.pipeline.reader import open_frames

    if not rate > 0:
        raise LidarpktError(f"--rate must be positive, got {rate}")
    stop = stop or threading.Event()
    while not stop.is_set():
        t0 = None
        start = time.monotonic()
        frames = 0
        with open_frames(path, metadata=metadata, **options) as reader:
            if on_reader is not None:
                on_reader(reader)
            for frame in reader:
                if t0 is None:
                    if before_first is not None:
                        before_first(frame)
                        before_first = None
                    t0 = frame.timestamp_ns
                    start = time.monotonic()
                ahead = (frame.timestamp_ns - t0) / 1e9 / rate - (time.monotonic() - start)
                if ahead > 0 and stop.wait(ahead):
                    return
                if stop.is_set():
                    return
                frames += 1
                yield frame
        if not loop or frames == 0:
            return


class LiveDecoder:
    """Packet batches (one stream and payload size each, arrival order) → frames, per sensor, through the
    one router of files and live sources (:class:`lidarpkt.pipeline.router.Router`).

    Args:
        ouster_metadata: :class:`lidarpkt.vendors.ouster.metadata.OusterMetadata` of each Ouster sensor
            (none for VLP-16 only).
        max_sensors: most sensors decoded (as ``lidarpkt.open``'s ``max_sensors``); packets of more are
            counted in :attr:`unrouted_packets`.
        options: the decoders' options of ``lidarpkt.open`` (``calibration``, ``velodyne_model``, ...).

    Packets of no known stream are counted in :attr:`unrouted_packets`, never raised on. VLP-16 position
    packets are counted in :attr:`position_packets`, not decoded (module doc).
    """

    def __init__(self, ouster_metadata=(), *, max_sensors: int = MAX_SENSORS, **options) -> None:
        from lidarpkt.pipeline.options import OpenOptions
        from lidarpkt.pipeline.reader import decoder_options

        self.ouster_metadata = list(ouster_metadata or ())
        _, by_vendor = decoder_options(OpenOptions.from_keywords("LiveDecoder", options))
        self.router = Router(RouteOptions(self.ouster_metadata, by_vendor), max_sensors=max_sensors,
                             unused_auxiliary=frozenset({"velodyne"}))
        self.unrouted_packets = 0

    @property
    def decoders(self) -> dict[tuple, Decoder]:
        return self.router.decoders

    @property
    def position_packets(self) -> int:
        """VLP-16 position packets seen (not used for the time: module doc)."""
        return self.router.packets.get(("velodyne", "position"), 0)

    def push(self, batch: PacketBatch) -> list[Frame]:
        """Decode one batch; returns the frames it completed."""
        frames = self.router.push(batch)
        if frames is None:
            self.unrouted_packets += len(batch)
            return []
        return frames

    def finish(self) -> list[Frame]:
        """The frames still being assembled (the last, partial ones)."""
        return self.router.finish()
