"""Frames into MCAP: point clouds and images per sensor frame, ``/tf_static``, log times in the capture.

:class:`SensorFrames` names each sensor's coordinate frame (``--frame-id``) and its static mount on
a base frame (``--base-frame``, ``--mount x,y,z,roll,pitch,yaw``: metres and degrees, roll about
x, then pitch about y, then yaw about z, fixed axes, as tf2's ``setRPY``). :class:`FrameTopics`
writes a frame's messages through a :class:`~lidarpkt.writers.mcap.writer.McapWriter` (what
``record --points`` uses); :class:`McapFrameWriter` is the MCAP writer of
:func:`lidarpkt.writers.open_writer` (what ``decode`` uses): the capture's raw packets
(:mod:`lidarpkt.writers.mcap.packets`) and its frames' messages.

Log times: a frame's messages are logged when its last packet was received: its last column's
sensor time plus the sensor's clock offset (host − sensor time on its first packet), kept inside
``[start_ns, end_ns]`` (the capture's first and last packet times) when those are given;
``/tf_static`` at ``start_ns`` (else the first frame's log time).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Iterable, Sequence, cast

import numpy as np

from lidarpkt.containers import rosmsgs
from lidarpkt.core.ros import Topic
from lidarpkt.errors import OutputError

from ..base import BaseWriter
from . import schemas
from .packets import CaptureTimes, PacketSink
from .pending import PendingFrames
from .pointcloud import default_frame_id, image_messages, pointcloud_messages
from .writer import McapWriter

TOPIC_GROUPS = ("packets", "points", "images")
Mount = tuple[float, float, float, float, float, float]


def parse_mount(text: str) -> Mount:
    """``"x,y,z,roll,pitch,yaw"`` (metres, degrees) → six floats; raises OutputError naming --mount."""
    try:
        values = tuple(float(v) for v in str(text).split(","))
    except ValueError:
        values = ()
    if len(values) != 6 or not all(np.isfinite(values)):
        raise OutputError(f"--mount {text}: give six numbers x,y,z,roll,pitch,yaw (metres, degrees)")
    return values  # type: ignore[return-value]


def calibration_file(metadata: Iterable[Any]) -> str | None:
    """Of the sensor files given (paths, as ``lidarpkt.open`` takes them), the one an MCAP of the frames records
    as their calibration (``calibration=`` of :class:`McapFrameWriter`): the first whose vendor writes no
    messages of its own for it (those are recorded with the packets); ``None`` when there is none.

    Raises what :func:`lidarpkt.vendors.registry.load_sensor_files` raises."""
    from lidarpkt.vendors import registry

    given = [m for m in metadata if isinstance(m, (str, os.PathLike))]
    for path, f in zip(given, registry.load_sensor_files(given)):
        if registry.vendor(f.vendor).ros.sensor_file_messages is None:
            return str(path)
    return None


def mount_quaternion(roll_deg: float, pitch_deg: float, yaw_deg: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of the rotation roll about x, then pitch about y, then yaw about z (fixed axes)."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_euler("xyz", [roll_deg, pitch_deg, yaw_deg], degrees=True).as_quat()
    return float(x), float(y), float(z), float(w)


def _sensor_keys(sensor) -> set[str]:
    keys = {str(k) for k in (sensor.serial, sensor.source) if k}
    if sensor.source and ":" in str(sensor.source):
        keys.add(str(sensor.source).rsplit(":", 1)[0])  # the address without the port
    return keys


class SensorFrames:
    """Each sensor's ``frame_id`` and optional mount on a base frame.

    Args:
        frame_ids: ``NAME`` entries are given to the sensors in order of first appearance;
            ``KEY=NAME`` entries to the sensor whose serial, source address or ``address:port``
            is KEY. A sensor without one gets its vendor's (``velodyne``, ``os_sensor``), with
            ``_1``, ``_2`` … for further sensors of that vendor.
        base_frame: the parent frame of the mounts; ``None``: no ``/tf_static``.
        mounts: one ``(x, y, z, roll, pitch, yaw)`` (or its text) per sensor in order of
            appearance; sensors beyond the list are mounted at the identity.

    Raises OutputError: mounts without a base frame, or a frame id given twice.
    """

    def __init__(self, frame_ids: Sequence[str] | str | None = None, base_frame: str | None = None,
                 mounts: Iterable[Mount | str] | None = None) -> None:
        if isinstance(frame_ids, str):
            frame_ids = [frame_ids]
        self._ordered = [f for f in (frame_ids or []) if "=" not in f]
        self._keyed = dict(f.split("=", 1) for f in (frame_ids or []) if "=" in f)
        names = [*self._ordered, *self._keyed.values()]
        if any(not v for v in names):
            raise OutputError("--frame-id: a frame id cannot be empty")
        if len(set(names)) != len(names):
            raise OutputError(f"--frame-id {' '.join(frame_ids or [])}: each sensor needs its own frame id")
        self.base_frame = base_frame or None
        self.mounts = [parse_mount(m) if isinstance(m, str) else tuple(float(v) for v in m) for m in (mounts or [])]
        if self.mounts and not self.base_frame:
            raise OutputError("--mount: a mount needs the frame it is on; add --base-frame NAME")
        self._assigned: dict[tuple, str] = {}
        self._unkeyed = 0  # sensors given an unkeyed NAME so far

    @staticmethod
    def key(sensor) -> tuple:
        return (sensor.vendor, sensor.source, sensor.serial)

    def is_new(self, sensor) -> bool:
        return self.key(sensor) not in self._assigned

    def frame_id(self, sensor) -> str:
        """The frame id of ``sensor`` (assigned on first call, stable afterwards)."""
        key = self.key(sensor)
        name = self._assigned.get(key)
        if name is not None:
            return name
        name = next((v for k, v in self._keyed.items() if k in _sensor_keys(sensor)), None)
        if name is None and self._unkeyed < len(self._ordered):
            name = self._ordered[self._unkeyed]
            self._unkeyed += 1
        if name is None:
            base = default_frame_id(sensor.vendor)
            same = sum(1 for k in self._assigned if k[0] == sensor.vendor)
            name = base if same == 0 else f"{base}_{same}"
        if name in self._assigned.values():
            raise OutputError(f"--frame-id: two sensors would both be {name!r}; give one --frame-id per sensor")
        self._assigned[key] = name
        return name

    def transform(self, sensor, stamp_ns: int):
        """The ``tf2_msgs/msg/TFMessage`` mounting ``sensor`` on the base frame, or None without one."""
        if not self.base_frame:
            return None
        name = self.frame_id(sensor)
        index = list(self._assigned).index(self.key(sensor))
        x, y, z, roll, pitch, yaw = self.mounts[index] if index < len(self.mounts) else (0.0,) * 6
        qx, qy, qz, qw = mount_quaternion(roll, pitch, yaw)
        t = rosmsgs.typestore().types
        stamped = t["geometry_msgs/msg/TransformStamped"](
            header=rosmsgs.header(stamp_ns, self.base_frame), child_frame_id=name,
            transform=t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](x=x, y=y, z=z),
                rotation=t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw)))
        return t[schemas.TF_MESSAGE](transforms=[stamped])


def frame_log_time(frame, offsets: dict[str, int]) -> int:
    """When the frame's last packet was received (host time, ns): its last column's sensor time plus
    its source's clock offset (the only offset when the frame's source is not named)."""
    return frame_end_ns(frame) + clock_offset(frame.sensor.source, offsets)


def frame_end_ns(frame) -> int:
    """The sensor time (ns) of the frame's last valid column (its first column's when none is valid)."""
    valid = frame.column_timestamp_ns[frame.column_valid]
    return int(valid.max()) if valid.size else frame.timestamp_ns


def clock_offset(source: str | None, offsets: dict[str, int]) -> int:
    """``source``'s clock offset (host − sensor time, ns); the only one when ``source`` has none; else 0."""
    offset = offsets.get(source) if source is not None else None
    if offset is None:
        offset = next(iter(offsets.values())) if len(offsets) == 1 else 0
    return offset


class FrameTopics:
    """Writes frames' point clouds and/or images and each new sensor's ``/tf_static`` to an MCAP file.

    Args:
        mcap: the :class:`~lidarpkt.writers.mcap.writer.McapWriter`.
        groups: among ``"points"``, ``"images"`` (``"packets"`` is ignored here).
        sensors: the :class:`SensorFrames` (default: the vendors' frame ids, no ``/tf_static``).
    """

    def __init__(self, mcap, groups: Iterable[str] = ("points",), sensors: SensorFrames | None = None) -> None:
        self.mcap = mcap
        self.groups = set(groups)
        self.sensors = sensors or SensorFrames()

    def write(self, frame, log_time_ns: int, tf_time_ns: int | None = None) -> None:
        """Write one frame's messages at ``log_time_ns``; a new sensor's mount first, at ``tf_time_ns``."""
        if self.sensors.is_new(frame.sensor):
            self.mount(frame.sensor, log_time_ns if tf_time_ns is None else tf_time_ns)
        for topic, msg in self.messages(frame):
            self.mcap.write_message(topic, msg, log_time_ns)

    def mount(self, sensor, time_ns: int) -> None:
        """Write ``sensor``'s mount on the base frame to ``/tf_static`` (stamped and logged at ``time_ns``), if
        there is a base frame."""
        tf = self.sensors.transform(sensor, time_ns)
        if tf is not None:
            self.mcap.write_latched(schemas.TF_STATIC, rosmsgs.encode(schemas.TF_MESSAGE, tf), time_ns,
                                    key=self.sensors.frame_id(sensor))

    def messages(self, frame) -> list:
        """``(topic, message)`` of the frame's point clouds and/or images, in its sensor's frame."""
        name = self.sensors.frame_id(frame.sensor)
        messages: list = []
        if "points" in self.groups:
            messages += pointcloud_messages(frame, frame_id=name)
        if "images" in self.groups:
            messages += image_messages(frame, frame_id=name)
        return messages


class McapFrameWriter(BaseWriter):
    """ROS 2 MCAP of a capture: its raw packets and its frames' messages (see the module doc).

    What ``lidarpkt decode IN -o OUT.mcap`` writes, from Python (one pass over the capture hands the
    writer its packets and frames, :func:`lidarpkt.writers.write_captures`):

    >>> with open_writer("mcap", "out.mcap", topics=("packets", "points")) as w:  # doctest: +SKIP
    ...     write_captures(["drive.pcap"], [w])

    Of each capture (:meth:`begin_capture` … :meth:`end_capture`) it writes the packets when ``packets`` is
    among the topics (:class:`~lidarpkt.writers.mcap.packets.PacketSink`) and measures its clock offsets and
    span (:class:`~lidarpkt.writers.mcap.packets.CaptureTimes`), the frames' log times; a frame whose log
    time the rest of the capture may still change waits (:class:`~lidarpkt.writers.mcap.pending.PendingFrames`),
    as do each sensor's mount and the sensor files' latched messages, logged at the capture's start. Frames written with
    :meth:`write` alone, without a pass, are logged at their sensor time (unless the times are given).

    Args:
        out: the ``.mcap`` file (its folder must exist).
        capture: the name of the capture the frames come from (recorded in the file's metadata when
            frames come without a pass).
        part: see :func:`lidarpkt.writers.open_writer`.
        topics: groups among ``packets``, ``points``, ``images``.
        frame_ids, base_frame, mounts: see :class:`SensorFrames`.
        metadata: the sensor files of the capture's sensors, as ``lidarpkt.open`` takes them (paths or
            loaded, one per sensor): what their packets are, and their clocks. By default those the pass
            recognises them with (given to it, or recorded in the capture).
        calibration: the calibration file the frames were decoded with, recorded in the file's metadata
            (``lidarpkt.calibration``, and ``lidarpkt.frames`` of each sensor); ``None``: stock.
        clock_offsets, start_ns, end_ns: host − sensor time (ns) per source address, the capture's
            first and last packet host times (see :func:`frame_log_time`), to use instead of measuring
            them from the packets.
        chunk_bytes: MCAP chunk size.

    Raises:
        OutputError: an unknown topic group; ``packets`` given frames without a pass (at the first frame,
            or at :meth:`close`); the output cannot be written. MetadataError: a file of ``metadata`` is of
            no kind lidarpkt reads.
    """

    suffix = ".mcap"
    wants_packets = True
    pending_bytes = 64 << 20  # encoded frame messages held in memory while their log time waits

    def __init__(self, out: str | os.PathLike[str], *, capture: Any = None, part: str | None = None,
                 topics: Iterable[str] = ("points",), frame_ids: Sequence[str] | str | None = None,
                 base_frame: str | None = None, mounts: Iterable[Mount | str] | None = None,
                 metadata: Any = None, calibration: str | os.PathLike[str] | None = None,
                 clock_offsets: dict[str, int] | None = None, start_ns: int | None = None,
                 end_ns: int | None = None, chunk_bytes: int = 4 << 20) -> None:
        from lidarpkt.vendors import registry

        super().__init__(out, capture=capture, part=part)
        groups = set(topics)
        if not groups or groups - set(TOPIC_GROUPS):
            raise OutputError(f"topics={','.join(sorted(groups))}: choose among {', '.join(TOPIC_GROUPS)}")
        sensors = SensorFrames(frame_ids, base_frame, mounts)
        self.sensor_files = registry.load_sensor_files(metadata)
        self.calibration = None if calibration is None else str(calibration)
        self.path = self.single_file()
        self._tmp = self.files.temporary(self.path)
        self.groups = groups
        self.wants_frames = bool(groups & {"points", "images"})
        self.mcap = self._open_messages(self._tmp, chunk_bytes)
        self.topics = FrameTopics(self.mcap, groups, sensors)
        self.clock_offsets = dict(clock_offsets or {})
        self.start_ns, self.end_ns = start_ns, end_ns
        self._given_times = clock_offsets is not None or start_ns is not None or end_ns is not None
        self._input: str | None = None if capture is None else str(capture)
        self._described: set[tuple] = set()
        self._capture: Any = None  # the capture being handed (begin_capture … end_capture)
        self._captures = 0
        self._times: CaptureTimes | None = None  # its times, while they are being measured
        self._sink: PacketSink | None = None
        self._sink_out: _SinkOutput | None = None
        self._pending = PendingFrames(self._tmp.parent, self.pending_bytes)
        self._unmounted: list = []  # sensors whose mount waits for the capture's start
        self.packet_messages = 0  # packet messages written (what `lidarpkt info` counts as the packets)
        self.decoded_messages = 0  # messages decoded from the packets (IMU samples...) written beside them
        if self.calibration is not None:
            self._add_calibration_record(self.calibration)

    def _open_messages(self, tmp: Path, chunk_bytes: int) -> Any:
        """Where the messages go: a :class:`~lidarpkt.writers.mcap.writer.McapWriter` on ``tmp``. The ROS bag
        writers (:mod:`lidarpkt.writers.rosbag`) give their bag files with the same methods instead."""
        from .writer import FRAMES_COMPRESSION, McapWriter

        # frames: chunks as FRAMES_COMPRESSION says and without CRCs (speed); no fsync (an output decoding
        # makes again, as the other writers' files)
        compression = FRAMES_COMPRESSION if self.wants_frames else "zstd"
        return McapWriter(tmp, chunk_seconds=float("inf"), chunk_bytes=chunk_bytes, compression=compression,
                          sync=False, chunk_crcs=not self.wants_frames)

    def _add_calibration_record(self, calibration: str) -> None:
        try:
            text = Path(calibration).read_text(encoding="utf-8", errors="replace")
        except OSError as exc:
            raise OutputError(f"calibration={calibration}: cannot read it to record it: "
                              f"{exc.strerror or exc}") from exc
        self.mcap.add_metadata("lidarpkt.calibration", {"path": calibration, "content": text})

    # ------------------------------------------------------------------ the pass
    def begin_capture(self, capture: Any) -> None:
        """The capture whose packets and frames come next (a :class:`lidarpkt.pipeline.passes.Capture`)."""
        if self._capture is not None:
            self.end_capture(self._capture)
        self._capture = capture
        self._captures += 1
        self._input = str(capture.path)
        self._sink = self._sink_out = None
        self._times = None
        if self._given_times:
            return
        span = capture.receive_span()  # an OSF file: decoded frames, no packets: the span they were received in
        if span is not None:
            self.set_capture_times({}, *span)
        else:
            self._times = CaptureTimes()

    def write_packets(self, batch: Any, stream: Any) -> None:
        """One batch of the capture in hand: its packets written (``packets`` topic), its times measured."""
        if self._capture is None:
            raise OutputError(f"{self.out}: packets come within a capture; call begin_capture(capture) first")
        files = self.sensor_files or self._capture.sensor_files
        if self._times is not None:
            self._times.add(batch, files)
            self._settle(final=False)
        if "packets" in self.groups:
            if self._sink is None:
                self._sink_out = _SinkOutput(self.mcap)
                self._sink = PacketSink(cast(McapWriter, self._sink_out), metadata=files)
            self._sink.push(batch)

    def end_capture(self, capture: Any = None) -> None:
        """The capture in hand is complete: the frames waiting for its span are written, and each new sensor's
        mount and the sensor files' latched messages at its start."""
        if self._capture is None:
            return
        self._capture = None
        times, self._times = self._times, None
        if times is not None:
            self.set_capture_times(times.offsets, times.start_ns, times.end_ns)
        self._settle(final=True)
        for sensor in self._unmounted:  # (frames come from packets: the capture has a start)
            self.topics.mount(sensor, self.start_ns or 0)
        self._unmounted.clear()
        if self._sink is not None and self._sink_out is not None:
            self._sink.finish()
            self._sink_out.release(self.start_ns or 0)
            self.decoded_messages += self._sink.decoded_messages
            self.packet_messages += self._sink_out.messages - self._sink.decoded_messages
            self._sink = self._sink_out = None

    def set_capture_times(self, clock_offsets: dict[str, int], start_ns: int | None, end_ns: int | None) -> None:
        """The clock offsets and time span of the capture whose frames come next."""
        self.clock_offsets = dict(clock_offsets)
        self.start_ns, self.end_ns = start_ns, end_ns

    def log_time(self, frame) -> int:
        return self._clamp(frame_log_time(frame, self.clock_offsets))

    def _clamp(self, t: int) -> int:
        if self.end_ns is not None:
            t = min(t, self.end_ns)
        if self.start_ns is not None:
            t = max(t, self.start_ns)
        return t

    def _settled(self, end_ns: int, source: str | None) -> bool:
        """Whether the rest of the capture can no longer change this frame's log time."""
        times = self._times
        if times is None or times.start_ns is None or times.end_ns is None:
            return False
        if not (times.offsets_final or source in times.offsets):
            return False
        return times.start_ns <= end_ns + clock_offset(source, times.offsets) <= times.end_ns

    def _settle(self, final: bool) -> None:
        """Write the waiting frames whose log time is now known (all of them at the capture's end)."""
        if not len(self._pending):
            return
        if final:
            waiting = list(self._pending.drain())
            offsets = self.clock_offsets
        else:
            waiting = self._pending.take(self._settled)
            offsets = self._times.offsets if self._times is not None else {}
        for end_ns, source, messages in waiting:
            t = end_ns + clock_offset(source, offsets)
            t = self._clamp(t) if final else t  # a settled time is inside the span
            for topic, data in messages:
                self.mcap.write(topic, data, t)

    # ------------------------------------------------------------------ frames
    def _write(self, frame) -> None:
        if "packets" in self.groups and self._capture is None and not self._captures:
            raise OutputError(f"{self.out}: topics=packets: the packets come from the pass over the capture; write "
                              "with lidarpkt.writers.write_captures([capture], [writer]), not frames alone")
        if not self.groups & {"points", "images"}:
            return
        sensor_key = (frame.sensor.vendor, frame.sensor.source, frame.sensor.model)
        if sensor_key not in self._described:  # what the frames were decoded with, once per sensor
            self._described.add(sensor_key)
            self.mcap.add_metadata("lidarpkt.frames", {
                "input": str(self._input), "sensor_info": json.dumps(frame.sensor.describe(), default=str),
                "calibration": self.calibration or "stock"})
        if self._times is None:  # the times are known: given, an OSF file's span, or none (sensor time)
            self.topics.write(frame, self.log_time(frame), self.start_ns)
            return
        sensors = self.topics.sensors
        if sensors.is_new(frame.sensor):
            sensors.frame_id(frame.sensor)  # named in order of appearance, mounted at the capture's start
            self._unmounted.append(frame.sensor)
        end_ns, source = frame_end_ns(frame), frame.sensor.source
        if self._settled(end_ns, source):
            t = end_ns + clock_offset(source, self._times.offsets)
            for topic, msg in self.topics.messages(frame):
                self.mcap.write_message(topic, msg, t)
        else:
            self._pending.add(end_ns, source, [(topic, rosmsgs.encode(topic.msgtype, msg))
                                               for topic, msg in self.topics.messages(frame)])

    def _finish(self) -> None:
        if self._capture is not None:  # a pass stopped short (damage): what it handed is written
            self.end_capture(self._capture)
        if "packets" in self.groups and not self._captures:
            raise OutputError(f"{self.out}: topics=packets: no capture was handed to the writer; write with "
                              "lidarpkt.writers.write_captures([capture], [writer])")
        self.mcap.close()
        self.files.commit(self._tmp)

    def _release(self) -> None:
        self._pending.close()
        self.mcap._abandon()  # close without a summary; the temporary is removed next


class _SinkOutput:
    """What a capture's :class:`~lidarpkt.writers.mcap.packets.PacketSink` writes to: the MCAP file, its
    messages counted; its latched messages (the sensor files', logged at the capture's start) held until
    :meth:`release` gives that start."""

    def __init__(self, mcap: McapWriter) -> None:
        self.mcap = mcap
        self.messages = 0
        self._latched: list[tuple[Topic, bytes, str]] = []

    def write(self, topic: Topic, data: bytes, log_time_ns: int, publish_time_ns: int | None = None) -> None:
        self.messages += 1
        self.mcap.write(topic, data, log_time_ns, publish_time_ns)

    def write_latched(self, topic: Topic, data: bytes, log_time_ns: int, *, key: str = "") -> None:
        self.messages += 1
        self._latched.append((topic, data, key))

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        self.mcap.add_metadata(name, data)

    def release(self, log_time_ns: int) -> None:
        for topic, data, key in self._latched:
            self.mcap.write_latched(topic, data, log_time_ns, key=key)
        self._latched.clear()
