"""Frame messages that wait for their log time: the MCAP writer encodes a frame when the pass hands it,
but logs it inside the capture's span (:class:`~lidarpkt.writers.mcap.packets.CaptureTimes`), which is known
only at the capture's end for a frame whose time falls outside the packets seen so far (a frame's last
column is a little later than the packet that completed it; a sensor clock without an offset).

:class:`PendingFrames` holds such frames' encoded messages in memory up to ``memory_bytes``, and the ones
beyond in an unnamed temporary file in the output's folder (memory stays bounded whatever the capture);
:meth:`PendingFrames.take` gives back those now settled, :meth:`PendingFrames.drain` all of them.
"""

from __future__ import annotations

import os
import pickle
import tempfile
from collections import deque
from pathlib import Path
from typing import IO, Callable, Iterator

from .schemas import Topic

Messages = list[tuple[Topic, bytes]]  # a frame's encoded messages


class PendingFrames:
    """Encoded frame messages waiting for their log time (see the module doc).

    Each frame waits as ``(end_ns, source, messages)``: its last column's sensor time (ns), its
    sensor's source name (which clock offset applies) and its encoded messages.

    Args:
        folder: where the temporary file goes (the output's folder).
        memory_bytes: message bytes held in memory before further frames go to the file.
    """

    def __init__(self, folder: str | os.PathLike[str], memory_bytes: int = 64 << 20) -> None:
        self.folder = Path(folder)
        self.memory_bytes = memory_bytes
        self._held: deque[tuple[int, str | None, Messages]] = deque()
        self._held_bytes = 0
        self._file: IO[bytes] | None = None
        self._spilled = 0

    def __len__(self) -> int:
        return len(self._held) + self._spilled

    def add(self, end_ns: int, source: str | None, messages: Messages) -> None:
        size = sum(len(data) for _, data in messages)
        if self._held_bytes + size <= self.memory_bytes or not self._held:
            self._held.append((end_ns, source, messages))
            self._held_bytes += size
            return
        if self._file is None:
            self._file = tempfile.TemporaryFile(dir=self.folder, prefix=".lidarpkt-pending-")
        pickle.dump((end_ns, source, messages), self._file, protocol=pickle.HIGHEST_PROTOCOL)
        self._spilled += 1

    def take(self, settled: Callable[[int, str | None], bool]) -> list[tuple[int, str | None, Messages]]:
        """The frames held in memory for which ``settled(end_ns, source)`` is true, removed (in the order
        they came); those in the file wait for :meth:`drain`."""
        if not self._held:
            return []
        out: list[tuple[int, str | None, Messages]] = []
        keep: deque[tuple[int, str | None, Messages]] = deque()
        for item in self._held:
            (out if settled(item[0], item[1]) else keep).append(item)
        if out:
            self._held = keep
            self._held_bytes -= sum(len(data) for _, _, messages in out for _, data in messages)
        return out

    def drain(self) -> Iterator[tuple[int, str | None, Messages]]:
        """Every frame waiting, in the order they came; empty afterwards."""
        while self._held:
            item = self._held.popleft()
            self._held_bytes -= sum(len(data) for _, data in item[2])
            yield item
        if self._file is not None:
            fh, self._file, self._spilled = self._file, None, 0
            try:
                fh.seek(0)
                while True:
                    try:
                        yield pickle.load(fh)
                    except EOFError:
                        break
            finally:
                fh.close()

    def close(self) -> None:
        """Forget what waits (removes the temporary file). Idempotent."""
        self._held.clear()
        self._held_bytes = 0
        if self._file is not None:
            self._file.close()
            self._file = None
            self._spilled = 0
