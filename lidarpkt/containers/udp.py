"""Live UDP capture as a packet source: a receive thread that never waits for its consumer.

:class:`UdpSource` binds one socket per port (unicast, broadcast or multicast), asks the
kernel for a large receive buffer (32 MiB; ``SO_RCVBUFFORCE`` when the process may, else
``SO_RCVBUF``, capped by ``net.core.rmem_max``) and reports what it granted. A thread
reads datagrams with their kernel receive time (``SO_TIMESTAMPNS``), their destination
address (``IP_PKTINFO``) and the kernel's count of datagrams dropped on a full buffer
(``SO_RXQ_OVFL``), and hands them to the consumer through an unbounded C queue kept
bounded by a byte budget: when the consumer falls behind by more than ``queue_bytes``,
new datagrams are dropped *and counted* (``queue_overflow``), the socket is never left
unread.

It is a :class:`~lidarpkt.containers.protocol.PacketSource` like a capture file's reader:
:meth:`UdpSource.batches` yields same-stream batches as they arrive (until :meth:`~UdpSource.stop`),
:meth:`UdpSource.poll` the batches received so far, for a loop that has other things to do between
them (``record``, ``view``). ``open_packet_source("udp://[ADDRESS]:PORT[,PORT...]")`` opens one.

Errors: :class:`lidarpkt.errors.PortInUseError` when a port is already bound,
:class:`lidarpkt.errors.ReceiveError` for any other socket failure (with the reason).
"""

from __future__ import annotations

import errno
import os
import queue
import selectors
import socket
import struct
import threading
import time
from dataclasses import dataclass, field

from typing import Iterator, Sequence

import numpy as np

from lidarpkt.core.checks import PORT, Number
from lidarpkt.errors import PortInUseError, ReceiveError
from lidarpkt.core.packet import Endpoint, Packet, PacketBatch

# Linux socket options Python does not name
SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40)
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33)
IP_PKTINFO = getattr(socket, "IP_PKTINFO", 8)

MAX_DATAGRAM = 65535
#: the values the receiver's options take: the kernel's buffer size is a C int, halved as the kernel doubles it
RCVBUF_BYTES = Number(1 << 10, (1 << 31) - 1, whole=True, example=str(32 << 20))
QUEUE_BYTES = Number(1, whole=True, example=str(256 << 20))
READ_BATCH = 1024  # datagrams read from one socket before the thread looks at the stop flag again
FINAL_READ_S = 1.0  # on stop, how long the kernel's backlog is read at most
_ANC_SPACE = socket.CMSG_SPACE(16) + socket.CMSG_SPACE(4) + socket.CMSG_SPACE(12)

Item = tuple[int, Endpoint, Endpoint, bytes]  # (host receive time ns, src, dst, payload)


@dataclass
class CaptureStats:
    """Counters of a capture (read them from any thread; they only grow)."""

    received: int = 0
    received_bytes: int = 0
    queue_overflow: int = 0  # datagrams dropped because the writer fell behind
    kernel_drops: dict[int, int] = field(default_factory=dict)  # port -> SO_RXQ_OVFL count
    rcvbuf_requested: int = 0
    rcvbuf_granted: dict[int, int] = field(default_factory=dict)  # port -> bytes the kernel gave

    @property
    def kernel_dropped(self) -> int:
        return sum(self.kernel_drops.values())


class UdpSource:
    """Receives UDP datagrams on ``ports`` in a background thread.

    Args:
        ports: UDP ports to listen on (one socket each).
        bind: local address (``0.0.0.0`` = every interface, broadcast included).
        multicast: IPv4 group to join (then ``bind`` defaults to the group).
        interface: interface name or IPv4 address for the multicast membership.
        rcvbuf_bytes: kernel receive buffer to ask for (:data:`RCVBUF_BYTES`).
        queue_bytes: payload bytes allowed to wait for the consumer before drops are counted (:data:`QUEUE_BYTES`).

    Raises:
        UsageError: ``rcvbuf_bytes``, ``queue_bytes`` or a port out of range.
        PortInUseError, ReceiveError: from :meth:`open` (called by the constructor).
    """

    def __init__(self, ports: list[int], *, bind: str | None = None, multicast: str | None = None,
                 interface: str | None = None, rcvbuf_bytes: int = 32 << 20, queue_bytes: int = 256 << 20) -> None:
        if not ports:
            raise ReceiveError("no UDP port to listen on: give --port, the port the sensor sends to (2368 for most; "
                               "a sensor file given with --metadata names its own)")
        self.ports = list(dict.fromkeys(PORT.check(p, "ports") for p in ports))
        rcvbuf_bytes = RCVBUF_BYTES.check(rcvbuf_bytes, "rcvbuf_bytes")
        queue_bytes = QUEUE_BYTES.check(queue_bytes, "queue_bytes")
        self.multicast = multicast
        self.bind_address = bind or (multicast if multicast else "0.0.0.0")
        self.interface = interface
        self.queue_bytes = queue_bytes
        self.path = f"udp://{self.bind_address}:{','.join(map(str, self.ports))}"  # its name, as a file's path
        self.stats = CaptureStats(rcvbuf_requested=rcvbuf_bytes)
        self._queue: queue.SimpleQueue[Item] = queue.SimpleQueue()
        # drain() waits on this, not on SimpleQueue.get(timeout): CPython's SimpleQueue.get waits
        # until the next put when a signal handler runs past its deadline (the timeout goes negative,
        # which means "forever"), and a recorder told to stop by SIGTERM as the packets stop never
        # returned. Event.wait (threading's lock) treats a passed deadline as a timeout.
        self._queued = threading.Event()
        self._bytes_in = 0  # written by the receive thread only
        self._bytes_out = 0  # written by the consumer only
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._sockets: list[tuple[socket.socket, int]] = []
        self.error: BaseException | None = None
        self.open()

    # ----------------------------------------------------------------- sockets
    def open(self) -> None:
        try:
            for port in self.ports:
                self._sockets.append((self._open_socket(port), port))
        except BaseException:
            self.close()
            raise

    def _open_socket(self, port: int) -> socket.socket:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            if self.multicast:
                # several listeners of one group is the norm for multicast; unicast must stay exclusive
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._set_rcvbuf(sock, port)
            self.stats.kernel_drops[port] = 0  # keys fixed before the thread runs: safe to sum from another thread
            for opt, level in ((SO_TIMESTAMPNS, socket.SOL_SOCKET), (SO_RXQ_OVFL, socket.SOL_SOCKET),
                               (IP_PKTINFO, socket.IPPROTO_IP)):
                try:
                    sock.setsockopt(level, opt, 1)
                except OSError:  # not Linux: fall back to user-space times, no drop counter
                    pass
            try:
                sock.bind((self.bind_address, port))
            except OSError as exc:
                if exc.errno == errno.EADDRINUSE:
                    raise PortInUseError(
                        f"UDP port {port} on {self.bind_address} is already in use by another program "
                        "(another recorder or the sensor's driver?): stop it or choose another --port"
                    ) from None
                if exc.errno == errno.EADDRNOTAVAIL:
                    raise ReceiveError(f"cannot listen on {self.bind_address}:{port}: no local interface "
                                        "has that address (check --bind)") from None
                if exc.errno == errno.EACCES:
                    raise ReceiveError(f"not allowed to listen on UDP port {port} (ports below 1024 need "
                                        "privileges)") from None
                raise ReceiveError(f"cannot listen on {self.bind_address}:{port}: {exc.strerror or exc}") from None
            if self.multicast:
                self._join(sock, self.multicast)
            sock.setblocking(False)
            return sock
        except BaseException:
            sock.close()
            raise

    def _set_rcvbuf(self, sock: socket.socket, port: int) -> None:
        want = self.stats.rcvbuf_requested
        try:
            sock.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, want)  # past rmem_max, needs CAP_NET_ADMIN
        except OSError:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, want)
        # Linux reports twice the usable size (it counts its bookkeeping); report the usable part
        self.stats.rcvbuf_granted[port] = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) // 2

    def _join(self, sock: socket.socket, multicast: str) -> None:
        try:
            group = socket.inet_aton(multicast)
        except OSError:
            raise ReceiveError(f"--multicast {self.multicast!r} is not an IPv4 address") from None
        ifindex, ifaddr = 0, b"\x00\x00\x00\x00"
        if self.interface:
            try:
                ifaddr = socket.inet_aton(self.interface)
            except OSError:
                try:
                    ifindex = socket.if_nametoindex(self.interface)
                except OSError:
                    raise ReceiveError(f"--interface {self.interface!r} is neither an IPv4 address nor "
                                        "a network interface of this machine") from None
        try:
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, group + ifaddr + struct.pack("@i", ifindex))
        except OSError as exc:
            raise ReceiveError(f"cannot join multicast group {self.multicast}: {exc.strerror or exc}") from None

    # ----------------------------------------------------------------- thread
    def start(self) -> None:
        """Start the receive thread."""
        self._thread = threading.Thread(target=self._run, name="lidarpkt-udp-receive", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        sel = selectors.DefaultSelector()
        for sock, port in self._sockets:
            sel.register(sock, selectors.EVENT_READ, (sock, port))
        try:
            while not self._stop.is_set():
                for key, _ in sel.select(timeout=0.1):
                    self._read_all(*key.data)  # (socket, port)
                    self._queued.set()
            # what the kernel already holds is not lost on a clean stop; a sender that never pauses
            # cannot keep the recorder from stopping: the final read ends after FINAL_READ_S
            deadline = time.monotonic() + FINAL_READ_S
            for sock, port in self._sockets:
                while self._read_all(sock, port) and time.monotonic() < deadline:
                    pass
            self._queued.set()
            self._final_kernel_drops()
        except BaseException as exc:  # surfaced to the consumer by drain()
            self.error = exc
            self._queued.set()
        finally:
            sel.close()

    def _final_kernel_drops(self) -> None:
        """SO_RXQ_OVFL only rides on a datagram that is read: drops after the last one read (a burst
        at the end) would go unreported. The socket's drop counter is also in /proc/net/udp (the
        same sk_drops), so take it from there once no more datagrams will be read."""
        try:
            with open("/proc/net/udp") as fh:
                lines = fh.read().splitlines()[1:]
        except OSError:  # not Linux
            return
        drops = {}
        for line in lines:
            f = line.split()
            if len(f) >= 13 and f[9].isdigit() and f[-1].isdigit():
                drops[int(f[9])] = int(f[-1])
        for sock, port in self._sockets:
            try:
                inode = os.fstat(sock.fileno()).st_ino
            except OSError:
                continue
            if inode in drops:
                self.stats.kernel_drops[port] = max(self.stats.kernel_drops[port], drops[inode])

    def _read_all(self, sock: socket.socket, port: int) -> bool:
        """Read the datagrams waiting on ``sock``, at most READ_BATCH of them, and queue them (or count
        them as overflow). Returns True if more may be waiting: the bound lets the thread see a stop
        request under a flood."""
        stats = self.stats
        local = self.multicast or self.bind_address
        put = self._queue.put
        for _ in range(READ_BATCH):
            try:
                data, anc, _flags, addr = sock.recvmsg(MAX_DATAGRAM, _ANC_SPACE)
            except (BlockingIOError, InterruptedError):
                return False
            now = 0
            dst_addr = local
            for level, kind, value in anc:
                if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(value) >= 16:
                    sec, nsec = struct.unpack_from("@qq", value)
                    now = sec * 1_000_000_000 + nsec
                elif level == socket.SOL_SOCKET and kind == SO_RXQ_OVFL and len(value) >= 4:
                    stats.kernel_drops[port] = struct.unpack_from("@I", value)[0]
                elif level == socket.IPPROTO_IP and kind == IP_PKTINFO and len(value) >= 12:
                    dst_addr = socket.inet_ntoa(value[8:12])
            if not now:
                now = time.time_ns()
            stats.received += 1
            n = len(data)
            stats.received_bytes += n
            if self._bytes_in - self._bytes_out + n > self.queue_bytes:
                stats.queue_overflow += 1
                continue
            self._bytes_in += n
            put((now, Endpoint(addr[0], addr[1]), Endpoint(dst_addr, port), data))
        return True

    def drain(self, timeout: float = 0.1, max_items: int = 4096) -> list[Item]:
        """Datagrams received so far, oldest first (waits up to ``timeout`` s for the first).

        Raises :class:`ReceiveError` if the receive thread failed.
        """
        items: list[Item] = []
        if self._queue.empty() and timeout > 0:
            self._queued.wait(timeout)
        self._queued.clear()  # before taking: a datagram queued from here on sets it again
        try:
            while len(items) < max_items:
                items.append(self._queue.get_nowait())
        except queue.Empty:
            pass
        self._bytes_out += sum(len(it[3]) for it in items)
        if not items and self.error is not None:
            raise ReceiveError(f"the UDP receive thread failed: {self.error!r}")
        return items

    def poll(self, timeout: float = 0.1, max_items: int = 4096) -> list[PacketBatch]:
        """The datagrams received so far as same-stream batches (:func:`batch_from_packets`), waiting up to
        ``timeout`` s for the first. Raises :class:`~lidarpkt.errors.ReceiveError` if the receive thread failed."""
        return batch_from_packets(self.drain(timeout, max_items))

    def batches(self) -> Iterator[PacketBatch]:
        """Batches as they arrive (starting the receive thread if it is not running), until :meth:`stop`
        is called and everything received has been handed out."""
        if self._thread is None:
            self.start()
        while not self._stop.is_set():
            yield from self.poll(0.1)
        while items := self.drain(timeout=0.0, max_items=65536):
            yield from batch_from_packets(items)

    def packets(self) -> Iterator[Packet]:
        """The datagrams one by one, as :meth:`batches` delivers them."""
        for batch in self.batches():
            for t, row in zip(batch.timestamp_ns.tolist(), batch.payload):
                yield Packet(t, batch.src, batch.dst, row.tobytes())

    def recorded_sensor_file(self) -> str | None:
        """None: the network carries no metadata (an Ouster sensor serves it over HTTP: :mod:`lidarpkt.vendors.ouster.sensor_http`)."""
        return None

    @property
    def queued_bytes(self) -> int:
        return self._bytes_in - self._bytes_out

    def stop(self) -> None:
        """Stop the receive thread (what it queued stays drainable)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)

    def close(self) -> None:
        self.stop()
        for sock, _ in self._sockets:
            sock.close()
        self._sockets.clear()

    def __enter__(self) -> "UdpSource":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def batch_from_packets(items: Sequence[tuple[int, Endpoint | None, Endpoint | None, bytes]]) -> list[PacketBatch]:
    """Group ``(host_time_ns, src, dst, payload)`` items into same-stream, same-size batches,
    each in arrival order (streams in order of first appearance)."""
    groups: dict[tuple, list] = {}
    for t, src, dst, payload in items:
        groups.setdefault((src, dst, len(payload)), []).append((t, payload))
    out = []
    for (src, dst, size), rows in groups.items():
        times = np.fromiter((t for t, _ in rows), np.int64, len(rows))
        arr = np.frombuffer(b"".join(p for _, p in rows), np.uint8).reshape(len(rows), size)
        out.append(PacketBatch(src, dst, times, arr, np.zeros(len(rows), np.int64)))
    return out


def parse_udp_url(url: str) -> tuple[str | None, list[int]]:
    """``"udp://[ADDRESS]:PORT[,PORT...]"`` → (bind address or None for every interface, ports).

    Raises :class:`~lidarpkt.errors.UsageError` naming the URL."""
    from lidarpkt.errors import UsageError

    rest = url[len("udp://"):] if url.startswith("udp://") else url
    host, sep, ports = rest.rpartition(":")
    try:
        numbers = [int(p) for p in ports.split(",")] if sep else []
    except ValueError:
        numbers = []
    if not numbers or not all(0 < p < 65536 for p in numbers):
        raise UsageError(f"{url}: expected udp://[ADDRESS]:PORT[,PORT...], e.g. udp://:2368,8308")
    return (host.strip("[]") or None), numbers
