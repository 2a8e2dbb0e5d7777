"""``lidarpkt replay``: send a capture's payloads over UDP at the original pace, a sensor simulator
(:func:`lidarpkt.recorder.replay.replay_capture`).

The lidar data stream goes to ``--to HOST:PORT``, the other streams to their original destination port on
HOST or where ``--port-map SRC:DST`` sends them. ``--http`` also serves the Ouster metadata endpoint, ``--ptc``
a Hesai Pandar's angle-correction CSV on its TCP PTC port, as the sensors do. Ctrl-C or SIGTERM stops it
with its summary; exit status 0, or 2 on an error.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time
from typing import Iterable

from lidarpkt.errors import RecorderError

from . import args as cliargs


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="capture to replay: pcap/pcapng, MCAP or ROS bag with raw packet topics")
    parser.add_argument("--to", required=True, metavar="HOST:PORT", help="where the lidar data stream goes")
    pace = parser.add_mutually_exclusive_group()
    pace.add_argument("--rate", type=cliargs.number("--rate"), default=1.0, metavar="F", help="speed factor (1 = real time)")
    pace.add_argument("--max", action="store_true", help="send as fast as possible")
    parser.add_argument("--loop", action="store_true", help="start again at the end, until interrupted")
    parser.add_argument("--port-map", action="append", default=[], metavar="SRC:DST",
                        help="send packets captured to port SRC to port DST instead (repeatable)")
    cliargs.add_sensor_options(parser, "a sensor's description file, to recognise its packets exactly (without it "
                                       "they are recognised as `lidarpkt info` does; MCAP files carry their own) and "
                                       "what --http/--ptc serve; repeat, one per sensor")
    parser.add_argument("--http", metavar="HOST:PORT",
                        help="also serve the (first) Ouster --metadata at GET /api/v1/sensor/metadata there, as the "
                             "sensor does (for record/view --sensor)")
    parser.add_argument("--ptc", metavar="HOST:PORT",
                        help="also answer Hesai PTC commands there (a Pandar's TCP port 9347), serving the Hesai "
                             "CSV of --calibration (or --metadata) for 'get calibration' (0x05), as the sensor does")
    parser.add_argument("--start-after-fetch", type=cliargs.number("--start-after-fetch"), metavar="S",
                        help="with --http or --ptc: send nothing until the metadata (calibration) has been fetched, "
                             "then start S seconds later (the client opens its sockets after fetching)")
    cliargs.add_quiet(parser, "no summary")


def parse_host_port(text: str) -> tuple[str, int]:
    """``--to HOST:PORT`` (``[v6]:PORT`` too) → (host, port). Raises :class:`RecorderError`."""
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not host:
        raise RecorderError(f"--to {text}: expected HOST:PORT; write e.g. --to 127.0.0.1:2368")
    if not 1 <= int(port) <= 65535:
        raise RecorderError(f"--to {text}: port {port} is out of range; a UDP port is in 1-65535")
    return host.strip("[]"), int(port)


def parse_port_map(items: Iterable[str]) -> dict[int, int]:
    """``--port-map 8308:9308 …`` → {8308: 9308}. Raises :class:`RecorderError`."""
    out = {}
    for item in items:
        a, sep, b = item.partition(":")
        if not sep or not a.isdigit() or not b.isdigit():
            raise RecorderError(f"--port-map {item}: expected SRC:DST port numbers; write e.g. --port-map 8308:9308")
        out[cliargs.port(a, "--port-map")] = cliargs.port(b, "--port-map")
    return out


def _sigterm_as_interrupt(signum, _frame) -> None:
    raise KeyboardInterrupt


def run(args: argparse.Namespace) -> int:
    from lidarpkt.recorder.replay import recorded_sensor_file, replay_capture
    from lidarpkt.vendors import registry

    host, port = parse_host_port(args.to)
    port_map = parse_port_map(args.port_map)
    cliargs.check_inputs([args.file])
    options = cliargs.sensor_options(args)
    given = list(options.get("metadata", ()))
    files = registry.load_sensor_files(given)
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
    ptc = _ptc_server(args, next((path for path, f in zip(given, files) if f.vendor == "hesai"), None))
    if args.start_after_fetch is not None and http is None and ptc is None:
        raise RecorderError("--start-after-fetch: it needs --http HOST:PORT or --ptc HOST:PORT; give both or neither")
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
        total = replay_capture(args.file, host, port, rate=None if args.max else args.rate, loop=args.loop,
                               port_map=port_map, metadata=files)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
        if http is not None:
            http.close()
        if ptc is not None:
            ptc.close()
    if not args.quiet:
        ports = ", ".join(f"{v} to port {k}" for k, v in sorted(total.per_port.items()))
        print(f"lidarpkt replay: {'interrupted; ' if total.interrupted else ''}sent {total.packets} packets "
              f"({total.bytes / 1e6:.1f} MB) to {host} in {total.seconds:.2f} s: {ports}", file=sys.stderr)
        if total.unknown:
            print(f"lidarpkt replay: note: {total.unknown} packets of no known stream went to their original "
                  "(or mapped) ports; if one is a lidar stream, give its sensor's --metadata to send it to --to",
                  file=sys.stderr)
    return 0


def _ptc_server(args: argparse.Namespace, calibration: str | None):
    """The PTC server of ``--ptc`` serving the calibration file (a Hesai CSV, checked first), or None."""
    flag = (getattr(args, "_sensor_flags", None) or {}).get(calibration, "--calibration")
    if calibration and not args.ptc:
        raise RecorderError(f"{flag} {calibration}: replay serves it over --ptc HOST:PORT; give both")
    if not args.ptc:
        return None
    if not calibration:
        raise RecorderError(f"--ptc {args.ptc}: there is no calibration to serve; give --calibration PandarXT32.csv")
    from lidarpkt.vendors.hesai.calibration import load_calibration
    from lidarpkt.vendors.hesai.ptc import GET_LIDAR_CALIBRATION, PTC_PORT, PtcServer

    load_calibration(calibration)  # a CalibrationError now, not in the client
    host, sep, port_text = args.ptc.rpartition(":")
    if not sep:
        host, port_text = args.ptc, str(PTC_PORT)
    if not host or not port_text.isdigit() or int(port_text) > 65535:
        raise RecorderError(f"--ptc {args.ptc!r}: expected HOST or HOST:PORT, e.g. 127.0.0.1:9347 (0: any free port)")
    host, port = host.strip("[]"), int(port_text)
    try:
        with open(calibration, "rb") as fh:
            server = PtcServer({GET_LIDAR_CALIBRATION: fh.read()}, host, port)
    except OSError as exc:
        raise RecorderError(f"--ptc {args.ptc}: cannot listen there ({exc.strerror or exc}); choose another port") from None
    # printed even with --quiet: scripts wait for it before starting the client
    print(f"lidarpkt replay: serving the Hesai calibration over PTC at {host}:{server.port}", file=sys.stderr, flush=True)
    return server
