"""The Rerun view: ``lidarpkt view [SOURCE] --rerun [TARGET]`` shows a capture or a live sensor in Rerun's
viewer (rerun-sdk: ``pip install 'lidarpkt[rerun]'``), with the entities and timelines of a ``.rrd``
recording (:mod:`lidarpkt.writers.rerun`); the status lines (packets/s, frames/s, losses) are printed
as with Foxglove.

TARGET (``--rerun`` alone is ``web``):

========================  ==========================================================================
``web``                   Rerun's web viewer served here (http://localhost:9090), the data over its
                          gRPC server (port 9876): open the printed address in a browser; on a
                          machine without a screen, forward both ports (``ssh -L 9090:localhost:9090
                          -L 9876:localhost:9876 HOST``). The SDK listens on every interface.
``web:PORT``              the same with the web viewer on PORT and gRPC on PORT + 1 (``web:0``: any
                          free ports; the printed address says which)
``spawn``                 start Rerun's native viewer (needs a display)
``rerun+http://…/proxy``  send to a viewer already running (``rerun`` in a terminal prints its address)
``FILE.rrd``              save a recording (renamed into place when the view stops)
========================  ==========================================================================

:class:`RerunView` has the methods of :class:`lidarpkt.view.server.ViewServer` that ``lidarpkt view``
uses (``publish``, ``count_packets``, ``publish_status``, ``wait_for_subscriber``, ``close``), so that
the same capture player and live tap feed either.
"""

from __future__ import annotations

import socket
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lidarpkt.errors import LidarpktError

DEFAULT_WEB_PORT = 9090  # Rerun's own defaults
DEFAULT_GRPC_PORT = 9876


class RerunViewError(LidarpktError):
    """The Rerun view cannot start (rerun-sdk missing, a port in use, a bad target)."""


@dataclass
class _Counts:
    name: str
    packets: int = 0
    frames: int = 0
    lost_packets: int = 0
    last: tuple[float, int, int] = (0.0, 0, 0)  # (monotonic s, packets, frames) at the last status


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _check_free(port: int, target: str) -> None:
    """Raise :class:`RerunViewError` if ``port`` is taken: the SDK's gRPC server would fail later, on its
    own thread, where no caller hears of it."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("0.0.0.0", port))
        except OSError as exc:
            raise RerunViewError(f"--rerun {target}: port {port} is in use ({exc.strerror or exc}); give "
                                 "web:PORT with a free PORT and PORT + 1, or web:0") from None


def _rerun():
    try:
        import rerun
    except ImportError:
        raise RerunViewError("--rerun needs rerun-sdk: pip install 'lidarpkt[rerun]'") from None
    return rerun


class RerunView:
    """Frames into a Rerun recording stream sent to ``target`` (see the module doc).

    Args:
        target: ``web``, ``web:PORT``, ``spawn``, a ``rerun+http://`` address or a ``.rrd`` path.
        color: ``"range"`` or ``"reflectivity"`` (:class:`lidarpkt.writers.rerun.RerunFrames`).
        name: the recording's name in the viewer.

    Attributes:
        url: the web viewer's address (``web``), else ``None``.

    Raises:
        RerunViewError: rerun-sdk is missing, the target is none of the above, a port cannot be used.
        OutputError: a ``.rrd`` path whose folder does not exist; another ``color``.
    """

    def __init__(self, target: str = "web", *, color: str = "range", name: str = "lidarpkt view") -> None:
        from lidarpkt.writers.base import AtomicFiles
        from lidarpkt.writers.rerun import APPLICATION_ID, RerunFrames

        rr = _rerun()
        self.target = target
        self.url: str | None = None
        self._files = AtomicFiles()
        self._tmp: Path | None = None
        self.recording: Any = rr.RecordingStream(APPLICATION_ID)
        self.recording.send_recording_name(name)
        try:
            self._connect(rr, target)
        except (RuntimeError, OSError, ValueError) as exc:  # the SDK's own errors: a port in use, a bad address
            self.recording.disconnect()
            if self._tmp is not None:  # a file: its folder, as every other output says it
                folder = Path(target).parent
                raise RerunViewError(f"--rerun {target}: cannot write in {folder}; choose a writable folder") from None
            raise RerunViewError(f"--rerun {target}: cannot serve or connect there ({exc})") from None
        except BaseException:
            self.recording.disconnect()
            raise
        self.frames = RerunFrames(self.recording, color=color)
        self._lock = threading.Lock()
        self._sensors: dict[str, _Counts] = {}  # by source address
        self._pending_packets: dict[str, int] = {}
        self.frames_published = 0
        self.frames_dropped = 0  # frames the caller dropped before publishing (under load)
        self._closed = False
        # only the web target holds the data in this process: a file, a spawned or a remote viewer has it
        self.serves_viewers = self.url is not None

    def _connect(self, rr: Any, target: str) -> None:
        if target == "web" or target.startswith("web:"):
            port_text = target[4:] or str(DEFAULT_WEB_PORT)
            if not port_text.isdigit() or int(port_text) > 65534:
                raise RerunViewError(f"--rerun {target}: give web or web:PORT (PORT 0-65534, 0: any free port)")
            web = int(port_text) or _free_port()
            grpc = _free_port() if port_text == "0" else web + 1 if target.startswith("web:") else DEFAULT_GRPC_PORT
            for port in (web, grpc):
                _check_free(port, target)
            grpc_url = self.recording.serve_grpc(grpc_port=grpc)
            rr.serve_web_viewer(web_port=web, open_browser=False, connect_to=grpc_url)
            self.url = f"http://localhost:{web}/?url={grpc_url.replace('127.0.0.1', 'localhost')}"
        elif target == "spawn":
            self.recording.spawn()
        elif target.startswith(("rerun+http://", "rerun+https://", "rerun://")):
            self.recording.connect_grpc(target)
        elif target.lower().endswith(".rrd"):
            self._tmp = self._files.temporary(target)
            self.recording.save(self._tmp)
        else:
            raise RerunViewError(f"--rerun {target}: give web, web:PORT, spawn, a rerun+http:// address or a "
                                 "FILE.rrd")

    # ------------------------------------------------------------ the ViewServer methods the view uses
    def wait_for_subscriber(self, timeout: float | None = None) -> bool:
        """True: Rerun's servers keep what was sent for viewers that connect later."""
        return True

    def sensor_name(self, frame) -> str:
        return self.frames.sensor_name(frame)

    def publish(self, frame, points: np.ndarray | None = None) -> None:
        """Log one frame; ``points`` is ``frame.points()`` if already computed. Raises
        :class:`~lidarpkt.errors.CalibrationError` when the sensor has no calibration."""
        self.frames.log(frame, points)
        with self._lock:
            source = str(frame.sensor.source)
            counts = self._sensors.get(source)
            if counts is None:
                counts = self._sensors[source] = _Counts(self.frames.sensor_name(frame), last=(time.monotonic(), 0, 0))
                counts.packets += self._pending_packets.pop(source, 0)
            counts.frames += 1
            counts.lost_packets += frame.counters.lost_packets
            self.frames_published += 1

    def count_packets(self, source: str, n: int) -> None:
        """Count ``n`` packets received from ``source`` for the status."""
        with self._lock:
            counts = self._sensors.get(source)
            if counts is not None:
                counts.packets += n
            else:
                self._pending_packets[source] = self._pending_packets.get(source, 0) + n

    def publish_status(self, lost_packets: int | None = None) -> list[dict]:
        """Each sensor's rates since the previous call (the status lines of ``lidarpkt view``), as
        :meth:`lidarpkt.view.server.ViewServer.publish_status` returns them; nothing is sent to Rerun."""
        now = time.monotonic()
        out = []
        with self._lock:
            for counts in self._sensors.values():
                t, p, f = counts.last
                dt = max(now - t, 1e-9)
                lost = counts.lost_packets if lost_packets is None or len(self._sensors) > 1 else lost_packets
                out.append({"sensor": counts.name, "packets_per_s": round((counts.packets - p) / dt, 1),
                            "frames_per_s": round((counts.frames - f) / dt, 2), "lost_packets": int(lost),
                            "packets": counts.packets, "frames": counts.frames,
                            "view_frames_dropped": self.frames_dropped})
                counts.last = (now, counts.packets, counts.frames)
        return out

    def close(self, grace_s: float = 0.2) -> None:
        """Send what is left and stop (a ``.rrd`` target is renamed into place). Idempotent."""
        if self._closed:
            return
        self._closed = True
        try:
            self.recording.flush()
            if grace_s > 0 and self.url is not None:
                time.sleep(grace_s)
            self.recording.disconnect()
        except RuntimeError as exc:  # the SDK's sink failed on its own thread (a server that could not start)
            raise RerunViewError(f"--rerun {self.target}: sending to Rerun failed ({exc})") from None
        if self._tmp is not None:
            self._files.commit(self._tmp)

    def __enter__(self) -> "RerunView":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def start_rerun(target: str, *, verb: str = "view", color: str = "range") -> RerunView:
    """A :class:`RerunView` on ``target``; says where to look (even with ``--quiet``: scripts wait for
    that line)."""
    view = RerunView(target, color=color, name=f"lidarpkt {verb}")
    if view.url is not None:
        where = f"Rerun web viewer on {view.url} (open it in a browser)"
    elif target == "spawn":
        where = "sending to Rerun's viewer"
    elif target.lower().endswith(".rrd"):
        where = f"recording to {target} (open it with: rerun {target})"
    else:
        where = f"sending to the Rerun viewer at {target}"
    print(f"lidarpkt {verb}: {where}", file=sys.stderr, flush=True)
    return view
