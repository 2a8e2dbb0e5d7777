"""Frames from live packet batches: the pipeline's driver fed as packets arrive (``record --points``, ``view``).

* :class:`LiveDecoder`: packet batches as they arrive from the network (any stream mix) routed to one
  frame decoder per sensor by the driver of capture files (:class:`lidarpkt.pipeline.reader.Driver`):
  the same routing, counts, unrouted streams, sensor limit and warnings as ``lidarpkt.open``.
* :class:`FrameTap`: decoding off the receive path: the caller (the recorder, the view) hands batches
  over and never waits; a thread decodes them and gives each frame to its consumers. Its queue is
  bounded in bytes: when decoding falls behind, further batches are dropped *for the frames* (counted
  in ``dropped_packets``); the caller, which writes the packets themselves, loses nothing.

Auxiliary packets a vendor does not decode live (``Vendor.live_auxiliary``) are counted, not decoded:
live VLP-16 frame times take the hour from the host clock (the sensor gives µs past the hour), as the
ROS driver stamps them, and a GPS fix arriving mid-stream whose time disagrees with the host clock (no
NTP, or a replayed capture) would move the decoder's clock back and every later packet would be
dropped as late.
"""

from __future__ import annotations

import queue
import threading
from typing import Callable, Iterable

from lidarpkt.core.decoder import Decoder
from lidarpkt.core.frame import Frame
from lidarpkt.core.packet import PacketBatch

from lidarpkt.vendors import registry

from .reader import Driver
from .router import MAX_SENSORS

FrameConsumer = Callable[[Frame], None]


class LiveDecoder:
    """Packet batches (one stream and payload size each, arrival order) → frames, per sensor, through the
    driver of capture files (:class:`lidarpkt.pipeline.reader.Driver`).

    Args:
        metadata: the sensor files of the sensors, as ``lidarpkt.open`` takes them (paths or loaded objects,
            any vendor's, told apart by content); none for sensors whose packets say enough.
        max_sensors: most sensors decoded (as ``lidarpkt.open``'s ``max_sensors``); packets of more are
            counted in :attr:`unrouted_packets`, with one :class:`~lidarpkt.errors.SkippedPacketWarning`.
        name: what that warning names (the address received on).
        options: the other decoding options of ``lidarpkt.open`` (``model``, ...).

    Packets of no known stream are counted in :attr:`unrouted_packets` (and ``stats.unrouted_streams``),
    never raised on. Auxiliary packets of the vendors that do not use them live (``Vendor.live_auxiliary``)
    are counted in :attr:`auxiliary_packets`, not decoded (module doc).

    Raises what :meth:`lidarpkt.pipeline.options.OpenOptions.sensor_setup` raises (a sensor file of no known kind, an
    unknown model).
    """

    def __init__(self, metadata=(), *, max_sensors: int = MAX_SENSORS, name: str = "live packets",
                 **options) -> None:
        from lidarpkt.pipeline.options import OpenOptions

        opts = OpenOptions.from_keywords("LiveDecoder", {**options, "metadata": list(metadata or ())})
        self.sensor_files, setup = opts.sensor_setup()
        self.driver = Driver(name, setup, max_sensors=max_sensors, sensor_files=self.sensor_files,
                             unused_auxiliary=frozenset(v.name for v in registry.VENDORS if not v.live_auxiliary))
        self.stats = self.driver.stats
        self.router = self.driver.router

    @property
    def decoders(self) -> dict[tuple, Decoder]:
        return self.driver.decoders

    @property
    def unrouted_packets(self) -> int:
        """Packets of no known stream, or of sensors beyond ``max_sensors``."""
        return self.stats.unrouted_packets

    @property
    def auxiliary_packets(self) -> int:
        """Auxiliary packets seen (decoded, or counted only: module doc)."""
        return sum(n for kind, n in self.router.packets.items() if not kind.lidar)

    def push(self, batch: PacketBatch) -> list[Frame]:
        """Decode one batch; returns the frames it completed."""
        return self.driver.route(batch)[1]

    def finish(self) -> list[Frame]:
        """The frames still being assembled (the last, partial ones)."""
        return self.driver.finish()


class FrameTap:
    """Background decoding of packet batches into frames (see the module doc).

    Args:
        decoder: routes batches to per-sensor frame decoders.
        consumers: called with each frame, in the decoding thread, in order.
        on_batch: called with each batch decoded (e.g. to count packets per source).
        queue_bytes: payload bytes allowed to wait for decoding before batches are dropped.

    A consumer that raises does not stop the others nor the decoding: the first error is kept
    in :attr:`error` and further ones are counted in :attr:`consumer_errors`.
    """

    def __init__(self, decoder: LiveDecoder, consumers: Iterable[FrameConsumer], *,
                 on_batch: Callable[[PacketBatch], None] | None = None, queue_bytes: int = 64 << 20) -> None:
        self.decoder = decoder
        self.consumers = list(consumers)
        self.on_batch = on_batch
        self.queue_bytes = queue_bytes
        self.dropped_packets = 0  # packets never decoded (decoding fell behind)
        self.frames = 0
        self.host_time_ns = 0  # receive time of the last packet of the batch being decoded (frames end before it)
        self.consumer_errors = 0
        self.error: BaseException | None = None
        self._queued_bytes = 0
        self._lock = threading.Lock()
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._run, name="lidarpkt-frame-tap", daemon=True)
        self._thread.start()

    def offer(self, batches: list[PacketBatch]) -> None:
        """Queue batches for decoding, or drop them (counted) if the queue is full. Never blocks."""
        if not batches:
            return
        size = sum(b.payload.nbytes for b in batches)
        with self._lock:
            if self._queued_bytes + size > self.queue_bytes:
                self.dropped_packets += sum(len(b) for b in batches)
                return
            self._queued_bytes += size
        self._queue.put((batches, size))

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                break
            batches, size = item
            try:
                for batch in batches:
                    frames = self.decoder.push(batch)
                    self.host_time_ns = int(batch.timestamp_ns[-1])
                    self._deliver(frames)
                    if self.on_batch is not None:
                        self.on_batch(batch)
            except Exception as exc:  # a decoder error must not take the recording down: kept, reported
                self._failed(exc)
            with self._lock:
                self._queued_bytes -= size
        try:
            self._deliver(self.decoder.finish())
        except Exception as exc:
            self._failed(exc)

    def _deliver(self, frames: list[Frame]) -> None:
        for frame in frames:
            self.frames += 1
            for consumer in self.consumers:
                try:
                    consumer(frame)
                except Exception as exc:
                    self._failed(exc)

    def _failed(self, exc: BaseException) -> None:
        self.consumer_errors += 1
        if self.error is None:
            self.error = exc

    def close(self, timeout: float = 60.0) -> None:
        """Decode what was queued, then the last partial frames; stop the thread. Idempotent."""
        if self._thread.is_alive():
            self._queue.put(None)
            self._thread.join(timeout)
