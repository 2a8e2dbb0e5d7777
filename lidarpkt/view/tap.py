"""Decoding off the receive path: the recorder hands packet batches over and never waits.

:class:`FrameTap` takes packet batches (:meth:`FrameTap.offer` never blocks), decodes them
into frames in its own thread with a :class:`~lidarpkt.view.sources.LiveDecoder`, and gives
each frame to its consumers, in that thread. Its queue is bounded in bytes: when decoding
falls behind, further batches are dropped *for the frames* (counted in
``dropped_packets``); the caller, which writes the packets themselves, loses nothing.

:class:`FrameDropper` is a consumer that hands frames to a slower one (the view) through a
queue of a few frames in yet another thread; when that queue is full the frame is dropped
for the viewer (counted in ``dropped``), so a slow viewer never holds decoding back.
"""

from __future__ import annotations

import queue
import threading
from typing import Callable, Iterable

from lidarpkt.core.frame import Frame
from lidarpkt.core.packet import PacketBatch

from .sources import LiveDecoder

FrameConsumer = Callable[[Frame], None]


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


class FrameDropper:
    """A frame consumer that passes frames to ``consume`` in its own thread, at most ``depth``
    waiting; frames beyond are dropped (counted in :attr:`dropped`, and ``on_drop`` called)."""

    def __init__(self, consume: FrameConsumer, *, depth: int = 16,
                 on_drop: Callable[[int], None] | None = None) -> None:
        self.consume = consume
        self.on_drop = on_drop
        self.dropped = 0
        self.delivered = 0
        self.error: BaseException | None = None
        self._queue: queue.Queue = queue.Queue(maxsize=depth)
        self._thread = threading.Thread(target=self._run, name="lidarpkt-view-publish", daemon=True)
        self._thread.start()

    def __call__(self, frame: Frame) -> None:
        try:
            self._queue.put_nowait(frame)
        except queue.Full:
            self.dropped += 1
            if self.on_drop is not None:
                self.on_drop(self.dropped)

    def _run(self) -> None:
        while True:
            frame = self._queue.get()
            if frame is None:
                break
            try:
                self.consume(frame)
                self.delivered += 1
            except Exception as exc:  # kept for the caller's report; the next frames are still tried
                if self.error is None:
                    self.error = exc

    def close(self, timeout: float = 60.0) -> None:
        """Publish the frames waiting, then stop the thread. Idempotent."""
        if self._thread.is_alive():
            self._queue.put(None)  # blocks only while the queue is full: the thread is emptying it
            self._thread.join(timeout)
