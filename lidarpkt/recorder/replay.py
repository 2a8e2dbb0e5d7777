"""``lidarpkt replay``: send a capture's payloads over UDP at the original pace (a sensor simulator).

The lidar data streams (the streams frames are made of: the vendor registry's classifier says which)
go to ``--to HOST:PORT``; the other streams (position, IMU, anything else) go to their original
destination port on HOST, or where ``--port-map SRC:DST`` sends them. Containers that keep
no ports (ROS bags, MCAP) send each stream to its vendor's factory port (a VLP-16's position packets to
8308, an Ouster's IMU packets to 7503, or the port its sensor file names).

Pacing follows the capture's own receive times divided by ``--rate``; ``--max`` sends as
fast as the socket takes them. The sender sleeps only when it is more than a millisecond
ahead, so at high rates packets leave in short bursts that keep the average pace exact.
"""

from __future__ import annotations

import argparse
import itertools
import json
import socket
import sys
import time
from dataclasses import dataclass, field
from typing import Iterable, Iterator

import numpy as np

from lidarpkt.core.packet import Packet, PacketBatch
from lidarpkt.errors import LidarpktError, RecorderError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from lidarpkt.cli import args as cliargs

    parser.add_argument("file", help="capture to replay: pcap/pcapng, MCAP or ROS bag with raw packet topics")
    parser.add_argument("--to", required=True, metavar="HOST:PORT", help="where the lidar data stream goes")
    pace = parser.add_mutually_exclusive_group()
    pace.add_argument("--rate", type=float, default=1.0, metavar="F", help="speed factor (1 = real time)")
    pace.add_argument("--max", action="store_true", help="send as fast as possible")
    parser.add_argument("--loop", action="store_true", help="start again at the end, until interrupted")
    parser.add_argument("--port-map", action="append", default=[], metavar="SRC:DST",
                        help="send packets captured to port SRC to port DST instead (repeatable)")
    cliargs.add_metadata(parser, "a sensor's file, to recognise its packets exactly (without it they are "
                                 "recognised as `lidarpkt info` does; MCAP files carry their own); repeat, one per "
                                 "sensor")
    parser.add_argument("--http", metavar="HOST:PORT",
                        help="also serve the (first) --metadata at GET /api/v1/sensor/metadata there, as the "
                             "sensor does (for record/view --sensor)")
    parser.add_argument("--ptc", metavar="HOST:PORT",
                        help="also answer Hesai PTC commands there (a Pandar's TCP port 9347), serving --calibration "
                             "for 'get calibration' (0x05), as the sensor does")
    parser.add_argument("--calibration", metavar="FILE", help="the Hesai angle-correction CSV --ptc serves")
    parser.add_argument("--start-after-fetch", type=float, metavar="S",
                        help="with --http or --ptc: send nothing until the metadata (calibration) has been fetched, "
                             "then start S seconds later (the client opens its sockets after fetching)")
    cliargs.add_quiet(parser, "no summary")


@dataclass
class ReplayStats:
    """What a replay sent: packets, bytes, per destination port, and how long it took."""

    packets: int = 0
    bytes: int = 0
    seconds: float = 0.0
    per_port: dict[int, int] = field(default_factory=dict)  # destination port -> packets
    unknown: int = 0  # packets of no known stream (sent to their original or mapped port)
    interrupted: bool = False  # stopped by Ctrl-C or SIGTERM before the end


def parse_host_port(text: str) -> tuple[str, int]:
    """``"HOST:PORT"`` (``[v6]:PORT`` too) → (host, port). Raises :class:`RecorderError`."""
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not host:
        raise RecorderError(f"--to {text}: expected HOST:PORT; write e.g. --to 127.0.0.1:2368")
    if not 1 <= int(port) <= 65535:
        raise RecorderError(f"--to {text}: port {port} is out of range; a UDP port is in 1-65535")
    return host.strip("[]"), int(port)


def parse_port_map(items: Iterable[str]) -> dict[int, int]:
    """``["8308:9308", …]`` → {8308: 9308}. Raises :class:`RecorderError`."""
    out = {}
    for item in items:
        a, sep, b = item.partition(":")
        if not sep or not a.isdigit() or not b.isdigit():
            raise RecorderError(f"--port-map {item}: expected SRC:DST port numbers; write e.g. --port-map 8308:9308")
        from lidarpkt.cli.args import port as port_number

        out[port_number(a, "--port-map")] = port_number(b, "--port-map")
    return out


def read_capture(path: str) -> Iterator[Packet]:
    """Every packet of a capture in receive order (pcap streamed; bags/MCAP read whole, then
    ordered by host receive time)."""
    from lidarpkt.containers.pcap_reader import PcapReader
    from lidarpkt.vendors.registry import open_packets

    reader = open_packets(path)
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


def recorded_sensor_file(path: str, look_ahead: int = 64):
    """The sensor file recorded in an MCAP file or bag (a driver's), loaded (a
    :class:`~lidarpkt.vendors.registry.SensorFile`); ``None`` for pcaps and files without one. Looks at the
    first ``look_ahead`` messages only."""
    from lidarpkt.containers import protocol
    from lidarpkt.vendors import registry

    text = protocol.recorded_sensor_file(path, registry.bag_messages(), look_ahead)
    return registry.load_sensor_files([text])[0] if text else None


def replay(packets: Iterable[Packet], host: str, port: int, *, rate: float | None = 1.0,
           port_map: dict[int, int] | None = None, metadata=None,
           clock=time.monotonic, sleep=time.sleep) -> ReplayStats:
    """Send ``packets`` to ``host``: the lidar streams to ``port``, others to their (mapped) ports.

    ``metadata``: the sensor files, as ``lidarpkt.open`` takes them, to recognise packets that are
    recognised only with them (an Ouster profile). ``rate`` None = as fast as possible.
    Returns :class:`ReplayStats`. Raises
    :class:`RecorderError` if the address cannot be resolved or a send fails.
    """
    from lidarpkt.vendors import registry

    port_map = port_map or {}
    setup = registry.setup(registry.load_sensor_files(metadata))
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
        sock.close()
    stats.seconds = clock() - start
    return stats


def _one_packet(p: Packet) -> PacketBatch:
    payload = np.frombuffer(p.payload, np.uint8)[None, :]
    return PacketBatch(p.src, p.dst, np.array([p.timestamp_ns], np.int64), payload, np.zeros(1, np.int64))


def _sigterm_as_interrupt(signum, _frame) -> None:
    raise KeyboardInterrupt


def run(args: argparse.Namespace) -> int:
    from lidarpkt.cli import args as cliargs

    host, port = parse_host_port(args.to)
    port_map = parse_port_map(args.port_map)
    cliargs.check_inputs([args.file])
    cliargs.check_inputs(args.metadata or (), "--metadata")
    from lidarpkt.vendors import registry

    files = registry.load_sensor_files(args.metadata or [])
    if not files:
        files = [f] if (f := recorded_sensor_file(args.file)) is not None else []
    mds = [f.loaded for f in files if f.vendor == "ouster"]  # what --http serves
    if not args.max and not args.rate > 0:
        raise RecorderError(f"--rate {args.rate}: not a positive speed factor; give e.g. --rate 1 (real time) or --max")
    http = None
    if args.http:
        if not mds:
            raise RecorderError(f"--http {args.http}: there is no Ouster metadata to serve; give --metadata M.json")
        from lidarpkt.vendors.ouster.sensor_http import MetadataHttpServer, parse_sensor

        http_host, http_port = parse_sensor(args.http, "--http")
        http = MetadataHttpServer(json.dumps(mds[0].raw), http_host, http_port)
        # printed even with --quiet: scripts wait for it before starting the client
        print(f"lidarpkt replay: serving the sensor metadata at http://{http_host}:{http.port}"
              "/api/v1/sensor/metadata", file=sys.stderr, flush=True)
    ptc = _ptc_server(args)
    if args.start_after_fetch is not None and http is None and ptc is None:
        raise RecorderError("--start-after-fetch: it needs --http HOST:PORT or --ptc HOST:PORT; give both or neither")
    import signal
    import threading

    previous = None  # SIGTERM stops the replay like Ctrl-C: the summary is still printed
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGTERM, _sigterm_as_interrupt)
    try:
        if args.start_after_fetch is not None:
            try:
                (http.fetched if http is not None else ptc.served).wait()
            except KeyboardInterrupt:
                return 0
            time.sleep(args.start_after_fetch)
        return _replay_rounds(args, host, port, port_map, files)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
        if http is not None:
            http.close()
        if ptc is not None:
            ptc.close()


def _ptc_server(args):
    """The PTC server of ``--ptc`` serving ``--calibration`` (a Hesai CSV, checked first), or None."""
    if args.calibration and not args.ptc:
        raise RecorderError(f"--calibration {args.calibration}: replay serves it over --ptc HOST:PORT; give both")
    if not args.ptc:
        return None
    if not args.calibration:
        raise RecorderError(f"--ptc {args.ptc}: there is no calibration to serve; give --calibration PandarXT32.csv")
    from lidarpkt.cli import args as cliargs
    from lidarpkt.vendors.hesai.calibration import load_calibration
    from lidarpkt.vendors.hesai.ptc import GET_LIDAR_CALIBRATION, PTC_PORT, PtcServer

    cliargs.check_inputs([args.calibration], "--calibration")
    load_calibration(args.calibration)  # a CalibrationError now, not in the client
    host, sep, port_text = args.ptc.rpartition(":")
    if not sep:
        host, port_text = args.ptc, str(PTC_PORT)
    if not host or not port_text.isdigit() or int(port_text) > 65535:
        raise RecorderError(f"--ptc {args.ptc!r}: expected HOST or HOST:PORT, e.g. 127.0.0.1:9347 (0: any free port)")
    host, port = host.strip("[]"), int(port_text)
    try:
        server = PtcServer({GET_LIDAR_CALIBRATION: open(args.calibration, "rb").read()}, host, port)
    except OSError as exc:
        raise RecorderError(f"--ptc {args.ptc}: cannot listen there ({exc.strerror or exc}); choose another port") from None
    # printed even with --quiet: scripts wait for it before starting the client
    print(f"lidarpkt replay: serving the Hesai calibration over PTC at {host}:{server.port}", file=sys.stderr, flush=True)
    return server


def _replay_rounds(args, host: str, port: int, port_map: dict[int, int], files: list) -> int:
    rate = None if args.max else args.rate
    rounds = itertools.count() if args.loop else range(1)
    total = ReplayStats(per_port={})
    try:
        for _ in rounds:
            s = replay(read_capture(args.file), host, port, rate=rate, port_map=port_map, metadata=files)
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
                raise LidarpktError(f"{args.file}: holds no UDP packets to replay; check it with lidarpkt info")
    except KeyboardInterrupt:  # between two rounds (opening the capture again): interrupted all the same
        total.interrupted = True
    if not args.quiet:
        ports = ", ".join(f"{v} to port {k}" for k, v in sorted(total.per_port.items()))
        print(f"lidarpkt replay: {'interrupted; ' if total.interrupted else ''}sent {total.packets} packets ({total.bytes / 1e6:.1f} MB) to {host} in "
              f"{total.seconds:.2f} s: {ports}", file=sys.stderr)
        if total.unknown:
            print(f"lidarpkt replay: note: {total.unknown} packets of no known stream went to their original "
                  "(or mapped) ports; if one is a lidar stream, give its sensor's --metadata to send it to --to",
                  file=sys.stderr)
    return 0
