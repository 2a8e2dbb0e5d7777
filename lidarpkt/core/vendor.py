"""What lidarpkt knows of one sensor vendor, in one record: :class:`Vendor`.

Each vendor package (``lidarpkt.vendors.<name>``) exports its record as ``VENDOR``; the list of them is
:data:`lidarpkt.vendors.registry.VENDORS`. Everything outside the vendor folders asks the registry and names
no vendor: the router and ``info`` ask the one classifier (:attr:`Vendor.classify`), the recorder the
stream counter, the bag reader and the MCAP writer the ROS messages, replay and pcap export the
factory addresses (of each stream kind a bag's message holds), the end-of-read summary the drop
reasons, ``lidarpkt.open`` the sensor files and the frame files. A record holds functions and tables;
the functions import the vendor's modules when called, so that reading the registry costs nothing.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Mapping, Sequence

from .streams import StreamKind

if TYPE_CHECKING:
    import os

    import numpy as np

    from .decoder import Decoder, StreamCounter
    from .dropped import DropCounts
    from .packet import Endpoint, PacketBatch
    from .ros import Topic
    from .sequence import FrameIterator

#: A bag message of a packet type → ``(payloads uint8[N, L], capture times int64[N] ns)``; arguments: the
#: deserialised message and the bag's receive time (ns) of it.
Extractor = Callable[[Any, int], "tuple[np.ndarray, np.ndarray]"]


@dataclass(frozen=True)
class DecodeSetup:
    """What a vendor's classifier and decoder factory are given.

    Attributes:
        sensor_files: the loaded sensor files given (``metadata=``), by vendor name, in the order given.
        options: the decoding options of ``lidarpkt.open`` by name (``cut_angle_deg``, ``model``,
            ``verify_crc``...); each vendor takes those it knows.
    """

    sensor_files: Mapping[str, tuple[Any, ...]] = field(default_factory=dict)
    options: Mapping[str, Any] = field(default_factory=dict)

    def files(self, vendor: str) -> tuple[Any, ...]:
        """The sensor files of ``vendor`` (``()`` when none was given)."""
        return tuple(self.sensor_files.get(vendor, ()))

    def option(self, name: str, default: Any = None) -> Any:
        value = self.options.get(name)
        return default if value is None else value


@dataclass(frozen=True)
class Match:
    """What a vendor's classifier says of a batch it recognises.

    Attributes:
        stream: the kind of stream (one of the vendor's :attr:`Vendor.streams`).
        sensor: what tells this vendor's sensors apart beyond their source address (the sensor file the
            packets fit, a model), ``()`` when the address says it all.
        make: the decoder of a new sensor, given the sensor's source name; ``None`` when the vendor
            recognises the stream but cannot decode it (its sensor file is missing or does not fit).
        sensor_files: the loaded sensor files (of those given) its decoder is given.
    """

    stream: StreamKind
    sensor: tuple = ()
    make: Callable[[str], Decoder] | None = None
    sensor_files: tuple[Any, ...] = ()

    @property
    def vendor(self) -> str:
        return self.stream.vendor

    @property
    def kind(self) -> str:
        return self.stream.name

    @property
    def lidar(self) -> bool:
        return self.stream.lidar

    @property
    def decodable(self) -> bool:
        return self.make is not None


@dataclass(frozen=True)
class SensorFiles:
    """A vendor's sensor description files (calibration, metadata), told apart from other vendors' by content.

    Attributes:
        what: what the file is, for messages (``"Ouster metadata JSON"``).
        recognise: whether a file's text (its first 64 KiB) is one.
        is_loaded: whether an object given instead of a path is one, loaded or parsed (a dict).
        load: a path, text or object of this kind → what the vendor's decoder takes. Raises
            :class:`~lidarpkt.errors.MetadataError` or :class:`~lidarpkt.errors.CalibrationError`.
        needed_for: ``"decoding"`` (no decoder without it), ``"xyz"`` (frames without XYZ without it) or
            ``""`` (the sensor's packets, or stock values, serve).
        ports: the UDP ports a loaded file says its sensor sends to (live reception listens there), ``None``
            when the file does not say.
    """

    what: str
    recognise: Callable[[str], bool]
    is_loaded: Callable[[Any], bool]
    load: Callable[[Any], Any]
    needed_for: str = ""
    ports: Callable[[Any], tuple[int, ...]] | None = None


@dataclass(frozen=True)
class PacketTopic:
    """Where a stream's raw packets go in an MCAP file: one message per packet (``encode(payload, host
    time ns)``), or one per rotation (``encode_rotation(payloads uint8[N, L], host times int64[N])``,
    logged at the last packet's time)."""

    topic: Topic
    encode: Callable[[bytes, int], bytes] | None = None
    encode_rotation: Callable[[np.ndarray, np.ndarray], bytes] | None = None


@dataclass(frozen=True)
class LatchedMessage:
    """A message written once per file (and again in each file of a rotated recording): ``key`` tells
    messages of one latched topic apart."""

    topic: Topic
    data: bytes
    key: str


@dataclass(frozen=True)
class FrameTopics:
    """How the vendor's ROS driver publishes frames, which lidarpkt follows.

    Attributes:
        frame_id: the sensor's default coordinate frame (``"velodyne"``, ``"os_sensor"``).
        points: the PointCloud2 topic of return slot 0 (slot k > 0: the name followed by k + 1).
        images: the prefix of the image topics (``<images>/range_image``).
        ring_from_bottom: PointCloud2 ``ring`` counts beams from the lowest (the driver's), not rows.
        intensity: the point field ``intensity`` takes (``"reflectivity"`` or ``"signal"``) where the frame has it.
    """

    frame_id: str
    points: str
    images: str
    ring_from_bottom: bool = False
    intensity: str = "reflectivity"


@dataclass(frozen=True)
class RosMessages:
    """The vendor's ROS messages: read from bags and MCAP files, written to MCAP.

    Attributes:
        definitions: ``.msg`` text of its message types that rosbags' ROS 2 store lacks, by type.
        packets: reading: message type → :data:`Extractor` of its packets.
        sensor_file_topic: reading: whether a ``std_msgs/String`` topic holds the vendor's sensor file as text.
        sensor_file_refusal: reading: why a text on such a topic is not the vendor's sensor file (``None``:
            it is one).
        packet_topics: writing: the topic of each stream kind's raw packets, by kind name (a stream
            without one goes to ``/lidarpkt/other_packets``).
        sensor_file_messages: writing, at the start: the latched messages of a loaded sensor file (its
            log time ns), and the MCAP metadata record ``lidarpkt.sensor`` of it.
        stream_record: writing, at a stream's first batch: its ``lidarpkt.sensor`` record (``None``: none).
        decoded: writing, beside the raw packets: messages decoded from them (IMU samples...), each
            ``(topic, data, log time ns)``.
        frames: how frames are published.
    """

    frames: FrameTopics
    definitions: Mapping[str, str] = field(default_factory=dict)
    packets: Mapping[str, Extractor] = field(default_factory=dict)
    sensor_file_topic: Callable[[str], bool] | None = None
    sensor_file_refusal: Callable[[str], str | None] | None = None
    packet_topics: Mapping[str, PacketTopic] = field(default_factory=dict)
    sensor_file_messages: Callable[[Any, int], tuple[list[LatchedMessage], dict[str, str]]] | None = None
    stream_record: Callable[[PacketBatch, str], dict[str, str] | None] | None = None
    decoded: Callable[[PacketBatch, Match], list[tuple[Topic, bytes, int]]] | None = None


@dataclass(frozen=True)
class FrameFiles:
    """Files of decoded frames the vendor's tools record (not packets), read by ``lidarpkt.open``.

    Attributes:
        what: what they are, for messages (``"OSF file"``).
        open: ``open(path, stats, include_partial)``: the reader of its frames (``stats.frames`` counts them).
        describe: a JSON-ready summary for ``lidarpkt info`` (``{"sensors": [...]}``: per sensor its
            ``source``, ``kind``, ``model``, ``frames``, first and last ``*_timestamp_ns``...).
        summary: the text ``lidarpkt info`` prints of that summary.
        receive_span: the first and last receive time (ns) of its frames, ``(None, None)`` without frames.
    """

    what: str
    open: Callable[[str | os.PathLike[str], Any, bool], FrameIterator]
    describe: Callable[[str | os.PathLike[str]], dict]
    summary: Callable[[dict], str]
    receive_span: Callable[[str | os.PathLike[str]], tuple[int | None, int | None]]


@dataclass(frozen=True)
class Vendor:
    """Everything lidarpkt knows of one vendor (see the module doc).

    Attributes:
        name: its registry name, the ``vendor`` of its :class:`~lidarpkt.core.sensor.SensorInfo` and streams.
        title: its name for people (``"Ouster"``).
        streams: the kinds of stream its sensors send.
        classify: the one classifier: the :class:`Match` of a batch of its packets, else ``None``.
        describe: what ``lidarpkt info`` says of a stream of its packets (JSON-ready, with ``"kind"``, its
            text for people), else ``None``.
        summary: the parts of ``info``'s line of a stream after the kind, from :attr:`describe`'s dict.
        counter: the recorder's packet counter (losses, rotations) of a matched stream, ``None`` for a
            stream without one.
        sensor_time_ns: the sensor's clock at the first packet of a matched batch (ns), ``None`` when its
            packets carry no time lidarpkt reads without decoding.
        drops: its decoder's ``stats`` → :class:`~lidarpkt.core.dropped.DropCounts`.
        endpoints: the factory source and destination of a matched stream (replay, pcap export of a
            capture that kept no addresses).
        split: a batch that holds packets of several of its stream kinds (a ROS message carrying a sensor's
            two streams together) parted by kind: each kind's :class:`Match` and the ``bool[N]`` mask of its
            rows, the masks covering every row once (a kind it does not hold: an empty mask); ``None`` for a
            vendor whose batches hold one kind each (the batch's :class:`Match` is every packet's).
        ros_messages: its ROS messages (:class:`RosMessages`), made when first asked: the vendor's ROS module is
            imported only by what reads or writes ROS messages. Read as :attr:`ros`.
        sensor_files: its sensor description files, ``None`` when it has none.
        frame_files: files of decoded frames it records, by container kind (:func:`~lidarpkt.containers.magic.container_kind`).
        frame_ids_counted: its frame ids count rotations from the stream's start (renumbered across the
            segments of a capture), rather than coming from the packets.
        models: the names of its models ``model=`` picks where the packets cannot say which (two models of
            one factory byte), ``None`` when it takes none.
        live_auxiliary: its auxiliary packets are decoded live too (``False``: live sources count them only,
            as a GPS time that disagrees with the host clock would move the decoder's clock).
        undecoded_hint: what to say when no stream was decoded but some are its streams it could not
            decode (``(path, unrouted streams → packets, its sensor files given)``), else ``None``.
        geometry: the XYZ geometry of a sensor whose frames were read back from a file, from its
            :class:`~lidarpkt.core.sensor.SensorInfo` (``metadata``: its sensor file's document) and the
            fields of the calibration the file kept (``None``: none); ``None`` when it cannot be rebuilt.
        sensor_file_in_packets: the sensor file a matched batch of its packets carries (loaded, as
            :attr:`SensorFiles.load` gives it; ``None`` when the batch holds none), for sensors that send
            their calibration in-band now and then: the reader of a later segment of a capture, which
            starts past it, is given the one of the capture's first packets and decodes as the whole
            capture does. ``None`` for a vendor whose packets carry none.
    """

    name: str
    title: str
    streams: tuple[StreamKind, ...]
    classify: Callable[[PacketBatch, DecodeSetup], Match | None]
    describe: Callable[[PacketBatch, DecodeSetup], dict | None]
    summary: Callable[[dict], list[str]]
    counter: Callable[[PacketBatch, Match], StreamCounter | None]
    sensor_time_ns: Callable[[PacketBatch, Match], int | None]
    drops: Callable[[Any], DropCounts]
    endpoints: Callable[[Match], tuple[Endpoint, Endpoint]]
    ros_messages: Callable[[], RosMessages]
    sensor_files: SensorFiles | None = None
    frame_files: Mapping[str, FrameFiles] = field(default_factory=dict)
    frame_ids_counted: bool = False
    live_auxiliary: bool = True
    models: Callable[[], tuple[str, ...]] | None = None
    undecoded_hint: Callable[[Any, Mapping[Any, int], Sequence[Any]], str | None] | None = None
    geometry: Callable[[Any, Mapping[str, Any] | None], Any] | None = None
    sensor_file_in_packets: Callable[[PacketBatch, Match], Any] | None = None
    split: Callable[[PacketBatch, Match], Sequence[tuple[Match, np.ndarray]]] | None = None

    @property
    def ros(self) -> RosMessages:
        """Its ROS messages (:attr:`ros_messages`)."""
        return self.ros_messages()

    def stream(self, name: str) -> StreamKind:
        """Its stream kind called ``name``.

        Raises:
            KeyError: it has none of that name.
        """
        for kind in self.streams:
            if kind.name == name:
                return kind
        raise KeyError(f"{self.name} has no stream kind {name!r}")
