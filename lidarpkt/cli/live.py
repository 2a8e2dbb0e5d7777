"""The flags of the live verbs: the receive path (``record``, ``view`` without a capture) and the Foxglove
server (``view``, ``record --view``), with what they become for the library."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from . import args as cliargs

__all__ = ["add_receive_arguments", "add_ws_argument", "live_sensors", "receive_options", "start_view"]


def add_receive_arguments(parser: argparse.ArgumentParser, metadata_help: str) -> None:
    """The flags of the live receive path, shared by ``record`` and ``view``."""
    parser.add_argument("--port", type=cliargs.port_type("--port"), action="append", metavar="PORT",
                        help="UDP port to listen on; repeat for several (default with --metadata/--sensor: the ports "
                             "its sensor file names; `lidarpkt info` shows a capture's ports)")
    parser.add_argument("--bind", metavar="ADDR", help="local address to listen on (default: all, broadcast included)")
    parser.add_argument("--multicast", metavar="GROUP", help="join this IPv4 multicast group")
    parser.add_argument("--interface", metavar="IF", help="interface (name or address) for --multicast")
    cliargs.add_sensor_options(parser, metadata_help)
    parser.add_argument("--sensor", metavar="HOST[:PORT]",
                        help="Ouster sensor to fetch the metadata from (GET /api/v1/sensor/metadata, port 80)")
    parser.add_argument("--rcvbuf", type=cliargs.number("--rcvbuf"), default=32, metavar="MB", help="kernel receive buffer to ask for (32)")
    parser.add_argument("--queue", type=cliargs.number("--queue"), default=256, metavar="MB",
                        help="payload megabytes allowed to wait for the writer before drops are counted (256)")


def receive_options(args: argparse.Namespace) -> dict[str, Any]:
    """The receive flags as the keyword arguments of :class:`lidarpkt.containers.udp.UdpSource` (and of
    :func:`lidarpkt.recorder.record.record`), ``ports`` excepted."""
    return {"bind": args.bind, "multicast": args.multicast, "interface": args.interface,
            "rcvbuf_bytes": int(args.rcvbuf * (1 << 20)), "queue_bytes": int(args.queue * (1 << 20))}


def live_sensors(args: argparse.Namespace) -> tuple[list, dict[str, Any]]:
    """(the sensor files of ``--metadata`` and of ``--sensor`` (fetched over HTTP), loaded by the vendor
    registry (:func:`lidarpkt.vendors.registry.load_sensor_files`); the other sensor options as
    ``lidarpkt.open`` takes them: ``model``).

    Raises :class:`lidarpkt.errors.MetadataError` (a file), :class:`~lidarpkt.errors.SensorConnectionError`
    (a sensor that does not answer; the message names the host and the URL tried) and what
    :func:`lidarpkt.cli.args.sensor_options` raises.
    """
    from lidarpkt.vendors import registry

    options = cliargs.sensor_options(args)
    files = registry.load_sensor_files(options.pop("metadata", ()))
    if getattr(args, "sensor", None):
        from lidarpkt.vendors.ouster.sensor_http import fetch_metadata, parse_sensor

        host, port = parse_sensor(args.sensor)
        files += registry.load_sensor_files([fetch_metadata(host, port)])
    return files, options


def add_ws_argument(parser: argparse.ArgumentParser) -> None:
    """``--ws HOST:PORT``, shared by ``view`` and ``record --view``."""
    parser.add_argument("--ws", default="127.0.0.1:8765", metavar="HOST:PORT",
                        help="address of the Foxglove WebSocket server (127.0.0.1:8765; port 0 = any free port)")


def start_view(ws: str, *, verb: str = "view"):
    """A :class:`~lidarpkt.view.server.ViewServer` on ``--ws``; says where to connect (even with
    ``--quiet``: scripts wait for that line). Raises :class:`lidarpkt.view.server.ViewError`."""
    from lidarpkt.view.server import ViewServer, parse_ws

    host, port = parse_ws(ws)
    server = ViewServer(host, port)
    shown = "localhost" if host in ("127.0.0.1", "0.0.0.0", "::", "::1") else host
    print(f"lidarpkt {verb}: serving ws://{host}:{server.port} (Foxglove: Open connection → "
          f"ws://{shown}:{server.port})", file=sys.stderr, flush=True)
    return server
