"""Raw lidar packets stored in ROS bags (rosbag2 sqlite3 or MCAP, ROS 1), read through ``rosbags``.

A ROS bag stores messages, not UDP datagrams. Topics whose message type carries raw
sensor packets are turned into :class:`~lidarpkt.core.packet.PacketBatch` objects, one per
message (every packet of a ``VelodyneScan`` has the same 1206-byte size). Each packet's
time is its own ROS stamp when the message has one (``VelodynePacket.stamp``), else the
bag's receive time; source and destination are ``None`` (a bag does not keep them).

What is extracted is decided by the message type alone, from the table the caller hands the reader
(:class:`~lidarpkt.containers.rosmsgs.BagMessages`, the vendor registry's): a function from one
deserialised message to ``(payloads uint8[N, L], timestamp_ns int64[N])`` per packet type, the ``.msg``
definitions of the types ROS does not ship, and the ``std_msgs/String`` topics where a driver records
its sensor file (read as the file's text, :meth:`BagReader.recorded_sensor_file`).
"""

from __future__ import annotations

import os
import struct
from pathlib import Path
from typing import Any, Generator, Iterable, Iterator


from ..errors import CaptureFormatError, LidarpktWarning, SkippedPacketWarning, TruncatedCaptureWarning
from lidarpkt.core.readahead import warn  # warnings.warn, or handed to the caller's thread when decoding ahead
from lidarpkt.core.packet import Packet, PacketBatch
from .filters import check_filters
from .inflate import bound_rosbags, bounded, inflate_rosbag2_files, needs_scope
from .magic import MCAP_MAGIC
from .mcap_records import DECOMPRESSION_ERRORS, mcap_stream_messages
from .rosbag import close_failed_open, guarded, with_default_metadata
from .rosmsgs import STRING, BagMessages, new_typestore

def _normalise_type(msgtype: str) -> str:
    # ROS 1 names types "pkg/Type"; rosbags presents them as "pkg/msg/Type"
    parts = msgtype.split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else msgtype


class BagReader:
    """Packet batches from a ROS bag holding raw packet topics.

    Args:
        path: a rosbag2 directory (with ``metadata.yaml``), its ``.db3`` or ``.mcap`` file, or a ROS 1
            ``.bag``.
        messages: the packet message types read and the topics holding sensor files (the vendor
            registry's, :func:`lidarpkt.vendors.registry.bag_messages`); by default only the stamped
            packets no vendor owns.
        topics: read only these topics (default: every topic of a known packet type).
        payload_sizes: keep only packets of these sizes.
        **filters: anything else that is not ``None`` raises: ``ports`` and ``src_addresses``
            cannot filter a bag, which records no UDP ports or addresses.

    Raises:
        UnsupportedFilterError: a filter this reader does not know or cannot apply.
        CaptureFormatError: the bag cannot be opened or decoded (message says why).
    """

    def __init__(self, path: str | os.PathLike[str], *, messages: BagMessages | None = None,
                 topics: Iterable[str] | None = None, payload_sizes: Iterable[int] | None = None, **filters: Any) -> None:
        check_filters(path, "bag", filters)
        self.path = Path(path)
        self.messages = messages if messages is not None else BagMessages()
        self.topics = None if topics is None else frozenset(topics)
        self.payload_sizes = None if payload_sizes is None else frozenset(int(s) for s in payload_sizes)
        self.stats: dict[str, Any] = {"messages": 0, "packets": 0, "skipped_topics": {}}
        self._sensor_file: str | None = None
        self._metadata_topics: list | None = None  # set by batches(): sensor file topics not read yet ([MCAP_MAGIC]: a plain MCAP)
        self._metadata_scanned = False
        self._metadata_dir: Any = None  # a TemporaryDirectory holding a completed metadata.yaml, if one was needed

    def recorded_sensor_file(self) -> str | None:
        """The text of the sensor file a driver recorded in the bag (on a ``std_msgs/String`` topic of
        :attr:`messages`' sensor file topics); ``None`` if there is none.

        Once :meth:`batches` has started on a ROS bag (not a plain MCAP file, read as one stream), those
        topics are read ahead of the packets if need be: a driver may record the file after the first
        packets, which would otherwise reach the caller before their sensor file does.
        """
        if self._sensor_file is None and self._metadata_topics is not None:
            topics, self._metadata_topics = self._metadata_topics, None
            if topics == [MCAP_MAGIC]:
                self._sensor_file = self._scan_mcap_metadata()
            elif topics:
                self._metadata_scanned = True
                self._sensor_file = self._scan_metadata(topics)
        return self._sensor_file

    def _scan_mcap_metadata(self) -> str | None:
        """The first sensor file message within the first :data:`MCAP_METADATA_LOOKAHEAD_BYTES` of a plain
        MCAP file, read as a stream of its own; ``None`` if there is none there, or damage comes first (which
        the pass over the packets reports)."""
        from mcap.exceptions import McapError

        from .rosmsgs import typestore

        store = typestore()  # std_msgs/String: no definition of the caller's needed
        with self.path.open("rb") as fh:
            try:
                for schema, channel, message in mcap_stream_messages(fh, self.path):
                    if fh.tell() > MCAP_METADATA_LOOKAHEAD_BYTES:
                        return None
                    if (schema is None or channel.message_encoding != "cdr" or schema.name not in
                            (STRING, "std_msgs/String") or self.messages.sensor_file_topic(channel.topic) is None):
                        continue
                    text = store.deserialize_cdr(message.data, STRING).data
                    found = self._metadata_text(channel.topic, text)
                    if found is not None:
                        self._metadata_scanned = True
                        return found
            except (McapError, CaptureFormatError, struct.error, EOFError, ValueError, OverflowError,
                    OSError) + DECOMPRESSION_ERRORS:
                return None
        return None

    def _scan_metadata(self, topics: list[str]) -> str | None:
        """The first sensor file among the messages of ``topics``, read by a reader of their own (beside the
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
                     and _normalise_type(c.msgtype) == STRING]
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
        """``text`` if it is the sensor file the topic holds; else ``None`` and a warning (a sensor file
        topic with something else on it)."""
        kind = self.messages.sensor_file_topic(topic)
        reason = "no sensor file topic" if kind is None else kind.refusal(text)
        if reason is None:
            return text
        warn(SkippedPacketWarning(
            f"{self.path}: the message on {topic} is not {kind.what if kind else 'a sensor file'} ({reason}; it "
            f"starts with {text[:40]!r}); ignored. Pass the sensor's file (metadata=... / --metadata) to decode "
            "its packets"))
        return None

    def _wanted(self, topic: str, msgtype: str) -> bool:
        kind = _normalise_type(msgtype)
        if kind == STRING:
            return self.messages.sensor_file_topic(topic) is not None
        return kind in self.messages.packets and (self.topics is None or topic in self.topics)

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

        store = new_typestore(self.messages.definitions)
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
            raise CaptureFormatError(f"{self.path}: cannot open as a ROS bag: {_plain(exc)}{_reindex_hint(self.path)}") from None
        return reader

    def batches(self) -> Iterator[PacketBatch]:
        """One batch per message of a packet topic, in bag time order (MCAP files: file order);
        ``index`` counts packets."""
        count = 0
        messages = self._mcap_messages() if self._is_mcap_file() else self._rosbags_messages()
        try:
            for topic, msgtype, bag_time_ns, msg in messages:
                kind = _normalise_type(msgtype)
                if kind == STRING:
                    if self._sensor_file is None and not self._metadata_scanned:
                        self._sensor_file = self._metadata_text(topic, msg.data)
                    continue
                if bag_time_ns >= 1 << 63:  # MCAP log times are uint64; packet times are int64 ns
                    raise CaptureFormatError(
                        f"{self.path}: the message on {topic} has the bag time {bag_time_ns} ns, more than a time can "
                        "hold (int64 ns, past the year 2262): the bag is damaged there")
                try:
                    payload, times = self.messages.packets[kind](msg, int(bag_time_ns))
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
            self._metadata_topics = [c.topic for c in conns if _normalise_type(c.msgtype) == STRING]
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

        store = new_typestore(self.messages.definitions)
        known: dict[int, bool] = {}
        n = 0
        self._metadata_topics = [MCAP_MAGIC]  # recorded_sensor_file(): look ahead in the file (see there)
        with self.path.open("rb") as fh:
            it = mcap_stream_messages(fh, self.path)
            while True:
                try:
                    schema, channel, message = next(it)
                except StopIteration:
                    return
                except (McapError, struct.error, EOFError, ValueError, OverflowError, OSError) + DECOMPRESSION_ERRORS as exc:  # OverflowError: a record length of 2**63 or more in a chunk
                    why = str(exc) or type(exc).__name__
                    warn(TruncatedCaptureWarning(
                        f"{self.path}: the MCAP file is cut short or damaged after {n} message{'s' * (n != 1)} ({why}); "
                        "the messages before the damage were read (a recording that was killed ends like this; "
                        f"lidarpkt export {self.path} -o FOLDER --format mcap writes a whole copy)"))
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


# a driver may record its sensor file a few packets after the start (ouster-ros does); a plain MCAP file (read as one stream) is
# searched this far for it when the packets come first
MCAP_METADATA_LOOKAHEAD_BYTES = 64 << 20


def _plain(exc: BaseException) -> str:
    """An error's message in words: rosbags wraps its causes' argument tuples (``"...: ('Header could not be
    read from file.',)"``); their text is kept, the tuple's parentheses and quotes are not."""
    import re

    text = str(exc) or type(exc).__name__
    return re.sub(r"\(\s*(['\"])(.*?)\1,?\s*\)", r"\2", text).rstrip(".")


def _reindex_hint(path: Path) -> str:
    """What to do with a ROS 1 bag that cannot be opened: one cut short (a recording that was killed) has no index."""
    if str(path).lower().endswith(".bag"):
        return ("; a ROS 1 bag cut short (a recording that was killed) has no index: rebuild it with rosbag reindex "
                "(ROS 1), then read it again")
    return "; check the bag with ros2 bag info"

