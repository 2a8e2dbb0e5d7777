"""A Foxglove WebSocket protocol client for the view tests: what the Foxglove app does, with
``websockets`` and ``protobuf`` (nothing of lidarpkt's or foxglove-sdk's own code).

It offers the subprotocols ``subprotocols`` (default both names of the protocol, the server
picks: ``foxglove.sdk.v1``, else the older ``foxglove.websocket.v1``; one of them alone to act as
a viewer that knows only it), subscribes to every channel advertised (now and later), and
decodes the binary ``messageData`` frames (opcode 0x01: uint32 subscription id, uint64 log
time, payload) with the schema of the advertisement: protobuf channels through the
FileDescriptorSet it carries, JSON channels as JSON.
"""

from __future__ import annotations

import base64
import json
import struct
import threading
import time
from dataclasses import dataclass, field

from conftest import end_process, start_process

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
MESSAGE_DATA = 0x01


@dataclass
class Received:
    topic: str
    log_time_ns: int
    message: object  # a protobuf message or a JSON value


@dataclass
class FoxgloveClient:
    url: str
    subprotocol: str | None = None
    channels: dict[int, dict] = field(default_factory=dict)
    messages: list[Received] = field(default_factory=list)
    server_info: dict | None = None
    subprotocols: list[str] = field(default_factory=lambda: list(SUBPROTOCOLS))

    def __post_init__(self) -> None:
        from websockets.sync.client import connect

        self._connection = connect(self.url, subprotocols=self.subprotocols, max_size=None, open_timeout=10)
        self._ws = self._connection.__enter__()
        self.subprotocol = self._ws.subprotocol
        self._classes: dict[int, object] = {}
        self._subs: dict[int, int] = {}  # subscription id -> channel id
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.closed = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _message_class(self, ch: dict):
        from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

        fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(ch["schema"]))
        pool = descriptor_pool.DescriptorPool()
        for f in fds.file:
            pool.Add(f)
        return message_factory.GetMessageClass(pool.FindMessageTypeByName(ch["schemaName"]))

    def _run(self) -> None:
        from websockets.exceptions import ConnectionClosed

        next_sub = 1
        pending: list[dict] = []
        pending_since = 0.0
        try:
            while not self._stop.is_set():
                # subscribe a moment after the advertisements (foxglove-sdk 0.30 may refuse a subscription
                # that follows its advertisement too closely: "subscribe to unknown channel")
                if pending and time.monotonic() - pending_since > 0.1:
                    self._ws.send(json.dumps({"op": "subscribe", "subscriptions": pending}))
                    pending = []
                try:
                    data = self._ws.recv(timeout=0.05)
                except TimeoutError:
                    continue
                if isinstance(data, str):
                    msg = json.loads(data)
                    if msg.get("op") == "serverInfo":
                        self.server_info = msg
                    elif msg.get("op") == "advertise":
                        for ch in msg["channels"]:
                            with self._lock:
                                self.channels[ch["id"]] = ch
                            if ch.get("encoding") == "protobuf":
                                self._classes[ch["id"]] = self._message_class(ch)
                            self._subs[next_sub] = ch["id"]
                            if not pending:
                                pending_since = time.monotonic()
                            pending.append({"id": next_sub, "channelId": ch["id"]})
                            next_sub += 1
                    continue
                if data[0] != MESSAGE_DATA:
                    continue
                sub_id, log_time = struct.unpack_from("<IQ", data, 1)
                payload = data[13:]
                ch_id = self._subs[sub_id]
                ch = self.channels[ch_id]
                if ch["id"] in self._classes:
                    message = self._classes[ch_id].FromString(payload)
                else:
                    message = json.loads(payload)
                with self._lock:
                    self.messages.append(Received(ch["topic"], log_time, message))
        except ConnectionClosed:
            pass
        finally:
            self.closed.set()

    def topics(self) -> set[str]:
        with self._lock:
            return {ch["topic"] for ch in self.channels.values()}

    def on(self, topic: str) -> list[Received]:
        with self._lock:
            return [m for m in self.messages if m.topic == topic]

    def wait_for(self, predicate, timeout: float = 60.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if predicate(self):
                return True
            time.sleep(0.05)
        return predicate(self)

    def close(self) -> None:
        self._stop.set()
        try:
            self._connection.__exit__(None, None, None)
        finally:
            self._thread.join(5)


def points_of(message):
    """``(xyz float32[N, 3], fields dict name -> ndarray)`` of a decoded ``foxglove.PointCloud``."""
    import numpy as np

    types = {1: "u1", 2: "i1", 3: "<u2", 4: "<i2", 5: "<u4", 6: "<i4", 7: "<f4", 8: "<f8"}
    dtype = np.dtype({"names": [f.name for f in message.fields],
                      "formats": [types[f.type] for f in message.fields],
                      "offsets": [f.offset for f in message.fields], "itemsize": message.point_stride})
    arr = np.frombuffer(message.data, dtype)
    return np.stack([arr["x"], arr["y"], arr["z"]], axis=1), {n: arr[n] for n in dtype.names}


def stamp_ns(message) -> int:
    return message.timestamp.seconds * 1_000_000_000 + message.timestamp.nanos


class LidarpktProcess:
    """A ``lidarpkt`` verb in a subprocess, waited on until its stderr shows ``ready``; as a context
    manager it kills the process if the test left it running (the model: tests/recorder/test_replay_record.py)."""

    def __init__(self, log_path, *args: str, ready: str | None = None, timeout: float = 60.0) -> None:
        import subprocess
        import sys
        from pathlib import Path

        self.log = Path(log_path)
        self.proc = start_process([sys.executable, "-m", "lidarpkt", *args], stdout=subprocess.DEVNULL,
                                  stderr=self.log.open("w"), cwd=Path(__file__).resolve().parents[1])
        deadline = time.monotonic() + timeout
        while ready is not None and ready not in self.log.read_text():
            if self.proc.poll() is not None or time.monotonic() > deadline:
                end_process(self.proc)
                raise AssertionError(f"lidarpkt {args[0]} did not start: {self.log.read_text()}")
            time.sleep(0.02)

    def port_after(self, prefix: str) -> int:
        """The port in the first ``prefix…HOST:PORT`` of the log (``serving ws://``, ``http://``)."""
        import re

        return int(re.search(re.escape(prefix) + r"[^\s:]+:(\d+)", self.log.read_text()).group(1))

    def stop(self, sig=None) -> int:
        import signal

        if self.proc.poll() is None:
            self.proc.send_signal(sig or signal.SIGTERM)
        return self.proc.wait(timeout=60)

    def __enter__(self) -> "LidarpktProcess":
        return self

    def __exit__(self, *_exc) -> None:
        end_process(self.proc)
