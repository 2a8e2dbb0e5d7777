"""``lidarpkt decode``: captures → MCAP (raw packets and frames) or NumPy ``.npz``.

``lidarpkt decode IN [IN …] -o OUT.mcap [--topics packets,points,images]``
    raw packets as the ROS drivers' topics (losslessly: a file decoded from a pcap gives
    back the same packets and so the same frames), organised ``PointCloud2`` per frame and
    return slot, and optionally range/reflectivity images (see :mod:`lidarpkt.writers.mcap.schemas`).
    Frame messages are logged at the host time their last packet was received (their last
    column's sensor time plus the sensor's clock offset, measured on its first packet);
    ``header.stamp`` is the sensor time of their first column.

``lidarpkt decode IN -o OUT.npz``
    the frames put on their fixed azimuth grid (:meth:`lidarpkt.core.frame.Frame.on_grid`) and
    stacked (spooled through temporary files beside OUT, so memory stays bounded): ``range_mm [K, R, H, W]``, ``reflectivity``, and for Ouster ``signal``,
    ``near_ir``, ``flags``; per column ``column_valid [K, W]``, ``column_timestamp_ns``,
    ``azimuth_deg``, ``measurement_id``, ``status``; per frame ``frame_id [K]``, ``partial``,
    ``lost_packets``; and ``return_labels``, ``sensor_json`` (the sensor description).
    The first sensor's keys are bare, whatever the input holds; further sensors' keys are prefixed
    ``s1_``, ``s2_`` …; ``sensor_prefixes`` lists the prefixes (``["", "s1_"]``).

A progress bar is drawn on stderr when it is a terminal (not with ``-q``). At the end, what was
skipped, lost or discarded is said once per input (:mod:`lidarpkt.core.dropped`).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lidarpkt.errors import LidarpktError, RecorderError, UsageError
from lidarpkt.cli.console import count

if TYPE_CHECKING:
    from lidarpkt.writers.feed import Feed

TOPIC_GROUPS = ("packets", "points", "images")  # lidarpkt.writers.mcap.frames.TOPIC_GROUPS


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from lidarpkt.cli import args as cliargs
    from lidarpkt.containers.magic import CAPTURES_TEXT
    from lidarpkt.writers import SUFFIXES

    parser.add_argument("inputs", nargs="+", metavar="IN", help=f"captures ({CAPTURES_TEXT}; bags and MCAP with raw "
                                                                "packet topics)")
    cliargs.add_output(parser, SUFFIXES,
                       help="OUT.mcap or OUT.npz; or OUT.parquet (a dataset folder), OUT.las, OUT.laz, OUT.csv, "
                            "OUT.ply / OUT.pcd / OUT.kitti (folders of one file per frame), OUT.rrd (Rerun), "
                            "OUT.bag (ROS 1), OUT.rosbag2 (a rosbag2 folder): the suffix chooses the format")
    cliargs.add_sensor_options(parser)
    parser.add_argument("--topics", default="packets,points", metavar="LIST",
                        help=f"MCAP and ROS bags: comma-separated groups among {', '.join(TOPIC_GROUPS)} "
                             "(packets,points)")
    parser.add_argument("--storage", choices=("sqlite3", "mcap"),
                        help="rosbag2: the storage of the bag's messages (sqlite3, as ros2 bag records by default)")
    parser.add_argument("--grid", type=cliargs.number("--grid"), metavar="DEG",
                        help="NPZ: azimuth grid resolution (default: the sensor's, from its firing rate)")
    parser.add_argument("--compress", action="store_true", help="NPZ: compress the arrays (slower)")
    add_frame_arguments(parser)
    parser.add_argument("--layout", choices=("points", "frames"),
                        help="Parquet: one row per return (points, the default) or per frame (frames)")
    parser.add_argument("--frames-per-file", type=cliargs.number("--frames-per-file"), metavar="N",
                        help="LAS/LAZ/CSV: one file per N frames in the folder OUT (default: one file)")
    cliargs.add_workers(parser)
    cliargs.add_quiet(parser, "no progress bar and no summary")


def add_frame_arguments(parser: argparse.ArgumentParser) -> None:
    """``--frame-id``, ``--base-frame``, ``--mount``: the MCAP frame options, the same in every verb
    that writes point clouds (pass :func:`frame_options` of the parsed args to the MCAP writer)."""
    parser.add_argument("--frame-id", action="append", metavar="NAME",
                        help="MCAP: the frame_id of a sensor's clouds and images; repeat once per sensor "
                             "(in order of appearance) or give SERIAL=NAME / ADDRESS=NAME (default: the vendor's ROS "
                             "driver's)")
    parser.add_argument("--base-frame", metavar="NAME",
                        help="MCAP: write each sensor's mount on this frame to /tf_static")
    parser.add_argument("--mount", action="append", metavar="X,Y,Z,ROLL,PITCH,YAW",
                        help="MCAP: a sensor's pose on --base-frame, metres and degrees (repeat once per sensor; "
                             "default: identity; write --mount=-1,... when the first value is negative)")


def frame_options(args: argparse.Namespace) -> dict:
    """The keyword arguments of :class:`lidarpkt.writers.mcap.frames.SensorFrames` from the flags."""
    return {"frame_ids": args.frame_id, "base_frame": args.base_frame, "mounts": args.mount}


def _open_options(args) -> dict[str, Any]:
    """The ``lidarpkt.open`` options of the flags."""
    from lidarpkt.cli import args as cliargs

    return {"workers": getattr(args, "workers", None), **cliargs.sensor_options(args)}


def _feed(args) -> tuple[Feed, Any]:
    """The pass of every input (:class:`lidarpkt.writers.feed.Feed`) and its progress bar (bytes of the inputs)."""
    from lidarpkt.cli import console
    from lidarpkt.writers.feed import Feed

    total = sum(Path(p).stat().st_size for p in args.inputs if Path(p).is_file())
    progress = console.Progress(args.quiet, total=total, desc="decode")
    return Feed(progress=lambda done, frames: progress.update(done, count(frames, "frame"))), progress


def run(args: argparse.Namespace) -> int:
    from lidarpkt.cli import args as cliargs
    from lidarpkt.writers import FORMATS, SUFFIXES, format_from_suffix, takes_packets

    # every check before any decoding: a typo must not cost a decode, nor leave a file behind
    cliargs.check_inputs(args.inputs)
    cliargs.sensor_options(args)  # the sensor files and model checked before any work
    fmt = format_from_suffix(args.output)
    folder = FORMATS[fmt].directory or bool(args.frames_per_file)
    out = cliargs.check_folder(args.output, "-o") if folder else cliargs.check_output(args.output, "-o", SUFFIXES)
    if args.frame_id or args.base_frame or args.mount:
        if not takes_packets(fmt):
            raise UsageError("--frame-id/--base-frame/--mount: they place the point clouds of MCAP and ROS bag "
                             f"outputs; drop them for {fmt} (or write -o OUT.mcap)")
        from lidarpkt.writers.mcap.frames import SensorFrames

        SensorFrames(**frame_options(args))  # their values checked before any decoding
    if fmt == "npz" or takes_packets(fmt):
        _format_options(args, fmt)  # rejects the flags of other formats
    if takes_packets(fmt):  # MCAP, ROS bags: the capture's packets too
        return _to_mcap(args, out, fmt)
    if fmt == "npz":
        return _to_npz(args, out)
    # folder outputs (parquet, ply, pcd, las/laz per N frames) get one writer per input, named by it
    return _to_format(args, out, fmt, folder)


# ----------------------------------------------------------------------------- MCAP
def _to_mcap(args, out: Path, fmt: str = "mcap") -> int:
    """The MCAP (or ROS bag) writer of :func:`lidarpkt.writers.open_writer`, given each input's packets and frames
    in one pass (:func:`lidarpkt.writers.write_captures`): what a script writes with the library."""
    from lidarpkt.writers import open_writer
    from lidarpkt.writers.mcap.frames import TOPIC_GROUPS, calibration_file

    groups = {g.strip() for g in args.topics.split(",") if g.strip()}
    unknown = groups - set(TOPIC_GROUPS)
    if unknown or not groups:
        raise UsageError(f"--topics {args.topics!r}: choose among {', '.join(TOPIC_GROUPS)}")
    options = _open_options(args)
    feed, progress = _feed(args)
    with open_writer(fmt, out, capture=args.inputs[0], topics=groups,
                     calibration=calibration_file(options.get("metadata", ())),
                     **frame_options(args), **_format_options(args, fmt)) as writer:
        for path in args.inputs:
            feed.write(path, [writer], **options)
    writer.close()
    progress.close()
    if not args.quiet:  # packet messages first: the count `lidarpkt info` gives for the file
        frame_messages = writer.mcap.messages_written - writer.packet_messages - writer.decoded_messages
        imu = f", {writer.decoded_messages} IMU/zone messages" if writer.decoded_messages else ""
        print(f"lidarpkt decode: {writer.packet_messages} packet messages{imu} and {frame_messages} frame messages "
              f"({count(feed.frames, 'frame')}) in {out} ({_size_bytes(out) / 1e6:.1f} MB)", file=sys.stderr)
    return 0


def _size_bytes(path: Path) -> int:
    """A file's size, or the sum of a folder's files (a rosbag2)."""
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) if path.is_dir() else os.path.getsize(path)


# ------------------------------------------------------------------------------ NPZ
def _to_npz(args, out: Path) -> int:
    from lidarpkt.writers import open_writer

    options = _open_options(args)
    feed, progress = _feed(args)
    with open_writer("npz", out, grid=args.grid, compress=args.compress) as writer:
        for path in args.inputs:
            feed.write(path, [writer], **options)
        progress.close()
        if not feed.frames:
            raise LidarpktError(f"{', '.join(args.inputs)}: no frames decoded; check the capture with lidarpkt info")
    if not args.quiet:
        print(f"lidarpkt decode: {count(feed.frames, 'frame')} from {count(writer.sensors, 'sensor')} in {out}", file=sys.stderr)
    return 0


# ----------------------------------------------------------- Parquet, LAS/LAZ, PLY, PCD
def _format_options(args, fmt: str) -> dict:
    """The writer options of ``fmt`` from the flags; a flag of another format is an error."""
    from lidarpkt.writers import accepted_options

    if args.layout is not None and fmt != "parquet":
        raise RecorderError(f"--layout {args.layout}: only Parquet outputs have layouts (-o OUT.parquet)")
    if args.frames_per_file is not None and "frames_per_file" not in accepted_options(fmt):
        raise RecorderError(f"--frames-per-file {args.frames_per_file}: only for LAS/LAZ/CSV outputs (-o OUT.las)")
    if getattr(args, "storage", None) is not None:
        if "storage" not in accepted_options(fmt):
            raise RecorderError(f"--storage {args.storage}: only rosbag2 outputs have storages (-o OUT.rosbag2)")
        return {"storage": args.storage}
    if fmt == "parquet":
        return {"layout": args.layout or "points"}
    if args.frames_per_file is not None:
        if args.frames_per_file < 1:
            raise RecorderError(f"--frames-per-file {args.frames_per_file}: give a positive number of frames")
        return {"frames_per_file": args.frames_per_file}
    return {}


def _to_format(args, out: Path, fmt: str, per_input: bool) -> int:
    """Folder formats get one writer per input (files named by capture), one-file formats one
    writer for all inputs."""
    from lidarpkt.writers import open_writer

    options = _format_options(args, fmt)
    open_options = _open_options(args)
    feed, progress = _feed(args)
    written: list[Path] = []
    if per_input:
        for path in args.inputs:
            with open_writer(fmt, out, capture=path, **options) as writer:
                feed.write(path, [writer], **open_options)
            written += writer.close()
    else:
        with open_writer(fmt, out, capture=args.inputs[0], **options) as writer:
            for path in args.inputs:
                writer.capture = Path(path).name  # the input of the frames that follow (CSV's capture column)
                feed.write(path, [writer], **open_options)
        written = writer.close()
    progress.close()
    if not feed.frames:
        raise LidarpktError(f"{', '.join(args.inputs)}: no frames decoded; check the capture with lidarpkt info")
    if not args.quiet:
        print(f"lidarpkt decode: {count(feed.frames, 'frame')} in {count(len(written), 'file')} under {out}", file=sys.stderr)
    return 0


# ------------------------------------------------------------------------------ Python API
def decode_captures(inputs: list[str | os.PathLike[str]], output: str | os.PathLike[str], *, quiet: bool = True,
                    **options) -> None:
    """The ``decode`` verb from Python: ``inputs`` → ``output`` (the suffix chooses the format).

    ``options`` are the verb's flags by their Python names, with the CLI's defaults: ``metadata``
    (list of paths of any vendor's sensor description files), ``model``, ``topics`` (``"packets,points"``), ``grid``, ``compress``,
    ``layout``, ``frames_per_file``, ``storage``, ``frame_id`` (list), ``base_frame``, ``mount`` (list of
    ``"x,y,z,roll,pitch,yaw"``). Raises the verb's :class:`~lidarpkt.errors.LidarpktError` s, and
    :class:`~lidarpkt.errors.OutputError` for an unknown option.
    """
    from lidarpkt.errors import OutputError

    parser = argparse.ArgumentParser(add_help=False)
    add_arguments(parser)
    args = parser.parse_args([*(str(p) for p in inputs), "-o", str(output)])
    unknown = sorted(set(options) - set(vars(args)))
    if unknown:
        raise OutputError(f"decode: no option {', '.join(unknown)}")
    for name, value in options.items():
        setattr(args, name, [str(v) for v in value] if isinstance(value, (list, tuple)) else value)
    args.quiet = quiet
    run(args)
