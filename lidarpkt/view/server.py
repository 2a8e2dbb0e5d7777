"""The Foxglove WebSocket server of ``lidarpkt view`` and ``record --view`` (foxglove-sdk's own server).

:class:`ViewServer` starts foxglove-sdk's WebSocket server on its own logging context, on a
loopback port behind :class:`~lidarpkt.view.front.SubprotocolFront` on the public one, so that
viewers offering either subprotocol name of the protocol (``foxglove.sdk.v1``, and the older
``foxglove.websocket.v1`` that the SDK alone refuses) connect, and publishes frames. Each sensor (vendor + source address) gets a name (``velodyne``,
``ouster``, ``velodyne_2`` …, also its ``frame_id``) and these channels, advertised on
its first frame:

==================================  ==========================  ==============================
topic                               schema                      what
==================================  ==========================  ==============================
``/NAME/points/LABEL``              ``foxglove.PointCloud``     one return slot (``strongest`` …)
``/NAME/range_image/LABEL``         ``foxglove.RawImage``       range, metres, ``32FC1``
``/NAME/reflectivity_image/LABEL``  ``foxglove.RawImage``       reflectivity
``/NAME/transform``                 ``foxglove.FrameTransform`` ``base_link`` → NAME (identity)
``/NAME/status``                    JSON                        packets/s, lost packets, frames/s
==================================  ==========================  ==============================

Message layouts are in :mod:`lidarpkt.view.messages`. Thread-safe: frames may be published
from one thread while another counts packets.
"""

from __future__ import annotations

import re
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from lidarpkt.errors import LidarpktError

from . import messages

if TYPE_CHECKING:
    from foxglove import WebSocketServer

STATUS_SCHEMA = {
    "type": "object",
    "properties": {
        "packets_per_s": {"type": "number"}, "frames_per_s": {"type": "number"},
        "lost_packets": {"type": "integer"}, "packets": {"type": "integer"}, "frames": {"type": "integer"},
        "view_frames_dropped": {"type": "integer"},
    },
}


SUBSCRIBE_SETTLE_S = 0.25  # after a client's first subscription, time for the rest of its subscriptions


class ViewError(LidarpktError):
    """The view server cannot start (address in use, foxglove-sdk missing)."""


def parse_ws(text: str) -> tuple[str, int]:
    """``"HOST:PORT"`` of ``--ws`` → (host, port); port 0 lets the system choose. Raises :class:`ViewError`."""
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or int(port) > 65535:
        raise ViewError(f"--ws {text}: not HOST:PORT with a port in 0-65535; give e.g. --ws 127.0.0.1:8765")
    return host.strip("[]"), int(port)


@dataclass
class _Sensor:
    name: str
    labels: tuple[str, ...]
    points: list = field(default_factory=list)
    range_images: list = field(default_factory=list)
    reflectivity_images: list = field(default_factory=list)
    transform: Any = None  # foxglove channels, made when the sensor's first frame arrives
    status: Any = None
    channel_ids: set = field(default_factory=set)
    packets: int = 0
    frames: int = 0
    lost_packets: int = 0
    last: tuple[float, int, int] = (0.0, 0, 0)  # (monotonic s, packets, frames) at the last status


def _listener():
    """A foxglove-sdk ``ServerListener`` whose ``subscribed`` event is set once a client subscribes
    (the SDK's protocol class supplies no-op defaults for the other callbacks)."""
    from foxglove.websocket import ServerListener

    class Listener(ServerListener):
        def __init__(self) -> None:
            self.subscribed = threading.Event()
            self.channels: set[int] = set()  # ids of the channels somebody subscribed to

        def on_subscribe(self, client, channel) -> None:
            # called on the SDK's thread, which may hold the SDK's own locks: take none of ours here
            self.channels.add(channel.id)
            self.subscribed.set()

    return Listener()


class ViewServer:
    """foxglove-sdk WebSocket server publishing frames (see the module doc).

    Args:
        host, port: where to listen (port 0: any free port; :attr:`port` says which).
        name: the server name clients show.
        first_frame_wait_s: a new sensor's first frame waits up to this long for a client to
            subscribe to its channels (just advertised), so that connected clients see it.

    Raises:
        ViewError: foxglove-sdk is not installed (``pip install lidarpkt[view]``) or the
            address cannot be bound.
    """

    serves_viewers = True  # the data reaches viewers only while this process serves it

    def __init__(self, host: str = "127.0.0.1", port: int = 8765, *, name: str = "lidarpkt",
                 first_frame_wait_s: float = 1.0) -> None:
        try:
            import foxglove
        except ImportError:
            raise ViewError("the view needs foxglove-sdk: pip install 'lidarpkt[view]'") from None
        self._foxglove = foxglove
        self.context = foxglove.Context()
        self._listener = _listener()
        self.first_frame_wait_s = first_frame_wait_s
        from .front import SubprotocolFront

        try:  # the SDK's server on loopback; the public port is the front's
            self._server: WebSocketServer | None = foxglove.start_server(name=name, host="127.0.0.1", port=0, context=self.context,
                                                 server_listener=self._listener)
        except Exception as exc:  # the SDK raises its own RuntimeError subclasses
            raise ViewError(f"--ws {host}:{port}: cannot start the Foxglove server ({exc})") from None
        try:
            self._front = SubprotocolFront(host, port, self._server.port)
        except OSError as exc:
            self._server.stop()
            raise ViewError(f"--ws {host}:{port}: cannot serve there ({exc.strerror or exc}); "
                            "choose another HOST:PORT") from None
        self.host = host
        self.port = self._front.port
        self._sensors: dict[tuple, _Sensor] = {}
        self._by_source: dict[str, _Sensor] = {}
        self._names: set[str] = set()
        self._pending_packets: dict[str, int] = {}  # packets of sources not yet named (before their first frame)
        self._lock = threading.Lock()
        self.frames_published = 0
        self.frames_dropped = 0  # frames the caller dropped before publishing (under load); shown in the status

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def wait_for_subscriber(self, timeout: float | None = None) -> bool:
        """Block until a client has subscribed to any channel; False on timeout. A client subscribes
        to several channels one after the other: this returns :data:`SUBSCRIBE_SETTLE_S` after the first."""
        if self._listener.subscribed.is_set():
            return True
        if not self._listener.subscribed.wait(timeout):
            return False
        time.sleep(SUBSCRIBE_SETTLE_S)
        return True

    # ------------------------------------------------------------------ sensors
    def _sensor(self, frame) -> _Sensor:
        key = (frame.sensor.vendor, frame.sensor.source)
        sensor = self._sensors.get(key)
        if sensor is not None:
            return sensor
        base = re.sub(r"[^A-Za-z0-9_]", "_", frame.sensor.vendor) or "sensor"
        name, k = base, 2
        while name in self._names:
            name, k = f"{base}_{k}", k + 1
        self._names.add(name)
        labels = []
        for slot, label in enumerate(frame.return_labels):
            label = re.sub(r"[^A-Za-z0-9_]", "_", label) or f"return{slot}"
            labels.append(label if label not in labels else f"{label}_{slot}")
        ch = self._foxglove.channels
        ctx = self.context
        sensor = _Sensor(name, tuple(labels))
        for label in labels:
            sensor.points.append(ch.PointCloudChannel(f"/{name}/points/{label}", context=ctx))
            sensor.range_images.append(ch.RawImageChannel(f"/{name}/range_image/{label}", context=ctx))
            sensor.reflectivity_images.append(ch.RawImageChannel(f"/{name}/reflectivity_image/{label}", context=ctx))
        sensor.transform = ch.FrameTransformChannel(f"/{name}/transform", context=ctx)
        sensor.status = self._foxglove.Channel(f"/{name}/status", schema=STATUS_SCHEMA, context=ctx)
        sensor.channel_ids = {c.id() for c in [*sensor.points, *sensor.range_images, *sensor.reflectivity_images,
                                               sensor.transform, sensor.status]}
        sensor.last = (time.monotonic(), 0, 0)
        self._sensors[key] = sensor
        if frame.sensor.source is not None:
            self._by_source[str(frame.sensor.source)] = sensor
        return sensor

    def _wait_for_sensor_subscription(self, sensor: _Sensor, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while not (sensor.channel_ids & self._listener.channels):
            if time.monotonic() >= deadline:
                return
            time.sleep(0.02)
        time.sleep(SUBSCRIBE_SETTLE_S)  # the client's other subscriptions follow the first

    def sensor_name(self, frame) -> str:
        """The name (and frame_id) of ``frame``'s sensor, advertising its channels if new."""
        with self._lock:
            return self._sensor(frame).name

    # ---------------------------------------------------------------- publishing
    def publish(self, frame, points: np.ndarray | None = None) -> None:
        """Publish one frame: point clouds, images and transform of its sensor.

        ``points`` is ``frame.points()`` if already computed. Raises
        :class:`lidarpkt.errors.CalibrationError` when the sensor has no geometry.
        """
        with self._lock:
            sensor = self._sensor(frame)
        if not sensor.frames and self.first_frame_wait_s > 0:
            self._wait_for_sensor_subscription(sensor, self.first_frame_wait_s)
        if points is None:
            points = frame.points()
        sensor.transform.log(messages.transform(frame, sensor.name))
        for slot in range(frame.shape[0]):
            sensor.points[slot].log(messages.point_cloud(frame, slot, sensor.name, points))
            rng, refl = messages.images(frame, slot, sensor.name)
            sensor.range_images[slot].log(rng)
            sensor.reflectivity_images[slot].log(refl)
        with self._lock:
            sensor.frames += 1
            sensor.lost_packets += frame.counters.lost_packets
            self.frames_published += 1

    def count_packets(self, source: str, n: int) -> None:
        """Count ``n`` packets received from ``source`` (``str`` of the source endpoint) for the status."""
        with self._lock:
            sensor = self._by_source.get(source)
            if sensor is not None:
                sensor.packets += n
            else:
                self._pending_packets[source] = self._pending_packets.get(source, 0) + n

    def publish_status(self, lost_packets: int | None = None) -> list[dict]:
        """Publish each sensor's status (rates since the previous call); returns them.

        ``lost_packets`` overrides the frames' own count (the recorder's loss accounting is
        the authority while recording; with one sensor only).
        """
        now = time.monotonic()
        out = []
        with self._lock:
            pending = self._pending_packets
            for source in list(pending):
                if source in self._by_source:
                    self._by_source[source].packets += pending.pop(source)
            for sensor in self._sensors.values():
                t, p, f = sensor.last
                dt = max(now - t, 1e-9)
                lost = sensor.lost_packets if lost_packets is None or len(self._sensors) > 1 else lost_packets
                status = {"packets_per_s": round((sensor.packets - p) / dt, 1),
                          "frames_per_s": round((sensor.frames - f) / dt, 2),
                          "lost_packets": int(lost), "packets": sensor.packets, "frames": sensor.frames,
                          "view_frames_dropped": self.frames_dropped}
                sensor.last = (now, sensor.packets, sensor.frames)
                out.append((sensor, status))
        for sensor, status in out:  # outside our lock: the SDK takes its own
            sensor.status.log(status)
        return [{"sensor": sensor.name, **status} for sensor, status in out]

    def close(self, grace_s: float = 0.2) -> None:
        """Stop the server (clients are disconnected) after ``grace_s`` seconds in which the last
        messages reach them. Idempotent."""
        server, self._server = getattr(self, "_server", None), None
        if server is not None:
            if grace_s > 0:
                time.sleep(grace_s)
            try:
                server.stop()
            finally:
                self._front.close()

    def __enter__(self) -> "ViewServer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
