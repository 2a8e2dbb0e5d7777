"""Raw lidar packets stored in ROS bags (rosbag2 sqlite3 or MCAP, ROS 1), read through ``rosbags``.

A ROS bag stores messages, not UDP datagrams. Topics whose message type carries raw
sensor packets are turned into :class:`~lidarpkt.core.packet.PacketBatch` objects, one per
message (every packet of a ``VelodyneScan`` has the same 1206-byte size). Each packet's
time is its own ROS stamp when the message has one (``VelodynePacket.stamp``), else the
bag's receive time; source and destination are ``None`` (a bag does not keep them).

What is extracted is decided by the message type alone, in :data:`PACKET_EXTRACTORS`:
a function from one deserialised message to ``(payloads uint8[N, L], timestamp_ns int64[N])``.
Adding a sensor's packet topic means adding one entry (and, if ROS does not ship the
type, its ``.msg`` definition to :data:`lidarpkt.containers.rosmsgs.MESSAGE_DEFINITIONS`).
"""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path
from typing import Any, Callable, Generator, Iterable, Iterator

import numpy as np

from ..errors import CaptureFormatError, LidarpktWarning, SkippedPacketWarning, TruncatedCaptureWarning
from lidarpkt.core.readahead import warn  # warnings.warn, or handed to the caller's thread when decoding ahead
from lidarpkt.core.packet import Packet, PacketBatch
from .filters import check_filters
from .inflate import bound_rosbags, bounded, inflate_rosbag2_files, needs_scope
from .magic import MCAP_MAGIC
from .mcap_records import DECOMPRESSION_ERRORS, mcap_stream_messages
from .rosbag import close_failed_open, guarded, with_default_metadata
from .rosmsgs import MESSAGE_DEFINITIONS, new_typestore  # noqa: F401 (MESSAGE_DEFINITIONS: the table, public here too)

# Topics holding the Ouster sensor metadata JSON (std_msgs/msg/String) as ouster-ros names them: its node's
# namespace (``/ouster``, ``/os_node``, ``/os_node0``, a user's own) then ``metadata``; every std_msgs/String
# topic named so is read (:func:`is_ouster_metadata_topic`), these are examples.
OUSTER_METADATA_TOPICS = ("/ouster/metadata", "/os_node/metadata", "/os_node0/metadata", "/metadata")


def is_ouster_metadata_topic(topic: str) -> bool:
    """Is ``topic`` (of type std_msgs/String) where ouster-ros records the sensor metadata: ``/metadata`` or
    any ``<namespace>/metadata``?"""
    return topic == "/metadata" or topic.endswith("/metadata")


def _stamp_ns(stamp: Any) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _velodyne_scan(msg: Any, bag_time_ns: int) -> tuple[np.ndarray, np.ndarray]:
    packets = msg.packets
    if not packets:
        return np.zeros((0, 1206), np.uint8), np.zeros(0, np.int64)
    payload = np.stack([np.asarray(p.data, dtype=np.uint8) for p in packets])
    times = np.array([_stamp_ns(p.stamp) for p in packets], dtype=np.int64)
    times[times == 0] = bag_time_ns  # drivers that leave the packet stamp empty
    return payload, times


def _velodyne_packet(msg: Any, bag_time_ns: int) -> tuple[np.ndarray, np.ndarray]:
    t = _stamp_ns(msg.stamp) or bag_time_ns
    return np.asarray(msg.data, dtype=np.uint8)[None, :], np.array([t], dtype=np.int64)


def _ouster_packet(msg: Any, bag_time_ns: int) -> tuple[np.ndarray, np.ndarray]:
    # PacketMsg has no stamp: the bag's receive (log) time is the packet's host time
    return np.asarray(msg.buf, dtype=np.uint8)[None, :], np.array([bag_time_ns], dtype=np.int64)


def _nebula_packet(msg: Any, bag_time_ns: int) -> tuple[np.ndarray, np.ndarray]:
    t = _stamp_ns(msg.stamp) or bag_time_ns
    return np.asarray(msg.data, dtype=np.uint8)[None, :], np.array([t], dtype=np.int64)


def _pandar_scan(msg: Any, bag_time_ns: int) -> tuple[np.ndarray, np.ndarray]:
    packets = msg.packets
    if not packets:
        return np.zeros((0, 0), np.uint8), np.zeros(0, np.int64)
    sizes = {int(p.size) for p in packets}
    if len(sizes) != 1:  # one sensor sends one size; a batch holds one size
        raise ValueError(f"packets of {len(sizes)} sizes ({sorted(sizes)[:4]}) in one PandarScan")
    size = sizes.pop()
    if not 0 < size <= 1500:
        raise ValueError(f"packet size {size} outside the 1500-byte buffer")
    payload = np.stack([np.asarray(p.data, dtype=np.uint8)[:size] for p in packets])
    times = np.array([_stamp_ns(p.stamp) for p in packets], dtype=np.int64)
    times[times == 0] = bag_time_ns
    return payload, times


# message type → extractor(message, bag receive time ns) → (payloads [N, L], times ns [N])
PACKET_EXTRACTORS: dict[str, Callable[[Any, int], tuple[np.ndarray, np.ndarray]]] = {
    "velodyne_msgs/msg/VelodyneScan": _velodyne_scan,
    "velodyne_msgs/msg/VelodynePacket": _velodyne_packet,
    "ouster_sensor_msgs/msg/PacketMsg": _ouster_packet,
    "ouster_ros/msg/PacketMsg": _ouster_packet,
    "nebula_msgs/msg/NebulaPacket": _nebula_packet,
    "pandar_msgs/msg/PandarScan": _pandar_scan,
}


def _normalise_type(msgtype: str) -> str:
    # ROS 1 names types "pkg/Type"; rosbags presents them as "pkg/msg/Type"
    parts = msgtype.split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else msgtype


class BagReader:
    """Packet batches from a ROS bag holding raw packet topics.

    Args:
        path: a rosbag2 directory (with ``metadata.yaml``), its ``.db3`` or ``.mcap`` file, or a ROS 1
            ``.bag``.
        topics: read only these topics (default: every topic of a known packet type).
        payload_sizes: keep only packets of these sizes.
        **filters: anything else that is not ``None`` raises: ``ports`` and ``src_addresses``
            cannot filter a bag, which records no UDP ports or addresses.

    Raises:
        UnsupportedFilterError: a filter this reader does not know or cannot apply.
        CaptureFormatError: the bag cannot be opened or decoded (message says why).
    """

    def __init__(self, path: str | os.PathLike[str], *, topics: Iterable[str] | None = None,
                 payload_sizes: Iterable[int] | None = None, **filters: Any) -> None:
        check_filters(path, "bag", filters)
        self.path = Path(path)
        self.topics = None if topics is None else frozenset(topics)
        self.payload_sizes = None if payload_sizes is None else frozenset(int(s) for s in payload_sizes)
        self.stats: dict[str, Any] = {"messages": 0, "packets": 0, "skipped_topics": {}}
        self._ouster_metadata: str | None = None
        self._metadata_topics: list | None = None  # set by batches(): metadata topics not read yet ([MCAP_MAGIC]: a plain MCAP)
        self._metadata_scanned = False
        self._metadata_dir: Any = None  # a TemporaryDirectory holding a completed metadata.yaml, if one was needed

    def ouster_metadata(self) -> str | None:
        """The Ouster metadata JSON text recorded in the bag (``/ouster/metadata``, ``/os_node0/metadata``...);
        ``None`` if there is none.

        Once :meth:`batches` has started on a ROS bag (not a plain MCAP file, read as one stream), the
        metadata topics are read ahead of the packets if need be: ouster-ros records the metadata after the
        first packets, which would otherwise reach the caller before their metadata does.
        """
        if self._ouster_metadata is None and self._metadata_topics is not None:
            topics, self._metadata_topics = self._metadata_topics, None
            if topics == [MCAP_MAGIC]:
                self._ouster_metadata = self._scan_mcap_metadata()
            elif topics:
                self._metadata_scanned = True
                self._ouster_metadata = self._scan_metadata(topics)
        return self._ouster_metadata

    def _scan_mcap_metadata(self) -> str | None:
        """The first Ouster metadata message within the first :data:`MCAP_METADATA_LOOKAHEAD_BYTES` of a plain
        MCAP file, read as a stream of its own; ``None`` if there is none there, or damage comes first (which
        the pass over the packets reports)."""
        from mcap.exceptions import McapError

        from .rosmsgs import typestore

        store = typestore()
        with self.path.open("rb") as fh:
            try:
                for schema, channel, message in mcap_stream_messages(fh, self.path):
                    if fh.tell() > MCAP_METADATA_LOOKAHEAD_BYTES:
                        return None
                    if (schema is None or channel.message_encoding != "cdr" or schema.name not in
                            ("std_msgs/msg/String", "std_msgs/String") or not is_ouster_metadata_topic(channel.topic)):
                        continue
                    text = store.deserialize_cdr(message.data, "std_msgs/msg/String").data
                    found = self._metadata_text(channel.topic, text)
                    if found is not None:
                        self._metadata_scanned = True
                        return found
            except (McapError, CaptureFormatError, struct.error, EOFError, ValueError, OverflowError,
                    OSError) + DECOMPRESSION_ERRORS:
                return None
        return None

    def _scan_metadata(self, topics: list[str]) -> str | None:
        """The first Ouster metadata among the messages of ``topics``, read by a reader of their own (beside the
        one reading the packets, whose completed metadata.yaml folder, if any, stays theirs)."""
        import warnings

        packets_dir, self._metadata_dir = self._metadata_dir, None
        try:
            with warnings.catch_warnings():  # what opening the bag warns of, the packets' reader said already
                warnings.simplefilter("ignore", LidarpktWarning)
                reader = self._open()
        except BaseException:
            self._metadata_dir = packets_dir
            raise
        try:
            conns = [c for c in reader.connections if c.topic in topics
                     and _normalise_type(c.msgtype) == "std_msgs/msg/String"]
            for conn, bag_time_ns, raw in guarded(reader.messages(connections=conns), self.path, needs_scope(reader)):
                try:
                    text = reader.deserialize(raw, conn.msgtype).data
                except Exception as exc:
                    raise CaptureFormatError(
                        f"{self.path}: message on {conn.topic} ({conn.msgtype}) at {bag_time_ns} ns cannot be "
                        f"decoded: {exc}") from None
                found = self._metadata_text(conn.topic, text)
                if found is not None:
                    return found
            return None
        finally:
            reader.close()
            self._cleanup_metadata_dir()
            self._metadata_dir = packets_dir

    def _metadata_text(self, topic: str, text: str) -> str | None:
        """``text`` if it is a JSON object, as Ouster metadata is; else ``None`` and a warning. Callers hand
        it to ``load_metadata``, which reads other text as the path of a file."""
        try:
            doc = json.loads(text)
            reason = f"a JSON {type(doc).__name__}, not an object"
        except (ValueError, RecursionError) as exc:  # not JSON; an int of > 4300 digits; nested too deep
            doc, reason = None, f"not JSON: {str(exc)[:80]}"
        if isinstance(doc, dict):
            return text
        warn(SkippedPacketWarning(
            f"{self.path}: the message on {topic} is not Ouster metadata ({reason}; it starts with {text[:40]!r}); "
            "ignored. Pass the sensor's metadata JSON (metadata=... / --metadata) to decode its packets"))
        return None

    def _wanted(self, topic: str, msgtype: str) -> bool:
        kind = _normalise_type(msgtype)
        if kind == "std_msgs/msg/String":
            return is_ouster_metadata_topic(topic)
        return kind in PACKET_EXTRACTORS and (self.topics is None or topic in self.topics)

    def _is_mcap_file(self) -> bool:
        if not self.path.is_file():
            return False
        with self.path.open("rb") as fh:
            return fh.read(len(MCAP_MAGIC)) == MCAP_MAGIC

    def _bag_paths(self) -> list[Path]:
        p = self.path
        if p.is_file() and p.suffix == ".db3" and (p.parent / "metadata.yaml").exists():
            p = p.parent  # rosbags opens a rosbag2 by its directory
        if p.is_dir() and (p / "metadata.yaml").is_file():
            patched = with_default_metadata(p)
            if patched is not None:
                self._metadata_dir, notes = patched
                warn(LidarpktWarning(f"{p}: metadata.yaml {notes}; read it so (an old rosbag2 writer left the "
                                     "field empty)"))
                return [Path(self._metadata_dir.name)]
        return [p]

    def _cleanup_metadata_dir(self) -> None:
        if self._metadata_dir is not None:
            self._metadata_dir.cleanup()
            self._metadata_dir = None

    def _open(self):
        from rosbags.highlevel import AnyReader

        store = new_typestore()
        reader = None
        try:
            reader = AnyReader(self._bag_paths(), default_typestore=store)
            with bounded(self.path):  # opening scans the chunks of a rosbag2's MCAP storage
                inflate_rosbag2_files(reader, self.path)
                reader.open()
            bound_rosbags(reader, self.path)  # ROS 1 chunks and rosbag2 messages inflate into a bounded size
        except Exception as exc:  # rosbags raises its own error types (AnyReaderError, ...)
            close_failed_open(reader, exc)
            self._cleanup_metadata_dir()
            if isinstance(exc, CaptureFormatError):
                raise
            raise CaptureFormatError(f"{self.path}: cannot open as a ROS bag: {exc}") from None
        return reader

    def batches(self) -> Iterator[PacketBatch]:
        """One batch per message of a packet topic, in bag time order (MCAP files: file order);
        ``index`` counts packets."""
        count = 0
        messages = self._mcap_messages() if self._is_mcap_file() else self._rosbags_messages()
        try:
            for topic, msgtype, bag_time_ns, msg in messages:
                kind = _normalise_type(msgtype)
                if kind == "std_msgs/msg/String":
                    if self._ouster_metadata is None and not self._metadata_scanned:
                        self._ouster_metadata = self._metadata_text(topic, msg.data)
                    continue
                if bag_time_ns >= 1 << 63:  # MCAP log times are uint64; packet times are int64 ns
                    raise CaptureFormatError(
                        f"{self.path}: the message on {topic} has the bag time {bag_time_ns} ns, more than a time can "
                        "hold (int64 ns, past the year 2262): the bag is damaged there")
                try:
                    payload, times = PACKET_EXTRACTORS[kind](msg, int(bag_time_ns))
                except (AttributeError, TypeError, ValueError, OverflowError) as exc:  # a bag's own definition of the type
                    raise CaptureFormatError(
                        f"{self.path}: the message on {topic} ({msgtype}) has not the fields lidarpkt reads for that "
                        f"type ({type(exc).__name__}: {exc}); the bag's definition of {kind} differs") from None
                self.stats["messages"] += 1
                if payload.shape[0] == 0:
                    continue
                if self.payload_sizes is not None and payload.shape[1] not in self.payload_sizes:
                    continue
                batch = PacketBatch.from_payloads(payload, times, first_index=count)
                count += len(batch)
                self.stats["packets"] += len(batch)
                yield batch
        finally:  # now, not when an error raised here (and the frames it keeps) is dropped: the bag's file closes
            messages.close()

    def packets(self) -> Iterator[Packet]:
        """Every packet of :meth:`batches`, one by one, in the same order (no addresses: ``src``/``dst`` None)."""
        for batch in self.batches():
            yield from batch.packets()

    def _rosbags_messages(self) -> Generator[tuple[str, str, int, Any], None, None]:
        reader = self._open()
        try:
            conns = []
            for c in reader.connections:
                if self._wanted(c.topic, c.msgtype):
                    conns.append(c)
                else:
                    self.stats["skipped_topics"][c.topic] = c.msgtype
            if not conns:
                return  # (rosbags reads no connections as all of them)
            self._metadata_topics = [c.topic for c in conns if _normalise_type(c.msgtype) == "std_msgs/msg/String"]
            for conn, bag_time_ns, raw in guarded(reader.messages(connections=conns), self.path,
                                                      needs_scope(reader)):
                try:
                    msg = reader.deserialize(raw, conn.msgtype)
                except Exception as exc:
                    raise CaptureFormatError(
                        f"{self.path}: message on {conn.topic} ({conn.msgtype}) at {bag_time_ns} ns cannot be "
                        f"decoded: {exc}") from None
                yield conn.topic, conn.msgtype, int(bag_time_ns), msg
        finally:
            reader.close()
            self._cleanup_metadata_dir()

    def _mcap_messages(self) -> Generator[tuple[str, str, int, Any], None, None]:
        """Messages of a plain MCAP file (no rosbag2 metadata.yaml needed), in file order.

        Read record by record, so a file whose writer was killed (no summary, a cut last
        chunk) yields everything up to the damage and then a :class:`TruncatedCaptureWarning`.
        """
        from mcap.exceptions import McapError
        from rosbags.typesys import get_types_from_msg

        store = new_typestore()
        known: dict[int, bool] = {}
        n = 0
        self._metadata_topics = [MCAP_MAGIC]  # ouster_metadata(): look ahead in the file (see there)
        with self.path.open("rb") as fh:
            it = mcap_stream_messages(fh, self.path)
            while True:
                try:
                    schema, channel, message = next(it)
                except StopIteration:
                    return
                except (McapError, struct.error, EOFError, ValueError, OverflowError, OSError) + DECOMPRESSION_ERRORS as exc:  # OverflowError: a record length of 2**63 or more in a chunk
                    warn(TruncatedCaptureWarning(
                        f"{self.path}: the MCAP file is cut short or damaged after {n} messages ({exc}); the "
                        "messages before the damage were read (a recording that was killed ends like this)"))
                    return
                wanted = known.get(channel.id)
                if wanted is None:
                    msgtype = schema.name if schema is not None else ""
                    wanted = (schema is not None and channel.message_encoding == "cdr"
                              and self._wanted(channel.topic, msgtype))
                    if wanted and msgtype not in store.types:
                        try:
                            store.register(get_types_from_msg(schema.data.decode(), msgtype))
                        except Exception as exc:
                            raise CaptureFormatError(
                                f"{self.path}: the schema of {msgtype} on {channel.topic} cannot be parsed: {exc}"
                            ) from None
                    if not wanted:
                        self.stats["skipped_topics"][channel.topic] = msgtype
                    known[channel.id] = wanted
                if not wanted:
                    continue
                n += 1
                try:
                    msg = store.deserialize_cdr(message.data, schema.name)
                except Exception as exc:
                    raise CaptureFormatError(
                        f"{self.path}: message on {channel.topic} ({schema.name}) at {message.log_time} ns cannot "
                        f"be decoded: {exc}") from None
                yield channel.topic, schema.name, int(message.log_time), msg


# ouster-ros records its metadata a few packets after the start; a plain MCAP file (read as one stream) is
# searched this far for it when the packets come first
MCAP_METADATA_LOOKAHEAD_BYTES = 64 << 20
