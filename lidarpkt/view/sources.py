"""Where the view's frames come from: a capture played at its own pace (:func:`play_capture`:
``lidarpkt.open``'s frames, released at the pace of their sensor timestamps divided by ``rate``,
optionally looping). Live packets become frames in the pipeline (:mod:`lidarpkt.pipeline.live`).
"""

from __future__ import annotations

import os
import threading
import time
from typing import Iterator

from lidarpkt.core.frame import Frame


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
