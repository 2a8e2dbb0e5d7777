"""Ouster frames from OSF files (ouster-sdk's recordings of decoded frames): ``lidarpkt.open("x.osf")`` gives
:class:`OsfReader`. The file itself (blocks, chunks, the field images) is read by
:mod:`lidarpkt.containers.osf`; this module gives its stored fields their Ouster meaning.

Each sensor entry holds the sensor's metadata JSON (:func:`~lidarpkt.vendors.ouster.metadata_json.load_metadata`). A
frame message (``LidarScanMsg``) carries per-column arrays (timestamp, measurement id, status), per-packet
ones (packet timestamp, alert flags), frame scalars (frame id, frame status, countdowns) and its fields.

Frames come out as ouster-sdk's ``OsfFrameSetSource`` gives them (by receive time across the
sensors' streams), as :class:`~lidarpkt.core.frame.Frame` s like those decoded from the sensor's packets
(columns by measurement id): ``range_mm``, ``reflectivity``, ``signal``, ``flags`` (``[R, H, W]``, R = 2
when the file stores the second return), ``near_ir``; ``column_timestamp_ns``, ``measurement_id``,
``status``; ``column_valid`` = status bit 0. Every other field the file stores is in ``frame.extra``
under its name in lower case (``zone_mask``, ``window``, ``zone_states``...), and so are the packet header
values, one per column as in frames decoded from packets (the value of the column's packet; the file keeps
them per packet or per frame): ``alert_flags``, ``thermal_shutdown``, ``shot_limiting``,
``countdown_thermal_shutdown``, ``countdown_shot_limiting`` (``uint8[W]``) and ``packet_timestamp_ns``
(``uint64[W]``, the host time the packet was received); and ``pose`` (``float64[4, 4, W]``, only when the
file stores one). ``partial`` is True when a column of the sensor's column window is not valid.

A damaged chunk or frame is a :class:`~lidarpkt.errors.CaptureFormatError` naming the file, after the frames
before it.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Generator, Iterator

import numpy as np

from lidarpkt.containers.osf.format import Damaged, root_table
from lidarpkt.containers.osf.reader import DAMAGED, FrameFile, FrameStream, stored_fields
from lidarpkt.core.frame import Frame, FrameCounters
from lidarpkt.core.sensor import SensorInfo
from lidarpkt.core.sequence import FrameIterator
from lidarpkt.errors import CaptureFormatError, LidarpktError
from .metadata import OusterMetadata
from .metadata_json import load_metadata

# Frame attribute of each standard channel, by return slot (the rest go to Frame.extra)
_FRAME_ATTRS = {"RANGE": ("range_mm", 0), "RANGE2": ("range_mm", 1), "REFLECTIVITY": ("reflectivity", 0),
                "REFLECTIVITY2": ("reflectivity", 1), "SIGNAL": ("signal", 0), "SIGNAL2": ("signal", 1),
                "FLAGS": ("flags", 0), "FLAGS2": ("flags", 1), "NEAR_IR": ("near_ir", None)}
_ATTR_DTYPES = {"range_mm": np.uint32, "reflectivity": np.uint8, "signal": np.uint16, "flags": np.uint8,
                "near_ir": np.uint16}



@dataclass
class OsfStream:
    """One sensor's frame stream: the stored stream, its sensor's metadata and :class:`SensorInfo`."""

    stored: FrameStream
    metadata: OusterMetadata
    sensor: SensorInfo

    @property
    def stream_id(self) -> int:
        return self.stored.stream_id


class OsfFile:
    """An OSF file's sensors (their metadata) and frames (:meth:`frames`); ``file`` is the stored file.

    Args:
        path: the ``.osf`` file.

    Raises:
        CaptureFormatError: what :class:`~lidarpkt.containers.osf.reader.FrameFile` raises, or sensor
            metadata that lidarpkt cannot read (the message says which).
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self.file = FrameFile(path)
        self.streams: list[OsfStream] = []
        try:
            for stored in self.file.streams:
                try:
                    md = load_metadata(stored.sensor_text)
                except LidarpktError as exc:
                    raise CaptureFormatError(f"{self.path}: the sensor metadata stored in the OSF file: {exc}") from None
                source = f"{self.path.name} (sensor {md.serial or stored.sensor_id})"
                self.streams.append(OsfStream(stored, md, md.sensor_info(source)))
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        self.file.close()

    @property
    def version_text(self) -> str:
        """The OSF version as ``"major.minor.patch"``."""
        return self.file.version_text

    def frames(self) -> Iterator[Frame]:
        """Every frame of every sensor, by receive time (ties: stream order), as ouster-sdk gives them.

        Raises:
            CaptureFormatError: a chunk or a frame message is damaged (after the frames before it).
        """
        by_id = {s.stream_id: s for s in self.streams}
        merged = self.file.messages_by_time()
        while True:
            try:
                item = next(merged, None)
                if item is None:
                    return
                frame = decode_frame(item[2], by_id[item[1]])
            except Damaged as exc:
                raise CaptureFormatError(f"{self.path}: {DAMAGED}: {exc}") from None
            except (struct.error, ValueError, IndexError, OverflowError, UnicodeDecodeError) as exc:
                raise CaptureFormatError(f"{self.path}: {DAMAGED} ({type(exc).__name__}: {exc})") from None
            yield frame

    def describe(self) -> dict[str, Any]:
        """A JSON-ready summary (``lidarpkt info``), read from the chunks without decoding a field: the OSF
        version and, per sensor, what it is and its frames (count, frame ids, receive times, ns).

        Raises:
            CaptureFormatError: a chunk or frame message is damaged.
        """
        sensors = []
        try:
            for stream in self.streams:
                ids, times, partial = [], [], 0
                window = stream.metadata.window_mask
                for ts, _, buf in self.file.messages(stream.stored):
                    msg = root_table(buf, "LidarScanMsg")
                    ids.append(int(msg.frame_id))
                    times.append(ts)
                    status = msg.header_status
                    partial += status is None or status.size != window.size or not (status[window] & 1).all()
                s = stream.sensor
                sensors.append({
                    "source": s.source, "model": s.model, "serial": s.serial, "firmware": s.firmware,
                    "profile": s.profile, "columns_per_frame": s.columns_per_frame, "rows": s.rows,
                    "frames": len(ids), "partial_frames": int(partial),
                    "frame_ids": [min(ids), max(ids)] if ids else None,
                    "first_timestamp_ns": min(times) if times else None,
                    "last_timestamp_ns": max(times) if times else None})
        except Damaged as exc:
            raise CaptureFormatError(f"{self.path}: {DAMAGED}: {exc}") from None
        except (struct.error, ValueError, IndexError, OverflowError) as exc:
            raise CaptureFormatError(f"{self.path}: {DAMAGED} ({type(exc).__name__}: {exc})") from None
        return {"osf_version": self.version_text, "sensors": sensors}


def decode_frame(buf: bytes, stream: OsfStream) -> Frame:
    """One ``LidarScanMsg`` (size-prefixed) of ``stream`` as a :class:`~lidarpkt.core.frame.Frame` (see the module).

    Raises:
        Damaged: the message or one of its fields is damaged.
    """
    md = stream.metadata
    h, w = md.pixels_per_column, md.columns_per_frame
    msg = root_table(buf, "LidarScanMsg")

    def per_column(name: str, dtype) -> np.ndarray:
        values = getattr(msg, name)
        if values is None or values.size == 0:
            return np.zeros(w, dtype)
        if values.size != w:
            raise Damaged(f"{name} of a frame has {values.size} columns, not the sensor's {w}")
        return values.astype(dtype)

    timestamp = per_column("header_timestamp", np.uint64)
    if (timestamp >> np.uint64(63)).any():
        raise Damaged("a column timestamp is beyond 2**63 ns")
    status = per_column("header_status", np.uint32)
    # the packet header values the file keeps (one per packet, or per frame) as the frames decoded from
    # packets hold them: one per column, the value of the column's packet
    per_packet = max(1, md.columns_per_packet)
    n_packets = -(-w // per_packet)
    extra: dict[str, np.ndarray] = {}
    for stored, key, kind in (("packet_timestamp", "packet_timestamp_ns", np.uint64), ("alert_flags", "alert_flags", np.uint8)):
        values = getattr(msg, stored)
        if values is not None and values.size not in (0, n_packets):
            raise Damaged(f"{stored} of a frame has {values.size} values, not one per packet ({n_packets})")
        values = values.astype(kind) if values is not None and values.size else np.zeros(n_packets, kind)
        extra[key] = np.repeat(values, per_packet)[:w]
    status_bits = int(msg.frame_status)  # ouster-sdk's frame_status: thermal shutdown bits 0-3, shot limiting 4-7
    for key, value in (("thermal_shutdown", status_bits & 0x0F), ("shot_limiting", status_bits >> 4 & 0x0F),
                       ("countdown_thermal_shutdown", msg.shutdown_countdown),
                       ("countdown_shot_limiting", msg.shot_limiting_countdown)):
        extra[key] = np.full(w, value, np.uint8)
    pose = msg.pose
    if pose is not None and pose.size:
        if pose.size != 16 * w:
            raise Damaged(f"the pose of a frame has {pose.size} values, not 16 per column ({16 * w})")
        extra["pose"] = np.ascontiguousarray(pose.reshape(w, 4, 4).transpose(1, 2, 0))

    fields = stored_fields(msg, h, w, md.pixel_shift_by_row)

    # the standard channels become the frame's attributes, in the types frames decoded from packets have
    # (an older ouster-sdk stored REFLECTIVITY of RNG15_RFL8_NIR8 as uint16): a value that does not fit keeps
    # the type it was stored in
    planes: dict[str, dict[Any, np.ndarray]] = {}
    for name, (attr, slot) in _FRAME_ATTRS.items():
        if name in fields:
            values = fields.pop(name)
            target = np.dtype(_ATTR_DTYPES[attr])
            fits = values.dtype.kind == "u" and (values.size == 0 or int(values.max()) <= np.iinfo(target).max)
            planes.setdefault(attr, {})[slot] = values.astype(target, copy=False) if fits else values
    returns = 2 if any(1 in slots for slots in planes.values()) else 1
    frame_kw: dict[str, Any] = {"near_ir": planes.get("near_ir", {}).get(None)}
    for attr in ("range_mm", "reflectivity", "signal", "flags"):
        slots = planes.get(attr)
        if slots is None:  # absent: zeros for the two a frame always has (no return), else None
            frame_kw[attr] = np.zeros((returns, h, w), _ATTR_DTYPES[attr]) if attr in ("range_mm", "reflectivity") else None
            continue
        dtype = np.result_type(*slots.values())
        frame_kw[attr] = np.stack([slots[r].astype(dtype, copy=False) if r in slots else np.zeros((h, w), dtype)
                                   for r in range(returns)])
    for name, values in fields.items():
        extra[name.lower()] = values
    valid = (status & 1).astype(bool)
    labels = tuple(stream.sensor.return_labels[:returns])
    labels += tuple(f"return_{r + 1}" for r in range(len(labels), returns))
    return Frame(
        sensor=stream.sensor,
        frame_id=int(msg.frame_id),
        return_labels=labels,
        column_valid=valid,
        column_timestamp_ns=timestamp.astype(np.int64),
        azimuth_deg=np.mod(360.0 * (1.0 - np.arange(w) / w), 360.0),
        measurement_id=per_column("header_measurement_id", np.uint16),
        status=status,
        partial=not bool(valid[md.window_mask].all()),
        counters=FrameCounters(),
        extra=extra,
        **frame_kw,
    )


class OsfReader(FrameIterator):
    """The frames of an OSF file (``lidarpkt.open("x.osf")``); ``file`` is its :class:`OsfFile`.

    ``stats`` counts the frames (its ``frames``: the caller's counts, ``lidarpkt.open``'s
    :class:`~lidarpkt.core.streams.SourceStats`); ``decoders`` is empty (no packets are decoded).
    ``include_partial``: also the frames with a column of the column window not valid (left out by
    default, as from packets).

    Raises:
        CaptureFormatError: see :class:`OsfFile`; while iterating, a damaged chunk or frame.
    """

    def __init__(self, path: str | os.PathLike[str], stats: Any, *, include_partial: bool = False) -> None:
        self.path = Path(path)
        self.file = OsfFile(path)
        self.stats = stats
        self.decoders: dict = {}
        self._include_partial = include_partial
        self._iter: Generator[Frame, None, None] = self._frames()

    def _frames(self) -> Generator[Frame, None, None]:
        try:
            for frame in self.file.frames():
                if frame.partial and not self._include_partial:
                    continue
                self.stats.frames += 1
                yield frame
        finally:
            self.file.close()

    def sensors(self) -> list:
        """The :class:`~lidarpkt.core.sensor.SensorInfo` of each sensor the file holds."""
        return [s.sensor for s in self.file.streams]

    def close(self) -> None:
        self._iter.close()
        self.file.close()


def receive_span(path: str | os.PathLike[str]) -> tuple[int | None, int | None]:
    """First and last receive time (ns) of the frames of an OSF file; ``(None, None)`` when it has none."""
    f = OsfFile(path)
    try:
        sensors = f.describe()["sensors"]
    finally:
        f.close()
    firsts = [s["first_timestamp_ns"] for s in sensors if s["first_timestamp_ns"] is not None]
    lasts = [s["last_timestamp_ns"] for s in sensors if s["last_timestamp_ns"] is not None]
    return (min(firsts), max(lasts)) if firsts else (None, None)
