"""``lidarpkt decode``: captures → MCAP (raw packets and frames) or NumPy ``.npz``.

``lidarpkt decode IN [IN …] -o OUT.mcap [--topics packets,points,images]``
    raw packets as the ROS drivers' topics (losslessly: a file decoded from a pcap gives
    back the same packets and so the same frames), organised ``PointCloud2`` per frame and
    return slot, and optionally range/reflectivity images (see :mod:`recorder.schemas`).
    Frame messages are logged at the host time their last packet was received (their last
    column's sensor time plus the sensor's clock offset, measured on its first packet);
    ``header.stamp`` is the sensor time of their first column.

``lidarpkt decode IN -o OUT.npz``
    the frames put on their fixed azimuth grid (:meth:`lidarpkt.frame.Frame.on_grid`) and
    stacked (spooled through temporary files beside OUT, so memory stays bounded): ``range_mm [K, R, H, W]``, ``reflectivity``, and for Ouster ``signal``,
    ``near_ir``, ``flags``; per column ``column_valid [K, W]``, ``column_timestamp_ns``,
    ``azimuth_deg``, ``measurement_id``, ``status``; per frame ``frame_id [K]``, ``partial``,
    ``lost_packets``; and ``return_labels``, ``sensor_json`` (the sensor description).
    Several sensors in one input get key prefixes ``s0_``, ``s1_`` ….

A progress bar is drawn on stderr when it is a terminal.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from lidarpkt.errors import LidarpktError, RecorderError

TOPIC_GROUPS = ("packets", "points", "images")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("inputs", nargs="+", metavar="IN", help="pcap/pcapng, MCAP or ROS bag with raw packet topics")
    parser.add_argument("-o", "--output", required=True, metavar="OUT", help="OUT.mcap or OUT.npz")
    parser.add_argument("--metadata", action="append", metavar="M.json", help="Ouster metadata JSON (repeatable)")
    parser.add_argument("--calibration", metavar="FILE", help="VLP-16 calibration (ROS YAML or VeloView XML)")
    parser.add_argument("--topics", default="packets,points", metavar="LIST",
                        help=f"MCAP: comma-separated groups among {', '.join(TOPIC_GROUPS)} (packets,points)")
    parser.add_argument("--grid", type=float, metavar="DEG", help="NPZ: azimuth grid resolution (sensor default)")
    parser.add_argument("--compress", action="store_true", help="NPZ: compress the arrays (slower)")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar or summary")


class _Progress:
    """A one-line progress bar on a terminal (nothing otherwise)."""

    def __init__(self, enabled: bool, total_bytes: int) -> None:
        self.enabled = enabled and sys.stderr.isatty()
        self.total = max(total_bytes, 1)
        self.start = time.monotonic()
        self.last = 0.0

    def update(self, done_bytes: int | None, frames: int, force: bool = False) -> None:
        now = time.monotonic()
        if not self.enabled or (now - self.last < 0.1 and not force):
            return
        self.last = now
        elapsed = now - self.start
        if done_bytes is None:
            bar = f"{frames} frames"
        else:
            frac = min(done_bytes / self.total, 1.0)
            filled = int(frac * 30)
            bar = f"[{'#' * filled}{'.' * (30 - filled)}] {frac * 100:5.1f}%  {frames} frames"
        print(f"\rdecode {bar}  {elapsed:6.1f} s", end="", file=sys.stderr, flush=True)

    def done(self, frames: int) -> None:
        if self.enabled:
            self.update(self.total, frames, force=True)
            print(file=sys.stderr)


def _bytes_read(reader) -> int | None:
    stats = getattr(getattr(reader, "reader", None), "stats", None)
    return getattr(stats, "bytes_read", None)


def _packet_reader(path: str):
    """The packet reader of one input (:func:`lidarpkt.sources.open_packet_source`)."""
    from lidarpkt.sources import open_packet_source

    return open_packet_source(path)


def _clock_offsets(path: str, md, look_ahead: int = 64) -> dict[str, int]:
    """Host receive time minus sensor time (ns) of each lidar source, from its first packet among
    the first ``look_ahead`` batches. Ouster clocks often count from boot, VLP-16 ones from the hour:
    frames are logged at sensor time + this offset, i.e. when their last packet was received."""
    from lidarpkt.velodyne import packet as vlp

    from . import streams
    from .sink import velodyne_sensor_time_ns

    offsets: dict[str, int] = {}
    reader = _packet_reader(path)
    for k, batch in enumerate(reader.batches()):
        if k >= look_ahead:
            break
        src = str(batch.src) if batch.src is not None else "unknown source"
        if src in offsets:
            continue
        if md is None and getattr(reader, "ouster_metadata", None) and reader.ouster_metadata():
            from lidarpkt.ouster.metadata import load_metadata

            md = load_metadata(reader.ouster_metadata())
        kind = streams.classify_size(batch.payload_size, md)
        host = int(batch.timestamp_ns[0])
        if kind == streams.VELODYNE_DATA:
            ts_us = vlp.as_data_packets(batch.payload[:1])["timestamp_us"]
            offsets[src] = host - int(velodyne_sensor_time_ns(ts_us, batch.timestamp_ns[:1])[0])
        elif kind == streams.OUSTER_LIDAR and md is not None:
            dtype = md.profile.packet_dtype(md.pixels_per_column, md.columns_per_packet)
            first = np.ascontiguousarray(batch.payload[:1]).view(dtype)[0, 0]["columns"][0]
            offsets[src] = host - int(first["timestamp_ns"])
    return offsets


def _frame_log_time(frame, offsets: dict[str, int]) -> int:
    """When the frame's last packet was received (host time, ns): its last column's sensor time plus
    its source's clock offset (the only offset when the frame's source is not named)."""
    valid = frame.column_timestamp_ns[frame.column_valid]
    end = int(valid.max()) if valid.size else frame.timestamp_ns
    offset = offsets.get(frame.sensor.source)
    if offset is None:
        offset = next(iter(offsets.values())) if len(offsets) == 1 else 0
    return end + offset


def _open_frames(path: str, args) -> object:
    import lidarpkt

    options = {}
    if args.calibration:
        options["calibration"] = args.calibration
    return lidarpkt.open(path, metadata=args.metadata, **options)


def run(args: argparse.Namespace) -> int:
    out = Path(args.output)
    for path in args.inputs:
        if not Path(path).exists():
            raise LidarpktError(f"{path}: no such file or directory")
    if not out.parent.is_dir():
        raise RecorderError(f"-o {out}: the folder {out.parent} does not exist")
    if out.suffix == ".npz":
        return _to_npz(args, out)
    if out.suffix == ".mcap":
        return _to_mcap(args, out)
    raise RecorderError(f"-o {out}: the output must end in .mcap or .npz")


# ----------------------------------------------------------------------------- MCAP
def _to_mcap(args, out: Path) -> int:
    from .mcap_writer import McapWriter
    from .pointcloud import image_messages, pointcloud_messages
    from .sink import PacketSink

    groups = {g.strip() for g in args.topics.split(",") if g.strip()}
    unknown = groups - set(TOPIC_GROUPS)
    if unknown or not groups:
        raise RecorderError(f"--topics {args.topics!r}: choose among {', '.join(TOPIC_GROUPS)}")
    md = None
    if args.metadata:
        from lidarpkt.ouster.metadata import load_metadata

        md = load_metadata(args.metadata[0])
    total = sum(Path(p).stat().st_size for p in args.inputs if Path(p).is_file())
    progress = _Progress(not args.quiet, total * (2 if "packets" in groups and groups - {"packets"} else 1))
    frames_written = 0
    done_before = 0
    described: set[tuple] = set()
    with McapWriter(out, chunk_seconds=float("inf"), chunk_bytes=4 << 20) as writer:
        if args.calibration:
            try:
                text = Path(args.calibration).read_text(encoding="utf-8", errors="replace")
            except OSError as exc:
                raise RecorderError(f"cannot read the calibration {args.calibration}: {exc.strerror}") from None
            writer.add_metadata("lidarpkt.calibration", {"path": str(args.calibration), "content": text})
        if "packets" in groups:
            from .replay import embedded_metadata

            for path in args.inputs:
                sink = PacketSink(writer, ouster_metadata=md or embedded_metadata(path))
                reader = _packet_reader(path)
                for batch in reader.batches():
                    sink.push(batch)
                    b = getattr(reader.stats, "bytes_read", None)
                    progress.update(None if b is None else done_before + b, frames_written)
                sink.finish()
                done_before += Path(path).stat().st_size if Path(path).is_file() else 0
        if groups & {"points", "images"}:
            for path in args.inputs:
                offsets = _clock_offsets(path, md)
                reader = _open_frames(path, args)
                for frame in reader:
                    log_time = _frame_log_time(frame, offsets)
                    sensor_key = (frame.sensor.vendor, frame.sensor.source, frame.sensor.model)
                    if sensor_key not in described:  # what the frames were decoded with, once per sensor
                        described.add(sensor_key)
                        writer.add_metadata("lidarpkt.frames", {
                            "input": str(path), "sensor_info": json.dumps(frame.sensor.describe(), default=str),
                            "calibration": str(args.calibration or "stock")})
                    messages = []
                    if "points" in groups:
                        messages += pointcloud_messages(frame)
                    if "images" in groups:
                        messages += image_messages(frame)
                    for topic, msg in messages:
                        writer.write_message(topic, msg, log_time)
                    frames_written += 1
                    b = _bytes_read(reader)
                    progress.update(None if b is None else done_before + b, frames_written)
                done_before += Path(path).stat().st_size if Path(path).is_file() else 0
    progress.done(frames_written)
    if not args.quiet:
        print(f"lidarpkt decode: {writer.messages_written} messages ({frames_written} frames) in {out} "
              f"({os.path.getsize(out) / 1e6:.1f} MB)", file=sys.stderr)
    return 0


# ------------------------------------------------------------------------------ NPZ
_PER_FRAME_FIELDS = ("range_mm", "reflectivity", "column_valid", "column_timestamp_ns", "azimuth_deg",
                     "signal", "near_ir", "flags", "measurement_id", "status")


class _Spool:
    """The frames of one sensor, each field appended to its own temporary file as raw bytes, so
    that memory stays bounded however long the input; :meth:`write_into` streams them into the
    ``.npz`` (a zip of ``.npy`` files) as ``[K, ...]`` arrays."""

    def __init__(self, tmpdir: Path, index: int, first) -> None:
        self.tmpdir = tmpdir
        self.index = index
        self.files: dict[str, tuple[object, np.dtype, tuple]] = {}
        self.scalars: dict[str, list] = {"frame_id": [], "partial": [], "lost_packets": []}
        self.constants = {"return_labels": np.array(first.return_labels),
                          "sensor_json": np.array(json.dumps(first.sensor.describe(), default=str))}
        self.count = 0

    def append(self, frame) -> None:
        for name in _PER_FRAME_FIELDS:
            arr = getattr(frame, name)
            if arr is None:
                continue
            arr = np.ascontiguousarray(arr)
            entry = self.files.get(name)
            if entry is None:
                fh = open(self.tmpdir / f"s{self.index}_{name}.raw", "w+b")
                entry = self.files[name] = (fh, arr.dtype, arr.shape)
            fh, dtype, shape = entry
            if arr.dtype != dtype or arr.shape != shape:
                raise LidarpktError(f"frame {frame.frame_id}: {name} is {arr.dtype}{list(arr.shape)}, unlike the "
                                    f"frames before it ({dtype}{list(shape)}); cannot stack them")
            fh.write(arr.tobytes())
        self.scalars["frame_id"].append(frame.frame_id)
        self.scalars["partial"].append(frame.partial)
        self.scalars["lost_packets"].append(frame.counters.lost_packets)
        self.count += 1

    def write_into(self, zf, prefix: str) -> None:
        import shutil

        for name, (fh, dtype, shape) in self.files.items():
            fh.flush()
            fh.seek(0)
            with zf.open(prefix + name + ".npy", "w", force_zip64=True) as out:
                np.lib.format.write_array_header_2_0(out, {
                    "descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False,
                    "shape": (self.count,) + tuple(shape)})
                shutil.copyfileobj(fh, out, 16 << 20)
            fh.close()
        arrays = {"frame_id": np.array(self.scalars["frame_id"], np.int64),
                  "partial": np.array(self.scalars["partial"], bool),
                  "lost_packets": np.array(self.scalars["lost_packets"], np.int64), **self.constants}
        for name, arr in arrays.items():
            with zf.open(prefix + name + ".npy", "w", force_zip64=True) as out:
                np.lib.format.write_array(out, arr, allow_pickle=False)


def _to_npz(args, out: Path) -> int:
    import tempfile
    import zipfile

    progress = _Progress(not args.quiet, sum(Path(p).stat().st_size for p in args.inputs if Path(p).is_file()))
    n = 0
    done_before = 0
    with tempfile.TemporaryDirectory(prefix="lidarpkt-npz-", dir=out.parent) as tmp:
        spools: dict[tuple, _Spool] = {}
        for path in args.inputs:
            reader = _open_frames(path, args)
            for frame in reader:
                key = (frame.sensor.vendor, frame.sensor.model, frame.sensor.source, frame.shape[0], frame.shape[1])
                gridded = frame.on_grid(args.grid)
                spool = spools.get(key)
                if spool is None:
                    spool = spools[key] = _Spool(Path(tmp), len(spools), gridded)
                spool.append(gridded)
                n += 1
                b = _bytes_read(reader)
                progress.update(None if b is None else done_before + b, n)
            done_before += Path(path).stat().st_size if Path(path).is_file() else 0
        progress.done(n)
        if not spools:
            raise LidarpktError(f"no frames decoded from {', '.join(args.inputs)}")
        try:
            with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED if args.compress else zipfile.ZIP_STORED,
                                 allowZip64=True) as zf:
                for spool in spools.values():
                    spool.write_into(zf, "" if len(spools) == 1 else f"s{spool.index}_")
        except OSError as exc:
            raise RecorderError(f"cannot write {out}: {exc.strerror or exc}") from None
    if not args.quiet:
        print(f"lidarpkt decode: {n} frames from {len(spools)} sensor(s) in {out}", file=sys.stderr)
    return 0
