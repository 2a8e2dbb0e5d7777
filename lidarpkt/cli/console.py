"""What the terminal shows and sends: the progress bar of every verb (off with ``-q`` or off a terminal),
and the signals that ask the long-running verbs to stop cleanly. The library takes plain arguments (a
progress callback, a stop function); the verbs make them from these."""

from __future__ import annotations

import os
import sys

__all__ = ["JobBars", "Progress", "StopSignals", "show_progress", "count"]


def count(n: int, noun: str, plural: str | None = None) -> str:
    """``"1 frame"``, ``"2 frames"``: a number and its noun, singular or plural."""
    return f"{n} {noun if n == 1 else (plural or noun + 's')}"


def show_progress(quiet: bool) -> bool:
    """Progress bars only on a terminal and without ``-q``."""
    return not quiet and sys.stderr.isatty()


class Progress:
    """The progress bar of every verb (tqdm on stderr): bytes of the input read when known, else a
    count, with a status text (``"52 frames"``) beside it. Off with ``-q`` or off a terminal."""

    def __init__(self, quiet: bool, *, total: int | None = None, unit: str = "B", desc: str = "") -> None:
        from tqdm import tqdm

        enabled = show_progress(quiet)
        try:  # a terminal that reports no size (a bare pty) would get no bar at all from tqdm
            size = os.get_terminal_size(sys.stderr.fileno())
            sized = size.columns > 0 and size.lines > 0
        except OSError:
            sized = False
        self.bar = tqdm(total=total or None, unit=unit, unit_scale=True, unit_divisor=1024 if unit == "B" else 1000,
                        desc=desc, disable=not enabled, file=sys.stderr, dynamic_ncols=sized,
                        ncols=None if sized else 80, nrows=None if sized else 24, leave=False, mininterval=0.1)

    def update(self, done: int | None, status: str = "") -> None:
        """``done``: how far (bytes or items) from the start, ``None`` if unknown; ``status``: text after the bar."""
        if self.bar.disable:
            return
        if done is not None and done != self.bar.n:
            self.bar.update(done - self.bar.n)
        if status:
            self.bar.set_postfix_str(status, refresh=False)

    def close(self) -> None:
        self.bar.close()

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class StopSignals:
    """SIGINT and SIGTERM ask a long-running verb (``record``, ``view``) to stop: it finishes cleanly
    (closes its files with their index, says its summary) instead of dying mid-write.

    ``with StopSignals() as stop:`` (or :meth:`install` … :meth:`restore`) installs the handlers (in the main thread only: elsewhere signals
    cannot be handled) and puts the previous ones back at the end. ``stop.event`` is set and
    ``stop.reason`` names the signal on the first one; with ``second_interrupt_raises``, a second
    Ctrl-C raises :class:`KeyboardInterrupt` (stop now)."""

    def __init__(self, *, second_interrupt_raises: bool = False) -> None:
        import threading

        self.event = threading.Event()
        self.reason: str | None = None
        self.second_interrupt_raises = second_interrupt_raises
        self._previous: dict = {}

    def __call__(self, signum, _frame) -> None:
        import signal

        if self.reason is not None and self.second_interrupt_raises and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.reason = signal.Signals(signum).name
        self.event.set()

    def install(self) -> "StopSignals":
        """Handle SIGINT and SIGTERM from now on (main thread only); returns self."""
        import signal
        import threading

        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._previous[sig] = signal.signal(sig, self)
        return self

    def restore(self) -> None:
        """Put the previous handlers back. Idempotent."""
        import signal

        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous.clear()

    def __enter__(self) -> "StopSignals":
        return self.install()

    def __exit__(self, *exc) -> None:
        self.restore()


class JobBars:
    """The ``progress`` callback of the archive jobs (:class:`lidarpkt.archive.engine.JobProgress`): one bar
    per pass, bytes of the units done, the units done (and failed) beside it. Off with ``-q`` or off a
    terminal."""

    def __init__(self, quiet: bool) -> None:
        self.quiet = quiet
        self.bar: Progress | None = None
        self.label: str | None = None

    def __call__(self, state) -> None:
        if self.bar is None or state.label != self.label:
            self.close()
            self.bar, self.label = Progress(self.quiet, total=state.bytes_total, desc=state.label), state.label
        self.bar.update(state.bytes_done, state.status())
        if state.finished:
            self.close()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None
