"""ROS bags of a capture: a ROS 1 ``.bag`` or a rosbag2 folder, written with rosbags.

``lidarpkt decode drive.pcap -o drive.bag`` (ROS 1) and ``lidarpkt decode drive.pcap -o drive.rosbag2``
(a rosbag2 folder; ``--storage sqlite3``, the default, or ``--storage mcap``), or ``export --format
rosbag1|rosbag2``, or from Python::

    with open_writer("rosbag2", "drive.rosbag2", storage="mcap", topics=("packets", "points")) as w:
        write_captures(["drive.pcap"], [w])     # one pass: the packets and the frames (what decode writes)

A bag holds what lidarpkt's MCAP output holds (:mod:`lidarpkt.writers.mcap.frames`; the topics,
message types and QoS are listed in :mod:`lidarpkt.writers.mcap.schemas`): the capture's raw packets
as the ROS drivers publish them, the IMU samples, each frame's ``sensor_msgs/PointCloud2`` per return
slot (and ``sensor_msgs/Image`` with ``topics`` ``images``), the GPS and ``/tf_static``. The messages
are built once, by the MCAP writer's code, as ROS 2 (CDR) messages; a writer here only stores them:

* **rosbag2** stores the CDR bytes as they are: in an SQLite file ``NAME_0.db3`` through rosbags'
  writer, or in an MCAP file ``NAME_0.mcap`` (the ``ros2`` profile lidarpkt's MCAP output already
  has, which is rosbag2's MCAP storage), beside a ``metadata.yaml`` (version 8) giving each topic's
  type, QoS and message count. lidarpkt's metadata records (``lidarpkt.sensor``, ``lidarpkt.frames``,
  ``lidarpkt.calibration``) go to its ``custom_data`` as JSON.
* **ROS 1** converts each message to ROS 1 serialisation (rosbags' ``cdr_to_ros1``: ``Header`` gains
  its ``seq``, 0) and stores it with ROS 1 definitions (ROS 1's ``std_msgs/Header``, so the MD5 sums
  are ROS 1's: ``sensor_msgs/PointCloud2`` is ``1158d486dd51d683ce2f1be655c3c181``); latched topics
  (``/tf_static``, ``/ouster/metadata``) have ``latching=1``. A ROS 1 bag has no place for the
  metadata records.

Times: a message's bag time is its MCAP log time (the host time its packet was received; a frame's,
when its last packet was), inside the capture's span; ``header.stamp`` is the sensor's time.

The output is written under a temporary name (a hidden file, or folder, beside it) and renamed when
complete; an existing rosbag2 folder is never written into.
"""

from __future__ import annotations

import functools
import json
import os
from pathlib import Path
from typing import Any, Iterable, Sequence

from lidarpkt.containers import rosmsgs
from lidarpkt.errors import OutputError

from .base import WRITE_ERRORS, failure_text
from .mcap import schemas
from .mcap.frames import McapFrameWriter, Mount
from .mcap.chunks import Data
from .mcap.writer import McapWriter

STORAGES = ("sqlite3", "mcap")
CALLER_ID = "/lidarpkt"


def _is_latched(topic: schemas.Topic) -> bool:
    return topic.qos == schemas.QOS_LATCHED


@functools.lru_cache(maxsize=1)
def ros1_typestore() -> Any:
    """lidarpkt's message types (:func:`lidarpkt.containers.rosmsgs.new_typestore` of every vendor's definitions,
    :func:`lidarpkt.vendors.registry.ros_definitions`) with ROS 1's ``std_msgs/Header`` (``seq``, ``stamp``,
    ``frame_id``): the definitions and MD5 sums of a ROS 1 bag."""
    from rosbags.typesys import Stores, get_typestore

    from lidarpkt.containers.rosmsgs import new_typestore
    from lidarpkt.vendors import registry

    store = new_typestore(registry.ros_definitions())
    store.FIELDDEFS.pop("std_msgs/msg/Header")
    store.register({"std_msgs/msg/Header": get_typestore(Stores.ROS1_NOETIC).FIELDDEFS["std_msgs/msg/Header"]})
    return store


class _BagMessages:
    """The message interface of :class:`~lidarpkt.writers.mcap.writer.McapWriter` (``write``,
    ``write_message``, ``write_latched``, ``add_metadata``, ``close``) on a rosbags writer."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.messages_written = 0
        self._connections: dict[str, Any] = {}
        self._writer: Any = None
        self._closed = False

    def _connect(self, topic: schemas.Topic) -> Any:  # pragma: no cover - abstract
        raise NotImplementedError

    def _encode(self, topic: schemas.Topic, data: bytes) -> bytes:
        return data

    def write(self, topic: schemas.Topic, data: bytes, log_time_ns: int, publish_time_ns: int | None = None) -> None:
        """Store one CDR message of ``topic`` at bag time ``log_time_ns``."""
        if self._closed:
            raise OutputError(f"{self.path} is closed")
        conn = self._connections.get(topic.name)
        if conn is None:
            conn = self._connections[topic.name] = self._connect(topic)
        try:
            self._writer.write(conn, int(log_time_ns), self._encode(topic, data))
        except WRITE_ERRORS as exc:
            raise OutputError(f"writing {self.path} failed: {failure_text(exc)}") from exc
        self.messages_written += 1

    def write_message(self, topic: schemas.Topic, message: object, log_time_ns: int) -> None:
        self.write(topic, rosmsgs.encode(topic.msgtype, message, schemas.typestore()), log_time_ns)

    def write_latched(self, topic: schemas.Topic, data: bytes, log_time_ns: int, *, key: str = "") -> None:
        self.write(topic, data, log_time_ns)  # one file: nothing to repeat; the topic's QoS says latched

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """A metadata record: ROS 1 bags keep none (see the module doc)."""

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._writer.close()

    def _abandon(self) -> None:
        """Stop without finishing (the temporary is removed next)."""
        self._closed = True


class Ros1BagMessages(_BagMessages):
    """A ROS 1 bag (rosbags' rosbag1 writer): each CDR message converted to ROS 1 serialisation."""

    def __init__(self, path: Path) -> None:
        from rosbags.rosbag1 import Writer

        super().__init__(path)
        self._writer = Writer(path)
        try:
            self._writer.open()
        except WRITE_ERRORS as exc:
            raise OutputError(f"cannot create the bag {path}: {failure_text(exc)}") from exc

    def _connect(self, topic: schemas.Topic) -> Any:
        return self._writer.add_connection(topic.name, topic.msgtype, typestore=ros1_typestore(),
                                           callerid=CALLER_ID, latching=1 if _is_latched(topic) else None)

    def _encode(self, topic: schemas.Topic, data: bytes) -> bytes:
        return bytes(schemas.typestore().cdr_to_ros1(data, topic.msgtype))

    def _abandon(self) -> None:
        super()._abandon()
        bio = getattr(self._writer, "bio", None)
        if bio is not None:
            bio.close()


class Rosbag2Sqlite3Messages(_BagMessages):
    """A rosbag2 folder with SQLite storage (rosbags' rosbag2 writer): ``NAME_0.db3`` and ``metadata.yaml``.

    ``folder`` (which must not exist) is made; ``name`` names the database file."""

    def __init__(self, folder: Path, name: str) -> None:
        from rosbags.rosbag2 import Writer

        super().__init__(folder)
        self._writer = Writer(folder)
        self._writer.dbpath = folder / f"{name}_0.db3"  # ros2 bag's name for it (rosbags would use the folder's)
        try:
            self._writer.open()
        except WRITE_ERRORS as exc:
            raise OutputError(f"cannot create the bag {folder}: {failure_text(exc)}") from exc
        self._records: dict[str, int] = {}

    def _connect(self, topic: schemas.Topic) -> Any:
        return self._writer.add_connection(topic.name, topic.msgtype, typestore=schemas.typestore(),
                                           offered_qos_profiles=topic.qos)

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """Kept in ``metadata.yaml``'s ``custom_data`` as JSON (``NAME``, then ``NAME.1`` ...)."""
        n = self._records[name] = self._records.get(name, -1) + 1
        self._writer.set_custom_data(name if n == 0 else f"{name}.{n}", json.dumps(data))

    def _abandon(self) -> None:
        super()._abandon()
        if self._writer.conn is not None:
            self._writer.conn.close()


class Rosbag2McapMessages(McapWriter):
    """A rosbag2 folder with MCAP storage: ``NAME_0.mcap`` (lidarpkt's MCAP file, rosbag2's MCAP storage)
    and the ``metadata.yaml`` that says so, written at :meth:`close`. ``folder`` (which must not exist)
    is made."""

    def __init__(self, folder: Path, name: str, chunk_bytes: int) -> None:
        try:
            folder.mkdir()
        except WRITE_ERRORS as exc:
            raise OutputError(f"cannot create the bag {folder}: {failure_text(exc)}") from exc
        self.folder = folder
        self.counts: dict[str, tuple[schemas.Topic, int]] = {}
        self.span: list[int] = []  # first and last log time
        self.custom_data: dict[str, str] = {}
        super().__init__(folder / f"{name}_0.mcap", chunk_seconds=float("inf"), chunk_bytes=chunk_bytes)

    def _add(self, topic: schemas.Topic, data: Data, log_time_ns: int, publish_time_ns: int | None = None) -> None:
        super()._add(topic, data, log_time_ns, publish_time_ns)
        _, n = self.counts.get(topic.name, (topic, 0))
        self.counts[topic.name] = (topic, n + 1)
        t = int(log_time_ns)
        self.span = [min(self.span[0], t), max(self.span[1], t)] if self.span else [t, t]

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        super().add_metadata(name, data)
        n = sum(1 for k in self.custom_data if k == name or k.startswith(name + "."))
        self.custom_data[name if n == 0 else f"{name}.{n}"] = json.dumps({str(k): str(v) for k, v in data.items()})

    def close(self) -> None:
        if self._closed:
            return
        super().close()
        write_rosbag2_metadata(self.folder, "mcap", [self.path.name], self.counts.values(), self.span,
                               self.custom_data)


def write_rosbag2_metadata(folder: Path, storage: str, files: list[str], counts: Iterable[tuple[schemas.Topic, int]],
                           span: Sequence[int], custom_data: dict[str, str]) -> None:
    """``folder/metadata.yaml`` (rosbag2 version 8, the fields and layout rosbags' writer gives) of one
    storage file: its topics (type, QoS, type hash, message count), time span and ``custom_data``."""
    from ruamel.yaml import YAML

    start, end = (int(span[0]), int(span[1])) if span else (0, 0)
    total = sum(n for _, n in counts)
    store = schemas.typestore()
    info = {
        "version": 8, "storage_identifier": storage, "relative_file_paths": list(files),
        "duration": {"nanoseconds": end - start}, "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": total,
        "topics_with_message_count": [
            {"topic_metadata": {"name": t.name, "type": t.msgtype, "serialization_format": "cdr",
                                "offered_qos_profiles": t.qos, "type_description_hash": store.hash_rihs01(t.msgtype)},
             "message_count": n} for t, n in counts],
        "compression_format": "", "compression_mode": "",
        "files": [{"path": f, "starting_time": {"nanoseconds_since_epoch": start}, "duration": {"nanoseconds": end - start},
                   "message_count": total} for f in files],
        "custom_data": dict(custom_data), "ros_distro": "lidarpkt",
    }
    yaml = YAML(typ="safe")
    yaml.default_flow_style = False
    with open(folder / "metadata.yaml", "w", encoding="utf-8") as fh:
        yaml.dump({"rosbag2_bagfile_information": info}, fh)


class _BagWriter(McapFrameWriter):
    """The MCAP writer's messages (packets, clouds, images, ``/tf_static``) in a bag; see the module doc.

    Args: as :class:`~lidarpkt.writers.mcap.frames.McapFrameWriter`'s (``out`` is the bag; no chunk
    size), with its defaults: ``topics=("packets", "points")`` fed by a pass
    (:func:`lidarpkt.writers.write_captures`) gives what ``decode`` writes (the drivers' packets,
    replayable); the default ``("points",)`` the clouds of the frames given.
    """

    def __init__(self, out: str | os.PathLike[str], *, capture: Any = None, part: str | None = None,
                 topics: Iterable[str] = ("points",), frame_ids: Sequence[str] | str | None = None,
                 base_frame: str | None = None, mounts: Iterable[Mount | str] | None = None,
                 metadata: Any = None, calibration: str | os.PathLike[str] | None = None,
                 clock_offsets: dict[str, int] | None = None, start_ns: int | None = None,
                 end_ns: int | None = None) -> None:
        super().__init__(out, capture=capture, part=part, topics=topics, frame_ids=frame_ids, base_frame=base_frame,
                         mounts=mounts, metadata=metadata, calibration=calibration, clock_offsets=clock_offsets,
                         start_ns=start_ns, end_ns=end_ns)


class Rosbag1Writer(_BagWriter):
    """A ROS 1 bag (``OUT.bag``) of the capture: see the module doc and :class:`_BagWriter`."""

    suffix = ".bag"

    def _open_messages(self, tmp: Path, chunk_bytes: int) -> Any:
        return Ros1BagMessages(tmp)


class Rosbag2Writer(_BagWriter):
    """A rosbag2 folder (``OUT``, made here; it must not exist or be empty) of the capture: see the
    module doc and :class:`_BagWriter`.

    Args:
        storage: ``"sqlite3"`` (``NAME_0.db3``, rosbag2's default) or ``"mcap"`` (``NAME_0.mcap``).

    Raises:
        OutputError: another storage; ``out`` is a file or a folder with something in it.
    """

    suffix = ".rosbag2"

    def __init__(self, out: str | os.PathLike[str], *, capture: Any = None, part: str | None = None,
                 storage: str = "sqlite3", topics: Iterable[str] = ("points",),
                 frame_ids: Sequence[str] | str | None = None, base_frame: str | None = None,
                 mounts: Iterable[Mount | str] | None = None, metadata: Any = None,
                 calibration: str | os.PathLike[str] | None = None, clock_offsets: dict[str, int] | None = None,
                 start_ns: int | None = None, end_ns: int | None = None) -> None:
        if storage not in STORAGES:
            raise OutputError(f"--storage {storage}: choose sqlite3 or mcap")
        self.storage = storage
        super().__init__(out, capture=capture, part=part, topics=topics, frame_ids=frame_ids, base_frame=base_frame,
                         mounts=mounts, metadata=metadata, calibration=calibration, clock_offsets=clock_offsets,
                         start_ns=start_ns, end_ns=end_ns)

    def single_file(self) -> Path:
        path = super().single_file()
        if path.is_file() or (path.is_dir() and any(path.iterdir())):
            raise OutputError(f"-o {path}: exists already; a rosbag2 folder is written new: remove it or choose "
                              "another name")
        return path

    def _open_messages(self, tmp: Path, chunk_bytes: int) -> Any:
        name = self.path.stem if self.path.suffix.lower() == ".rosbag2" else self.path.name  # NAME of NAME_0.db3
        if self.storage == "mcap":
            return Rosbag2McapMessages(tmp, name, chunk_bytes)
        return Rosbag2Sqlite3Messages(tmp, name)
