"""Frames to a slower consumer without holding decoding back.

:class:`FrameDropper` is a consumer of :class:`lidarpkt.pipeline.live.FrameTap` (decoding off the receive
path) that hands frames to a slower one (the view) through a queue of a few frames in yet another thread;
when that queue is full the frame is dropped for the viewer (counted in ``dropped``), so a slow viewer
never holds decoding back.
"""

from __future__ import annotations

import queue
import threading
from typing import Callable

from lidarpkt.core.frame import Frame

FrameConsumer = Callable[[Frame], None]


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
