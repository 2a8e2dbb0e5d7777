"""``lidarpkt record``: capture a live sensor (and a serial GPS) to MCAP without losing a packet
(:func:`lidarpkt.recorder.record.record`).

It prints a status line each second and a summary at the end. It stops on Ctrl-C, SIGTERM,
``--duration`` or ``--frames`` and closes the file with its summary and index (a second Ctrl-C: at
once, the file still indexed). Killed outright, it leaves a file readable up to its last complete
chunk (``--chunk-seconds``, 0.5 s by default).

Exit status: 0 = recorded, nothing lost; 1 = recorded but packets were lost (the summary
says where); 2 = error (port in use, disk full, bad option …).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from lidarpkt.errors import RecorderError

from . import args as cliargs
from .console import count
from .live import add_receive_arguments, add_ws_argument, live_sensors, receive_options, start_view


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from .decode import add_frame_arguments

    add_receive_arguments(parser, "a sensor's description file (its metadata or calibration, of any vendor, told "
                                  "apart by its content): recorded in the file, and what the --points frames are "
                                  "decoded with; repeat, one per sensor")
    stop = parser.add_mutually_exclusive_group()
    stop.add_argument("--duration", type=cliargs.number("--duration"), metavar="S", help="stop after S seconds")
    stop.add_argument("--frames", type=cliargs.number("--frames"), metavar="N", help="stop after N complete rotations")
    cliargs.add_output(parser, (".mcap",), help="MCAP file to write")
    parser.add_argument("--rotate-size", type=cliargs.number("--rotate-size"), metavar="MB",
                        help="start a new file every MB megabytes (files are then OUT_0000.mcap, OUT_0001.mcap ...)")
    parser.add_argument("--rotate-time", type=cliargs.number("--rotate-time"), metavar="S", help="start a new file every S seconds (as above)")
    parser.add_argument("--chunk-seconds", type=cliargs.number("--chunk-seconds"), default=0.5, metavar="S",
                        help="close an MCAP chunk every S seconds: at most that much is lost if killed (0.5)")
    parser.add_argument("--gps", metavar="PORT", help="serial port of an NMEA GPS (e.g. /dev/ttyUSB0)")
    parser.add_argument("--baud", type=cliargs.number("--baud"), default=9600, help="GPS baud rate (9600)")
    parser.add_argument("--points", action="store_true",
                        help="also write PointCloud2 frames (decoded off the receive path) to the MCAP")
    parser.add_argument("--view", action="store_true",
                        help="serve a Foxglove live view while recording (see --ws); it never costs a packet")
    add_ws_argument(parser)
    add_frame_arguments(parser)  # with --points: each sensor's frame id and its mount on /tf_static
    cliargs.add_json(parser, "the summary as one JSON document", file_flag="--report")  # -o is the MCAP
    cliargs.add_quiet(parser, "no status line and no summary: only errors, the notices of what happens to the "
                              "stream (silence, unknown packets kept), and the one line that says where it listens "
                              "and writes (scripts wait for it)")


def run(args: argparse.Namespace) -> int:
    from lidarpkt.recorder.record import record

    from .console import StopSignals

    cliargs.sensor_options(args)  # the sensor files and model checked first
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

        from .decode import frame_options

        sensors = SensorFrames(**frame_options(args))  # checked before anything is opened
    files, decoder_options = live_sensors(args)
    # a second Ctrl-C: stop now (the file still gets its index)
    stop = StopSignals(second_interrupt_raises=True).install()
    try:
        recording = record(
            args.output, ports=args.port or (), metadata=files, decoder_options=decoder_options,
            chunk_seconds=args.chunk_seconds, rotate_bytes=int(args.rotate_size * 1e6) if args.rotate_size else None,
            rotate_seconds=args.rotate_time, gps=args.gps, gps_baud=args.baud, points=args.points, sensors=sensors,
            view=(lambda: start_view(args.ws, verb="record")) if args.view else None, duration_s=args.duration,
            max_frames=args.frames, should_stop=lambda: stop.reason, on_listening=lambda capture: _listening(capture, args),
            on_status=None if args.quiet else _status_line, on_notice=_notice, **receive_options(args))
    finally:
        stop.restore()
    summary = recording.summary
    if not args.quiet:
        print(("\n" if sys.stderr.isatty() else "") + summary_text(summary, recording.report_lines), file=sys.stderr)
    cliargs.emit_json(args, json.dumps(summary, indent=2))
    return 0 if summary["lost_total"] == 0 else 1


def _listening(capture, args: argparse.Namespace) -> None:
    granted = ", ".join(f"{b / (1 << 20):.1f} MiB on port {p}" for p, b in capture.stats.rcvbuf_granted.items())
    out = Path(args.output)
    if args.rotate_size or args.rotate_time:  # the files the writer makes: STEM_0000.mcap, STEM_0001.mcap ...
        writing = f"{out.with_name(out.stem + '_0000.mcap')}, {out.stem}_0001.mcap ... (a new file every " + \
            " or ".join(x for x in (f"{args.rotate_size:g} MB" if args.rotate_size else "",
                                    f"{args.rotate_time:g} s" if args.rotate_time else "") if x) + ")"
    else:
        writing = str(out)
    # printed even with --quiet: the one line that says the recorder is ready (scripts wait for it)
    ports = ", ".join(map(str, capture.ports))
    print(f"lidarpkt record: listening on {capture.bind_address} {'port' if len(capture.ports) == 1 else 'ports'} "
          f"{ports}; receive buffer asked {capture.stats.rcvbuf_requested / (1 << 20):g} MiB, granted {granted}; "
          f"writing {writing}", file=sys.stderr, flush=True)


def _status_line(s) -> None:
    lost = f"{s.lost_gaps} (gaps) + {s.kernel_drops} (kernel) + {s.queue_overflow} (queue)"
    print(f"\r[{s.seconds:7.1f} s] {s.packets_per_s:8.0f} pkt/s  {count(s.frames, 'rotation')}  lost {lost}  "
          f"{s.bytes_written / 1e6:8.1f} MB", end="" if sys.stderr.isatty() else "\n", file=sys.stderr, flush=True)


def _notice(text: str) -> None:
    """A line to the user; on a terminal it starts below the status line it interrupts."""
    print(("\n" if sys.stderr.isatty() else "") + f"lidarpkt record: {text}", file=sys.stderr, flush=True)


def summary_text(d: dict, report_lines: list[str]) -> str:
    """The summary a recording prints: its files, counts and losses, then the sink's report lines."""
    lines = [
        f"lidarpkt record: stopped by {d['stopped_by']} after {d['seconds']:.1f} s",
        f"  {count(d['packets'], 'packet')} in {count(d['messages_written'], 'message')}, "
        f"{count(d['frames'], 'rotation')}, "
        f"{d['bytes_written'] / 1e6:.1f} MB in {', '.join(d['files'])}",
        f"  lost: {d['lost_total']} = the larger of {d['lost_gaps']} (gaps in the packets' own counters, wherever "
        f"lost) and {d['kernel_drops']} (kernel buffer full) + {d['queue_overflow']} (writer fell behind), which "
        f"leave gaps too; {d['out_of_order']} out of order",
    ]
    if d["interruptions"]:
        lines.append(f"  the sensor stream was interrupted {count(d['interruptions'], 'time')} (a jump of more than a second "
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
    return "\n".join(lines + report_lines)
