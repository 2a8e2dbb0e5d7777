"""Replaying a capture: its payloads sent over UDP at the original pace (a sensor simulator).

The lidar data stream (VLP-16 data packets, Ouster lidar packets) goes to ``host:port``;
the other streams (VLP-16 position, Ouster IMU, anything else) go to their original
destination port on HOST, or where ``port_map`` sends them. Containers that keep
no ports (ROS bags, MCAP) send position packets to 8308 and IMU packets to 7503.

Pacing follows the capture's own receive times divided by ``rate``; ``rate=None`` sends as
fast as the socket takes them. The sender sleeps only when it is more than a millisecond
ahead, so at high rates packets leave in short bursts that keep the average pace exact.
"""

from __future__ import annotations

import itertools
import socket
import time
from dataclasses import dataclass, field
from typing import Iterable, Iterator

import numpy as np

from lidarpkt.errors import LidarpktError, RecorderError
from lidarpkt.core.packet import Packet

from lidarpkt.core import streams

DEFAULT_PORTS = {streams.VELODYNE_POSITION: 8308, streams.OUSTER_IMU: 7503}


@dataclass
class ReplayStats:
    """What a replay sent: packets, bytes, per destination port, and how long it took."""

    packets: int = 0
    bytes: int = 0
    seconds: float = 0.0
    per_port: dict[int, int] = field(default_factory=dict)  # destination port -> packets
    unknown: int = 0  # packets of no known stream (sent to their original or mapped port)
    interrupted: bool = False  # stopped by Ctrl-C or SIGTERM before the end


def read_capture(path: str) -> Iterator[Packet]:
    """Every packet of a capture in receive order (pcap streamed; bags/MCAP read whole, then
    ordered by host receive time)."""
    from lidarpkt.containers import open_packet_source
    from lidarpkt.containers.pcap_reader import PcapReader

    reader = open_packet_source(path)
    if isinstance(reader, PcapReader):
        yield from reader.packets()
        return
    batches = list(reader.batches())
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


def embedded_metadata(path: str, look_ahead: int = 64):
    """The Ouster metadata recorded in an MCAP file or bag (``/ouster/metadata``), parsed; ``None``
    for pcaps and files without it. Looks at the first ``look_ahead`` messages only."""
    from lidarpkt.vendors.ouster.metadata import load_metadata
    from lidarpkt.containers.protocol import embedded_ouster_metadata

    text = embedded_ouster_metadata(path, look_ahead)
    return load_metadata(text) if text else None


def replay(packets: Iterable[Packet], host: str, port: int, *, rate: float | None = 1.0,
           port_map: dict[int, int] | None = None, ouster_metadata=None,
           clock=time.monotonic, sleep=time.sleep) -> ReplayStats:
    """Send ``packets`` to ``host``: the lidar stream to ``port``, others to their (mapped) ports.

    ``ouster_metadata``: one :class:`~lidarpkt.vendors.ouster.metadata.OusterMetadata` or a list (one per
    sensor), to recognise non-legacy Ouster lidar packets. ``rate`` None = as fast as possible.
    Returns :class:`ReplayStats`. Raises
    :class:`RecorderError` if the address cannot be resolved or a send fails.
    """
    port_map = port_map or {}
    if isinstance(ouster_metadata, (list, tuple)):
        mds = list(ouster_metadata) or [None]
    else:
        mds = [ouster_metadata]
    try:
        family, _, _, _, addr = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)[0]
    except socket.gaierror as exc:
        raise RecorderError(f"--to {host}: cannot resolve the host ({exc.strerror or exc}); give an address such as 127.0.0.1") from None
    sock = socket.socket(family, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 8 << 20)
    dest_host = addr[0]
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
                kinds = [streams.classify_size(size, md) for md in mds]
                kind = next((k for k in kinds if k != streams.OTHER), streams.OTHER)
                if kind == streams.OTHER and mds == [None] and _ouster_lidar_by_header(p):
                    kind = streams.OUSTER_LIDAR  # as `lidarpkt info` recognises it without metadata
                if kind in (streams.VELODYNE_DATA, streams.OUSTER_LIDAR, streams.HESAI_DATA):
                    out_port = port
                else:
                    base = orig if orig is not None else DEFAULT_PORTS.get(kind, port)
                    out_port = port_map.get(base, base)
                kind_port[(size, orig)] = out_port
                if kind == streams.OTHER:
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
        sock.close()
    stats.seconds = clock() - start
    return stats


def _ouster_lidar_by_header(p: Packet) -> bool:
    """Whether one payload reads as an Ouster lidar packet the way ``lidarpkt info`` guesses without metadata."""
    from lidarpkt.vendors import ouster
    from lidarpkt.core.packet import PacketBatch

    payload = np.frombuffer(p.payload, np.uint8)[None, :]
    batch = PacketBatch(p.src, p.dst, np.array([p.timestamp_ns], np.int64), payload, np.zeros(1, np.int64))
    try:
        found = ouster.describe_stream(batch)
    except Exception:  # a guess: a payload it cannot read is no Ouster lidar packet
        return False
    return bool(found) and found.get("kind") == "Ouster lidar"


def replay_capture(path: str, host: str, port: int, *, rate: float | None = 1.0, loop: bool = False,
                   port_map: dict[int, int] | None = None, ouster_metadata=None) -> ReplayStats:
    """Send the packets of the capture ``path`` to ``host`` (:func:`replay`), once or, with ``loop``, again
    and again until interrupted (Ctrl-C, or SIGTERM raised as ``KeyboardInterrupt``); returns the
    totals of every round.

    Raises:
        lidarpkt.errors.LidarpktError: the capture holds no UDP packet; what :func:`replay` raises.
    """
    rounds = itertools.count() if loop else range(1)
    total = ReplayStats(per_port={})
    try:
        for _ in rounds:
            s = replay(read_capture(path), host, port, rate=rate, port_map=port_map, ouster_metadata=ouster_metadata)
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
    return total
