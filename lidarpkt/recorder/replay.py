"""Replaying a capture: its payloads sent over UDP at the original pace (a sensor simulator).

The lidar data streams (the streams frames are made of: the vendor registry's classifier says which)
go to ``host:port``; the other streams (auxiliary ones, anything else) go to their original
destination port on HOST, or where ``port_map`` sends them. Containers that keep no ports (ROS bags,
MCAP) send each stream to its vendor's port (the factory one, or the one its sensor file names), each
stream kind its own where one message carries two (:func:`read_capture`).

Pacing follows the capture's own receive times divided by ``rate``; ``rate=None`` sends as
fast as the socket takes them. The sender sleeps only when it is more than a millisecond
ahead, so at high rates packets leave in short bursts that keep the average pace exact.
"""

from __future__ import annotations

import itertools
import socket
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Iterable, Iterator

import numpy as np

from lidarpkt.core.packet import Packet, PacketBatch
from lidarpkt.errors import LidarpktError, RecorderError

if TYPE_CHECKING:
    from lidarpkt.core.vendor import Match


@dataclass
class ReplayStats:
    """What a replay sent: packets, bytes, per destination port, and how long it took."""

    packets: int = 0
    bytes: int = 0
    seconds: float = 0.0
    per_port: dict[int, int] = field(default_factory=dict)  # destination port -> packets
    unknown: int = 0  # packets of no known stream (sent to their original or mapped port)
    interrupted: bool = False  # stopped by Ctrl-C or SIGTERM before the end


def read_capture(path: str, metadata=None) -> Iterator[Packet]:
    """Every packet of a capture in receive order (pcap streamed; bags/MCAP read whole, then
    ordered by host receive time).

    A bag's or an MCAP's packets, which kept no addresses, come from and to their vendor's factory
    endpoints, each stream kind its own (:func:`lidarpkt.vendors.registry.factory_addressed`; the stream of
    a payload size told by its first batch, with the sensor files ``metadata``, as :func:`replay` takes
    them): a message carrying two kinds of packets sends each to its port. Packets of no vendor keep none.
    """
    from lidarpkt.containers.pcap_reader import PcapReader
    from lidarpkt.vendors import registry

    reader = registry.open_packets(path)
    if isinstance(reader, PcapReader):
        yield from reader.packets()
        return
    setup = registry.setup(registry.load_sensor_files(metadata))
    matched: dict[int, Match | None] = {}  # the stream of each payload size
    batches = []
    for batch in reader.batches():
        if len(batch) and (batch.src is None or batch.dst is None):
            size = batch.payload_size
            if size not in matched:
                matched[size] = registry.classify(batch, setup)
            match = matched[size]
            if match is not None:
                batches.extend(registry.factory_addressed(batch, match))
                continue
        batches.append(batch)
    if not batches:
        return
    # a bag stores a rotation's packets in one message written after its last packet: host times,
    # not file order, give the interleaving of the streams as they were received
    order = np.lexsort((np.concatenate([b.index for b in batches]), np.concatenate([b.timestamp_ns for b in batches])))
    which = np.concatenate([np.full(len(b), i) for i, b in enumerate(batches)])
    row = np.concatenate([np.arange(len(b)) for b in batches])
    for k in order.tolist():
        b = batches[which[k]]
        r = row[k]
        yield Packet(int(b.timestamp_ns[r]), b.src, b.dst, b.payload[r].tobytes())


def recorded_sensor_file(path: str, look_ahead: int = 64):
    """The sensor file recorded in an MCAP file or bag (a driver's), loaded (a
    :class:`~lidarpkt.vendors.registry.SensorFile`); ``None`` for pcaps and files without one. Looks at the
    first ``look_ahead`` messages only."""
    from lidarpkt.containers import protocol
    from lidarpkt.vendors import registry

    text = protocol.recorded_sensor_file(path, registry.bag_messages(), look_ahead)
    return registry.load_sensor_files([text])[0] if text else None


def sender(host: str, port: int) -> tuple[socket.socket, str]:
    """The UDP socket packets are sent from (one source address for every round of a replay: receivers see
    one sensor) and the address of ``host``. Raises :class:`RecorderError` if ``host`` cannot be resolved."""
    try:
        family, _, _, _, addr = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)[0]
    except socket.gaierror as exc:
        raise RecorderError(f"--to {host}: cannot resolve the host ({exc.strerror or exc}); give an address such as 127.0.0.1") from None
    sock = socket.socket(family, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 8 << 20)
    return sock, str(addr[0])


def replay(packets: Iterable[Packet], host: str, port: int, *, rate: float | None = 1.0,
           port_map: dict[int, int] | None = None, metadata=None,
           clock=time.monotonic, sleep=time.sleep, sock: socket.socket | None = None) -> ReplayStats:
    """Send ``packets`` to ``host``: the lidar streams to ``port``, others to their (mapped) ports.

    ``metadata``: the sensor files, as ``lidarpkt.open`` takes them, to recognise packets that are
    recognised only with them (an Ouster profile). ``rate`` None = as fast as possible. ``sock``: the socket
    to send from (:func:`sender`; kept open), else one of its own, closed at the end.
    Returns :class:`ReplayStats`. Raises
    :class:`RecorderError` if the address cannot be resolved or a send fails.
    """
    from lidarpkt.vendors import registry

    port_map = port_map or {}
    setup = registry.setup(registry.load_sensor_files(metadata))
    own = sock is None
    if own:
        sock, dest_host = sender(host, port)
    else:
        dest_host = str(socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)[0][4][0])
    assert sock is not None
    stats = ReplayStats(per_port={})
    kind_port: dict[tuple[int, int | None], int] = {}
    unknown_keys: set[tuple[int, int | None]] = set()
    start = clock()
    t0 = None
    try:
        for p in packets:
            size = len(p.payload)
            orig = p.dst.port if p.dst is not None else None
            out_port = kind_port.get((size, orig))
            if out_port is None:
                match = registry.classify(_one_packet(p), setup)  # as `lidarpkt info` recognises it
                if match is not None and match.lidar:
                    out_port = port
                else:
                    if orig is not None:
                        base = orig
                    else:
                        base = registry.vendor(match.vendor).endpoints(match)[1].port if match is not None else port
                    out_port = port_map.get(base, base)
                kind_port[(size, orig)] = out_port
                if match is None:
                    unknown_keys.add((size, orig))
            if (size, orig) in unknown_keys:
                stats.unknown += 1
            if rate is not None:
                if t0 is None:
                    t0 = p.timestamp_ns
                ahead = (p.timestamp_ns - t0) / 1e9 / rate - (clock() - start)
                if ahead > 0.001:
                    sleep(ahead)
            try:
                sock.sendto(p.payload, (dest_host, out_port))
            except OSError as exc:
                raise RecorderError(f"--to {dest_host}:{out_port}: sending failed ({exc.strerror or exc}); check the address and the network") from None
            stats.packets += 1
            stats.bytes += size
            stats.per_port[out_port] = stats.per_port.get(out_port, 0) + 1
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: what was sent is still counted
        stats.interrupted = True
    finally:
        if own:
            sock.close()
    stats.seconds = clock() - start
    return stats


def _one_packet(p: Packet) -> PacketBatch:
    payload = np.frombuffer(p.payload, np.uint8)[None, :]
    return PacketBatch(p.src, p.dst, np.array([p.timestamp_ns], np.int64), payload, np.zeros(1, np.int64))


def replay_capture(path: str, host: str, port: int, *, rate: float | None = 1.0, loop: bool = False,
                   port_map: dict[int, int] | None = None, metadata=None) -> ReplayStats:
    """Send the packets of the capture ``path`` to ``host`` (:func:`replay`), once or, with ``loop``, again
    and again until interrupted (Ctrl-C, or SIGTERM raised as ``KeyboardInterrupt``); returns the
    totals of every round. ``metadata``: the sensor files, as :func:`replay` takes them.

    Raises:
        lidarpkt.errors.LidarpktError: the capture holds no UDP packet; what :func:`replay` raises.
    """
    rounds = itertools.count() if loop else range(1)
    total = ReplayStats(per_port={})
    sock, _ = sender(host, port)  # every round from one source address: one sensor to the receivers
    try:
        for _ in rounds:
            s = replay(read_capture(path, metadata), host, port, rate=rate, port_map=port_map, metadata=metadata,
                       sock=sock)
            total.packets += s.packets
            total.bytes += s.bytes
            total.seconds += s.seconds
            total.unknown += s.unknown
            for k, v in s.per_port.items():
                total.per_port[k] = total.per_port.get(k, 0) + v
            if s.interrupted:
                total.interrupted = True
                break
            if s.packets == 0:
                raise LidarpktError(f"{path}: holds no UDP packets to replay; check it with lidarpkt info")
    except KeyboardInterrupt:  # between two rounds (opening the capture again): interrupted all the same
        total.interrupted = True
    finally:
        sock.close()
    return total
