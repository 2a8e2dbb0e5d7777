"""``lidarpkt view [SOURCE]``: see a capture or a live sensor in Foxglove (Open connection → ws://localhost:8765).

With SOURCE (pcap/pcapng, MCAP, ROS bag) the frames of ``lidarpkt.open`` are published at the
capture's own pace (``--rate``, ``--loop``) once a client has subscribed, and the view keeps
serving after the end until interrupted. Without SOURCE it receives a live sensor with the
flags and receive path of ``lidarpkt record`` (``--port``, ``--bind``, ``--multicast``,
``--metadata``, ``--sensor``); decoding and publishing run off the receive path (see
:mod:`lidarpkt.pipeline.live`). Ctrl-C or SIGTERM stops it; exit status 0, or 2 on an error.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time

from lidarpkt.cli.console import count
from lidarpkt.containers.magic import CAPTURES_TEXT


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from . import args as cliargs
    from .live import add_receive_arguments, add_ws_argument

    parser.add_argument("source", nargs="?", metavar="SOURCE",
                        help=f"capture to show ({CAPTURES_TEXT}); without it, a live sensor")
    add_ws_argument(parser)
    parser.add_argument("--rerun", nargs="?", const="web", metavar="TARGET",
                        help="show it in Rerun's viewer instead of Foxglove: web (the default: Rerun's web viewer "
                             "served on http://localhost:9090, data on port 9876; web:PORT, web:0 = any free "
                             "ports), spawn (the native viewer), a rerun+http:// address, or FILE.rrd (needs "
                             "pip install 'lidarpkt[rerun]')")
    parser.add_argument("--color", choices=("range", "reflectivity"), default="range",
                        help="--rerun: colour the points by range (default) or reflectivity")
    parser.add_argument("--rate", type=cliargs.number("--rate"), default=1.0, metavar="F", help="SOURCE: speed factor (1 = real time)")
    parser.add_argument("--loop", action="store_true", help="SOURCE: start again at the end, until interrupted")
    add_receive_arguments(parser, "a sensor's description file (its metadata or calibration, of any vendor, told "
                                  "apart by its content); repeat, one per sensor")
    parser.add_argument("--duration", type=cliargs.number("--duration"), metavar="S", help="stop after S seconds")
    cliargs.add_quiet(parser, "no status lines")


def run(args: argparse.Namespace) -> int:
    from lidarpkt.errors import LidarpktError
    from lidarpkt.view.server import parse_ws

    from . import args as cliargs
    from .console import StopSignals

    if args.source is not None:
        cliargs.check_inputs([args.source])
    cliargs.sensor_options(args)  # the sensor files and model checked before any work
    if args.source is not None and (args.port or args.bind or args.multicast or args.sensor):
        raise LidarpktError(f"--port/--bind/--multicast/--sensor: not with SOURCE {args.source}; view either a "
                            "capture or a live sensor")
    parse_ws(args.ws)  # a wrong flag is an error before any work
    if args.source is not None and args.rate <= 0:
        raise LidarpktError(f"--rate {args.rate}: not a positive speed factor; give e.g. --rate 1 (real time)")
    with StopSignals() as stop:
        if args.source is not None:
            return _view_capture(args, stop.event)
        return _view_live(args, stop.event)


def _deadline(args) -> float:
    return time.monotonic() + args.duration if args.duration is not None else float("inf")


def _view_capture(args, stop: threading.Event) -> int:
    from lidarpkt.view.sources import play_capture

    from . import args as cliargs

    deadline = _deadline(args)
    readers = []
    counted = [0]
    servers = []  # started at the first frame: a capture that cannot be read is an error before any serving

    def new_round(reader) -> None:  # each round of --loop reads the capture again, counting from 0
        readers.append(reader)
        counted[0] = 0

    def wait_for_client(first) -> None:
        servers.append(_start(args))
        servers[0].sensor_name(first)  # advertise its channels, then wait until somebody looks
        if not args.quiet:
            print("lidarpkt view: waiting for a client to subscribe", file=sys.stderr, flush=True)
        while not servers[0].wait_for_subscriber(0.1) and not stop.is_set() and time.monotonic() < deadline:
            pass

    try:
        last_status = time.monotonic()
        frames = play_capture(args.source, rate=args.rate, loop=args.loop, stop=stop, on_reader=new_round,
                              before_first=wait_for_client, **cliargs.sensor_options(args))
        for frame in frames:
            server = servers[0]
            server.publish(frame)
            reader = readers[-1]
            server.count_packets(str(frame.sensor.source), reader.stats.packets - counted[0])
            counted[0] = reader.stats.packets
            if time.monotonic() - last_status >= 1.0:
                last_status = time.monotonic()
                _status_line(server.publish_status(), args.quiet)
            if time.monotonic() >= deadline:
                stop.set()
        if not servers:  # no frame at all (lidarpkt.open raised otherwise)
            from lidarpkt.errors import LidarpktError

            raise LidarpktError(f"{args.source}: no frame to show; check it with lidarpkt info")
        if not servers[0].serves_viewers:  # a .rrd file, a spawned or remote Rerun viewer: it has every frame
            return 0
        if not stop.is_set() and time.monotonic() < deadline and not args.quiet:
            print(f"lidarpkt view: end of {args.source} ({count(servers[0].frames_published, 'frame')}); still serving, "
                  "Ctrl-C to stop", file=sys.stderr, flush=True)
        while not stop.wait(1.0) and time.monotonic() < deadline:
            servers[0].publish_status()
    finally:
        for server in servers:
            server.close()
    return 0


def _view_live(args, stop: threading.Event) -> int:
    from lidarpkt.containers.udp import UdpSource
    from lidarpkt.pipeline.live import FrameTap, LiveDecoder
    from lidarpkt.view.tap import FrameDropper

    from .live import live_sensors, receive_options

    files, decoder_options = live_sensors(args)
    ports = args.port or [p for f in files for p in f.ports]
    capture = UdpSource(ports, **receive_options(args))
    server = tap = dropper = None
    try:
        server = _start(args)
        view = server

        def dropped(n: int) -> None:
            view.frames_dropped = n

        dropper = FrameDropper(server.publish, on_drop=dropped)
        tap = FrameTap(LiveDecoder(files, **decoder_options), [dropper], on_batch=lambda b: view.count_packets(str(b.src), len(b)))
        print(f"lidarpkt view: listening on {capture.bind_address} port(s) {', '.join(map(str, capture.ports))}",
              file=sys.stderr, flush=True)
        capture.start()
        deadline = _deadline(args)
        last_status = time.monotonic()
        while not stop.is_set() and time.monotonic() < deadline:
            tap.offer(capture.poll(timeout=0.05))
            if time.monotonic() - last_status >= 1.0:
                last_status = time.monotonic()
                _status_line(server.publish_status(), args.quiet)
        capture.stop()
        while batches := capture.poll(timeout=0.0, max_items=65536):
            tap.offer(batches)
    finally:
        capture.close()
        if tap is not None:
            tap.close()
        if dropper is not None:
            dropper.close()
        if server is not None:
            server.publish_status()
            server.close()
    _report_errors(tap, dropper)
    return 0


def _start(args):
    """The Foxglove server on ``--ws``, or with ``--rerun`` the Rerun view (:mod:`lidarpkt.view.rerun`)."""
    if getattr(args, "rerun", None):
        from lidarpkt.view.rerun import start_rerun

        return start_rerun(args.rerun, color=args.color)
    from .live import start_view

    return start_view(args.ws)


def _report_errors(tap, dropper) -> None:
    for what, err in (("decoding", tap.error if tap else None), ("publishing", dropper.error if dropper else None)):
        if err is not None:
            print(f"lidarpkt view: warning: {what} failed for some frames: {err}", file=sys.stderr)


def _status_line(statuses: list[dict], quiet: bool) -> None:
    if quiet:
        return
    for s in statuses:
        print(f"lidarpkt view: {s['sensor']}: {s['packets_per_s']:.0f} pkt/s, {s['frames_per_s']:.1f} frames/s, "
              f"lost {s['lost_packets']}, {count(s['frames'], 'frame')}, {s['view_frames_dropped']} dropped for the view",
              file=sys.stderr, flush=True)
