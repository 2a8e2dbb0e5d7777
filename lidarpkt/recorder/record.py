"""``lidarpkt record``: capture a live sensor (and a serial GPS) to MCAP without losing a packet.

The live packet source (:mod:`lidarpkt.containers.udp`) reads the sockets in its thread; this loop polls it,
writes the packets through :class:`lidarpkt.writers.mcap.packets.PacketSink`, counts loss, prints a status
line each second and a summary at the end. It stops on Ctrl-C, SIGTERM, ``--duration`` or
``--frames`` and closes the file with its summary and index. Killed outright, it leaves a
file readable up to its last complete chunk (``--chunk-seconds``, 0.5 s by default).

Exit status: 0 = recorded, nothing lost; 1 = recorded but packets were lost (the summary
says where); 2 = error (port in use, disk full, bad option …).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from lidarpkt.errors import LidarpktError, RecorderError

from lidarpkt.containers import rosmsgs

from lidarpkt.writers.mcap import schemas
from lidarpkt.writers.mcap.writer import McapWriter

from lidarpkt.containers.udp import UdpSource
from lidarpkt.writers.mcap.packets import PacketSink


def add_receive_arguments(parser: argparse.ArgumentParser) -> None:
    """The flags of the live receive path, shared by ``record`` and ``view``."""
    from lidarpkt.cli import args as cliargs

    parser.add_argument("--port", type=cliargs.port_type("--port"), action="append", metavar="PORT",
                        help="UDP port to listen on; repeat for several (VLP-16: 2368 data, 8308 position; "
                             "Ouster: 7502 lidar, 7503 IMU; default with --metadata/--sensor: the ports it names)")
    parser.add_argument("--bind", metavar="ADDR", help="local address to listen on (default: all, broadcast included)")
    parser.add_argument("--multicast", metavar="GROUP", help="join this IPv4 multicast group")
    parser.add_argument("--interface", metavar="IF", help="interface (name or address) for --multicast")
    cliargs.add_metadata(parser, "Ouster sensor metadata JSON (record: stored in the file); repeat, one per sensor")
    parser.add_argument("--sensor", metavar="HOST[:PORT]",
                        help="Ouster sensor to fetch the metadata from (GET /api/v1/sensor/metadata, port 80)")
    parser.add_argument("--rcvbuf", type=float, default=32, metavar="MB", help="kernel receive buffer to ask for (32)")
    parser.add_argument("--queue", type=float, default=256, metavar="MB",
                        help="payload megabytes allowed to wait for the writer before drops are counted (256)")


def load_sensor_files(args: argparse.Namespace) -> list:
    """The sensor files of ``--metadata`` (each, as :func:`lidarpkt.vendors.registry.load_sensor_files` loads
    them) and of ``--sensor`` (fetched over HTTP).

    Raises :class:`lidarpkt.errors.MetadataError` (a file) or :class:`~lidarpkt.errors.SensorConnectionError` (a sensor
    that does not answer; the message names the host and the URL tried).
    """
    from lidarpkt.vendors import registry

    files = registry.load_sensor_files(args.metadata or [])
    if getattr(args, "sensor", None):
        from lidarpkt.vendors.ouster.sensor_http import fetch_metadata, parse_sensor

        host, port = parse_sensor(args.sensor)
        files += registry.load_sensor_files([fetch_metadata(host, port)])
    return files


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from lidarpkt.cli import args as cliargs
    from lidarpkt.view.server import add_ws_argument

    add_receive_arguments(parser)
    stop = parser.add_mutually_exclusive_group()
    stop.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    stop.add_argument("--frames", type=int, metavar="N", help="stop after N complete rotations")
    cliargs.add_output(parser, (".mcap",), help="MCAP file to write")
    parser.add_argument("--rotate-size", type=float, metavar="MB",
                        help="start a new file every MB megabytes (files are then OUT_0000.mcap, OUT_0001.mcap ...)")
    parser.add_argument("--rotate-time", type=float, metavar="S", help="start a new file every S seconds (as above)")
    parser.add_argument("--chunk-seconds", type=float, default=0.5, metavar="S",
                        help="close an MCAP chunk every S seconds: at most that much is lost if killed (0.5)")
    parser.add_argument("--gps", metavar="PORT", help="serial port of an NMEA GPS (e.g. /dev/ttyUSB0)")
    parser.add_argument("--baud", type=int, default=9600, help="GPS baud rate (9600)")
    parser.add_argument("--points", action="store_true",
                        help="also write PointCloud2 frames (decoded off the receive path) to the MCAP")
    parser.add_argument("--view", action="store_true",
                        help="serve a Foxglove live view while recording (see --ws); it never costs a packet")
    add_ws_argument(parser)
    from lidarpkt.cli.decode import add_frame_arguments

    add_frame_arguments(parser)  # with --points: each sensor's frame id and its mount on /tf_static
    cliargs.add_json(parser, "the summary as one JSON document", file_flag="--report")  # -o is the MCAP
    cliargs.add_quiet(parser, "no status line and no summary")


def run(args: argparse.Namespace) -> int:
    from lidarpkt.cli import args as cliargs

    cliargs.check_inputs(args.metadata or (), "--metadata")
    cliargs.check_output(args.output, "-o", (".mcap",), keep_on_error=True)  # a recording is kept up to a failure
    cliargs.check_json(args)
    if args.gps:
        cliargs.check_inputs([args.gps], "--gps")
    sensors = None
    if args.frame_id or args.base_frame or args.mount:
        if not args.points:
            raise RecorderError("--frame-id/--base-frame/--mount: they name the frames of the point clouds; "
                                "add --points")
        from lidarpkt.writers.mcap.frames import SensorFrames

        from lidarpkt.cli.decode import frame_options

        sensors = SensorFrames(**frame_options(args))  # checked before anything is opened
    files = load_sensor_files(args)
    # a second Ctrl-C: stop now (the file still gets its index)
    stop = cliargs.StopSignals(second_interrupt_raises=True).install()
    capture = gps = writer = frames = None
    try:
        ports = args.port or [p for f in files for p in f.ports]
        capture = UdpSource(ports, bind=args.bind, multicast=args.multicast, interface=args.interface,
                             rcvbuf_bytes=int(args.rcvbuf * (1 << 20)), queue_bytes=int(args.queue * (1 << 20)))
        if args.gps:  # opened before the file, so that a wrong port leaves no empty recording
            from .gps import GpsReader

            gps = GpsReader(args.gps, args.baud)
            gps.start()
        if args.points or args.view:  # before the file: a view that cannot serve leaves no empty recording
            from .frames import LiveFrames

            frames = LiveFrames(files, points=args.points, ws=args.ws if args.view else None, sensors=sensors)
        writer = McapWriter(args.output, chunk_seconds=args.chunk_seconds,
                            rotate_bytes=int(args.rotate_size * 1e6) if args.rotate_size else None,
                            rotate_seconds=args.rotate_time)
        sink = PacketSink(writer, metadata=files, log_time_ns=time.time_ns())
        granted = ", ".join(f"{p}: {b / (1 << 20):.1f} MiB" for p, b in capture.stats.rcvbuf_granted.items())
        # printed even with --quiet: it says the recorder is ready (scripts wait for it)
        print(f"lidarpkt record: listening on {capture.bind_address} port(s) "
              f"{', '.join(map(str, capture.ports))}; receive buffer asked "
              f"{capture.stats.rcvbuf_requested / (1 << 20):.0f} MiB, granted {granted}; writing {args.output}",
              file=sys.stderr, flush=True)
        capture.start()
        return _loop(args, capture, writer, sink, gps, stop, frames)
    finally:
        stop.restore()
        if gps is not None:
            gps.close()
        if capture is not None:
            capture.close()
        if frames is not None:
            frames.close()
        if writer is not None:
            try:
                writer.close()
            except LidarpktError:
                pass  # the error that stopped the loop is the one reported


def _loop(args, capture: UdpSource, writer: McapWriter, sink: PacketSink, gps, stop, frames=None) -> int:
    start = time.monotonic()
    last_status = start
    last_packets = 0
    reason = None
    gps_failed = False
    notes_shown = 0
    last_rx: float | None = None  # when a datagram last arrived
    silent = False
    while reason is None:
        batches = capture.poll(timeout=0.05)
        now = time.monotonic()
        if batches:
            if silent and last_rx is not None:  # silent is only ever set after a datagram
                _notice(f"packets again after {now - last_rx:.1f} s of silence")
                silent = False
            last_rx = now
        elif last_rx is not None and not silent and now - last_rx > 1.0:
            silent = True  # the sensor stopped, restarted or was unplugged: keep recording
            _notice(f"no packets for {now - last_rx:.1f} s (sensor stopped or unplugged?); still listening")
        for batch in batches:
            sink.push(batch)
        if frames is not None:  # after the packets are written; never waits (see recorder.frames)
            frames.offer(batches)
            frames.write_points(writer)
        for note in sink.notes[notes_shown:]:
            _notice(f"note: {note}")
        notes_shown = len(sink.notes)
        if gps is not None:
            _write_gps(writer, gps)
            if gps.error and not gps_failed:  # the lidar recording goes on without it
                gps_failed = True
                _notice(f"warning: {gps.error}; recording continues without GPS")
        writer.tick()
        now = time.monotonic()
        if stop.reason:
            reason = stop.reason
        elif args.duration is not None and now - start >= args.duration:
            reason = f"duration {args.duration:g} s"
        elif args.frames is not None and sink.frames >= args.frames:
            reason = f"{args.frames} frames"
        if frames is not None:
            frames.tick(_lost_total(capture, sink))
        if now - last_status >= 1.0 and not args.quiet:
            rate = (sink.packets - last_packets) / (now - last_status)
            last_packets, last_status = sink.packets, now
            print(f"\r[{now - start:7.1f} s] {rate:8.0f} pkt/s  {sink.frames} frames  lost {_lost(capture, sink)}  "
                  f"{writer.bytes_written / 1e6:8.1f} MB", end="" if sys.stderr.isatty() else "\n",
                  file=sys.stderr, flush=True)
    # stop receiving, then write whatever was already received
    capture.stop()
    while True:
        batches = capture.poll(timeout=0.0, max_items=65536)
        if not batches:
            break
        for batch in batches:
            sink.push(batch)
        if frames is not None:
            frames.offer(batches)
    if frames is not None:
        frames.finish(writer)  # decodes what is queued and the last partial frames, writes their points
    if gps is not None:
        gps.close()
        _write_gps(writer, gps)
    sink.finish()
    writer.close()
    elapsed = time.monotonic() - start
    summary = _summary(capture, writer, sink, gps, elapsed, reason)
    if frames is not None:
        summary.update(frames.summary())
    if not args.quiet:
        print(("\n" if sys.stderr.isatty() else "") + _summary_text(summary, sink), file=sys.stderr)
    from lidarpkt.cli import args as cliargs

    cliargs.emit_json(args, json.dumps(summary, indent=2))
    return 0 if summary["lost_total"] == 0 else 1


def _notice(text: str) -> None:
    """A line to the user; on a terminal it starts below the status line it interrupts."""
    print(("\n" if sys.stderr.isatty() else "") + f"lidarpkt record: {text}", file=sys.stderr, flush=True)


def _write_gps(writer: McapWriter, gps) -> None:
    store = rosmsgs.typestore()
    from .gps import sentence_time_ns

    for host_ns, sentence in gps.drain():
        stamp = sentence_time_ns(sentence, host_ns)  # the GPS's own time where it says it
        msg = store.types[schemas.NMEA_SENTENCE](header=rosmsgs.header(stamp, "gps"), sentence=sentence)
        writer.write_message(schemas.NMEA, msg, host_ns)


def _lost(capture: UdpSource, sink: PacketSink) -> str:
    s = capture.stats
    return f"{sink.lost} (gaps) + {s.kernel_dropped} (kernel) + {s.queue_overflow} (queue)"


def _lost_total(capture: UdpSource, sink: PacketSink) -> int:
    s = capture.stats
    return max(sink.lost, s.kernel_dropped + s.queue_overflow)


def _summary(capture, writer, sink, gps, elapsed: float, reason: str | None) -> dict:
    s = capture.stats
    return {
        "stopped_by": reason,
        "seconds": round(elapsed, 3),
        "files": [str(p) for p in writer.files],
        "bytes_written": writer.bytes_written,
        "messages_written": writer.messages_written,
        "datagrams_received": s.received,
        "packets": sink.packets,
        "frames": sink.frames,
        "lost_gaps": sink.lost,
        "out_of_order": sink.out_of_order,
        "interruptions": sum(r.count.interruptions for r in sink.streams.values()),
        # packets whose own counters jumped off both neighbours (lidarpkt.core.continuity): recorded, not counted
        "corrupted": sum(r.count.corrupted for r in sink.streams.values()),
        "kernel_drops": s.kernel_dropped,
        "queue_overflow": s.queue_overflow,
        # datagrams dropped here (kernel, queue) leave gaps in the stream counters too: counting both
        # would count them twice; gaps beyond the local drops were lost before reaching this machine
        "lost_total": _lost_total(capture, sink),
        "rcvbuf_requested": s.rcvbuf_requested,
        "rcvbuf_granted": {str(k): v for k, v in s.rcvbuf_granted.items()},
        "gps_sentences": gps.sentences if gps is not None else 0,
        "gps_bad_checksum": gps.bad if gps is not None else 0,
        "gps_error": gps.error if gps is not None else None,
        "streams": [
            {"kind": r.kind, "src": r.src, "dst": r.dst, "payload_size": r.payload_size,
             "packets": r.count.packets, "lost": r.count.lost, "out_of_order": r.count.out_of_order,
             "frames": r.count.frames, "interruptions": r.count.interruptions, "corrupted": r.count.corrupted,
             "messages": r.messages}
            for r in sink.streams.values()
        ],
    }


def _summary_text(d: dict, sink: PacketSink) -> str:
    lines = [
        f"lidarpkt record: stopped by {d['stopped_by']} after {d['seconds']:.1f} s",
        f"  {d['packets']} packets in {d['messages_written']} messages, {d['frames']} rotations, "
        f"{d['bytes_written'] / 1e6:.1f} MB in {', '.join(d['files'])}",
        f"  lost: {d['lost_total']} = the larger of {d['lost_gaps']} (gaps in the packets' own counters, wherever "
        f"lost) and {d['kernel_drops']} (kernel buffer full) + {d['queue_overflow']} (writer fell behind), which "
        f"leave gaps too; {d['out_of_order']} out of order",
    ]
    if d["interruptions"]:
        lines.append(f"  the sensor stream was interrupted {d['interruptions']} time(s) (a jump of more than a second "
                     "in its own counters: stopped, restarted or unplugged); recording went on")
    if d["corrupted"]:
        lines.append(f"  {d['corrupted']} packets were corrupted (their own counters jumped further than the capture "
                     "time allows): recorded as received, not counted as gaps")
    if d["gps_sentences"] or d["gps_bad_checksum"]:
        lines.append(f"  GPS: {d['gps_sentences']} sentences, {d['gps_bad_checksum']} rejected (bad checksum)")
    if "frames_decoded" in d:
        lines.append(f"  frames decoded off the receive path: {d['frames_decoded']}, {d['points_frames_written']} "
                     f"written as points, {d['view_frames_dropped']} dropped for the view, "
                     f"{d['packets_not_decoded']} packets not decoded (decoding fell behind; all were recorded)")
        if d.get("frames_error"):
            lines.append(f"  decoding for the view/points failed on some frames: {d['frames_error']}")
    return "\n".join(lines + sink.report_lines())

