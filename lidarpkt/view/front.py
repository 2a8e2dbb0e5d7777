"""The view's public port: viewers that offer the Foxglove protocol's older WebSocket subprotocol
name reach foxglove-sdk's server, which knows only the newer one.

The Foxglove WebSocket protocol is one wire protocol under two subprotocol names:
``foxglove.websocket.v1`` (Foxglove Studio's open-source web builds, Lichtblick before its
December 2025 release) and ``foxglove.sdk.v1`` (foxglove-sdk 0.30's server, which answers any
other offer with HTTP 400). :class:`SubprotocolFront` listens on the public port and hands each
connection to the SDK server on a loopback port: in the client's HTTP upgrade request the older
name, when the client does not also offer the newer, is replaced by the newer
(:func:`rename_offer`); in the server's answer the chosen subprotocol is named back as the client
offered it (:func:`rename_answer`: a browser fails a handshake whose subprotocol it did not
offer). ``Sec-WebSocket-Accept`` depends on the client's key alone, so the handshake stays valid;
after it the bytes go through unchanged, both ways. Clients offering the newer name pass through
untouched.

It runs an asyncio loop in one daemon thread. A request head larger than
:data:`MAX_HEAD_BYTES`, or a connection that ends before its head, is closed.
"""

from __future__ import annotations

import asyncio
import threading

__all__ = ["SubprotocolFront", "rename_offer", "rename_answer", "SDK_SUBPROTOCOL", "OLD_SUBPROTOCOL"]

SDK_SUBPROTOCOL = "foxglove.sdk.v1"
OLD_SUBPROTOCOL = "foxglove.websocket.v1"
MAX_HEAD_BYTES = 64 * 1024  # an HTTP request head; browsers send well under 8 KiB
_HEADER = b"sec-websocket-protocol"
_RELAY_BYTES = 1 << 16


def _protocol_lines(lines: list[bytes]) -> list[int]:
    return [i for i, line in enumerate(lines[1:], 1) if line.split(b":", 1)[0].strip().lower() == _HEADER]


def _tokens(line: bytes) -> list[str]:
    return [t.strip() for t in line.split(b":", 1)[1].decode("latin-1").split(",") if t.strip()]


def rename_offer(head: bytes) -> tuple[bytes, bool]:
    """``(head, renamed)``: an HTTP request head (through its blank line) with ``foxglove.websocket.v1``
    replaced by ``foxglove.sdk.v1`` in its ``Sec-WebSocket-Protocol`` offers, where the client does
    not offer the newer name itself; ``renamed`` says whether it did so."""
    lines = head.split(b"\r\n")
    where = _protocol_lines(lines)
    offered = [t for i in where for t in _tokens(lines[i])]
    if OLD_SUBPROTOCOL not in offered or SDK_SUBPROTOCOL in offered:
        return head, False
    for i in where:
        name = lines[i].split(b":", 1)[0]
        tokens = [SDK_SUBPROTOCOL if t == OLD_SUBPROTOCOL else t for t in _tokens(lines[i])]
        lines[i] = name + b": " + ", ".join(tokens).encode("latin-1")
    return b"\r\n".join(lines), True


def rename_answer(head: bytes) -> bytes:
    """An HTTP response head with the subprotocol ``foxglove.sdk.v1`` named ``foxglove.websocket.v1``."""
    lines = head.split(b"\r\n")
    for i in _protocol_lines(lines):
        if _tokens(lines[i]) == [SDK_SUBPROTOCOL]:
            lines[i] = lines[i].split(b":", 1)[0] + b": " + OLD_SUBPROTOCOL.encode()
    return b"\r\n".join(lines)


async def _pipe(src: asyncio.StreamReader, dst: asyncio.StreamWriter) -> None:
    """Copy until ``src`` ends, then close ``dst`` (the other direction then ends too)."""
    try:
        while data := await src.read(_RELAY_BYTES):
            dst.write(data)
            await dst.drain()
    except (ConnectionError, OSError):
        pass
    finally:
        dst.close()


class SubprotocolFront:
    """A TCP listener on ``host:port`` relaying each connection to ``target_host:target_port`` with
    the subprotocol renamed in the handshake (see the module doc).

    Args:
        host, port: where to listen (port 0: a free port; :attr:`port` says which).
        target_port, target_host: the foxglove-sdk server.

    Raises:
        OSError: the address cannot be bound.
    """

    def __init__(self, host: str, port: int, target_port: int, target_host: str = "127.0.0.1") -> None:
        self.target = (target_host, target_port)
        self._connections: set[asyncio.Task] = set()
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="lidarpkt-view-front", daemon=True)
        self._thread.start()
        try:
            self._server = asyncio.run_coroutine_threadsafe(
                asyncio.start_server(self._handle, host, port, limit=MAX_HEAD_BYTES), self._loop).result(10)
        except BaseException:
            self._stop_loop()
            raise
        self.port: int = self._server.sockets[0].getsockname()[1]

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None  # a handler runs as a task
        self._connections.add(task)
        upstream = None
        try:
            head = await reader.readuntil(b"\r\n\r\n")
            head, renamed = rename_offer(head)
            up_reader, upstream = await asyncio.open_connection(*self.target, limit=MAX_HEAD_BYTES)
            upstream.write(head)
            await upstream.drain()
            answer = await up_reader.readuntil(b"\r\n\r\n")
            writer.write(rename_answer(answer) if renamed else answer)
            await writer.drain()
            await asyncio.gather(_pipe(reader, upstream), _pipe(up_reader, writer))
        except (asyncio.IncompleteReadError, asyncio.LimitOverrunError, ConnectionError, OSError):
            pass  # a client that left, a head too large, the SDK server gone: this connection ends
        finally:
            for w in (writer, upstream):
                if w is not None:
                    w.close()
            self._connections.discard(task)

    def close(self) -> None:
        """Stop listening and end every relayed connection. Idempotent."""
        if self._loop.is_closed():
            return

        async def stop() -> None:
            self._server.close()
            for task in list(self._connections):
                task.cancel()
            await asyncio.gather(*self._connections, return_exceptions=True)

        try:
            asyncio.run_coroutine_threadsafe(stop(), self._loop).result(10)
        finally:
            self._stop_loop()

    def _stop_loop(self) -> None:
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(10)
        self._loop.close()
