"""The keyword options of ``lidarpkt.open`` and :class:`~lidarpkt.pipeline.reader.FrameReader`, declared once.

:class:`OpenOptions` is the one list of the options: their names, types, defaults and documentation.
``lidarpkt.open`` (:func:`~lidarpkt.pipeline.reader.open_frames`), ``FrameReader`` and the threads over
segments (:mod:`lidarpkt.pipeline.parallel`) take them from here: their signatures (``help()``,
``inspect.signature``) and the *Args* of their docstrings are made from its fields
(:func:`with_options`).
"""

from __future__ import annotations

import dataclasses
import inspect
import textwrap
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Iterable, TypedDict, TypeVar

from lidarpkt.core.checks import PORT, WORKERS, Allowed, Number, Several, Switch, Text, option_error
from lidarpkt.errors import UsageError

if TYPE_CHECKING:
    from lidarpkt.containers.segments import Segment
    from lidarpkt.core.vendor import DecodeSetup

__all__ = ["OpenOptions", "OpenKeywords", "with_options", "DECODING_OPTIONS"]


#: a sensor file as ``metadata=`` takes it: a path, JSON text, a parsed document or a loaded file
SensorFileArg = Any
#: the options handed to the vendors' decoders (:meth:`OpenOptions.decoding`)
DECODING_OPTIONS = ("model", "cut_angle_deg", "cut_on_block", "verify_crc", "soft_id_check")


def _option(default: Any, doc: str, allowed: Allowed | None = None) -> Any:
    """A field of :class:`OpenOptions`: its default, its documentation and the values it takes (checked by
    :meth:`OpenOptions.from_keywords`; ``None``: anything, checked where it is used)."""
    return field(default=default, metadata={"doc": doc, "allowed": allowed})



class _SegmentOf(Allowed):
    """A :class:`~lidarpkt.containers.segments.Segment` (from ``plan_segments``), or None."""

    def check(self, value: Any, name: str) -> Any:
        if value is None:  # a whole capture: the segments module is not needed
            return value
        from lidarpkt.containers.segments import Segment

        if isinstance(value, Segment):
            return value
        raise option_error(name, value, "not a Segment of plan_segments()", "plan_segments(path)[0]", flag=False)


@dataclass(frozen=True)
class OpenOptions:
    """The keyword options of ``lidarpkt.open`` and ``FrameReader`` (each field's ``metadata["doc"]`` says
    what it does). Made from keywords by :meth:`from_keywords`; ``dataclasses.replace`` changes some."""

    metadata: SensorFileArg | Iterable[SensorFileArg] | None = _option(
        None, "the sensors' description files, one per sensor, of any vendor, told apart by their content: a "
        "path, JSON text, or a loaded (or parsed) file; a list of them for several sensors. Some sensors need "
        "theirs to be decoded, some to compute XYZ, some have stock values (:mod:`lidarpkt.vendors` says "
        "which); MCAP files lidarpkt records carry them. A file that fits no stream of the capture is reported "
        "(an :class:`~lidarpkt.errors.UnusedSensorFileWarning`).")
    model: str | None = _option(
        None, "the sensor model where its packets cannot say it (two models that share a factory byte); by "
        "default read from the packets.", Text(optional=True, example="'MODEL'"))
    cut_angle_deg: float | None = _option(
        None, "cut frames at this azimuth (degrees) instead of at the wrap through 0° (sensors whose frames end "
        "where their azimuth wraps).", Number(0, 360, high_open=True, optional=True, example="90"))
    cut_on_block: bool = _option(
        False, "cut at the block of firings that wraps (VeloView's frames) rather than at the firing sequence "
        "that wraps.", Switch())
    source: str | None = _option(None, "decode only packets from this source IP address.",
                                 Text(optional=True, example="'192.168.1.201'"))
    include_partial: bool = _option(True, "yield the partial frames (default True): frames missing columns of their "
                                    "rotation, at the ends of the capture or where packets were lost.", Switch())
    verify_crc: bool = _option(
        True, "check the CRC of packets whose firmware writes one (default True).", Switch())
    soft_id_check: bool = _option(
        False, "accept packets whose init_id differs from their sensor file's (a changed init_id still "
        "ends the frame).", Switch())
    max_sensors: int = _option(
        64, "most sensors (one decoder each) decoded from one capture (64); packets of further sources are "
        "counted as unrouted, with a SkippedPacketWarning.", Number(1, whole=True, example="8"))
    read_ahead: bool | None = _option(
        None, "read the packets in a background thread while decoding (pcap/pcapng only): ``None`` (default) "
        "when the file has at least 8 MB and the machine 2+ CPUs; ``False`` never; ``True`` always. Same "
        "frames, order, stats, errors and warnings either way.", Switch(optional=True))
    segment: Segment | None = _option(
        None, "yield only the frames of this :class:`~lidarpkt.containers.segments.Segment` of the capture "
        "(from :func:`~lidarpkt.containers.segments.plan_segments`); the frames of all segments, in order, are "
        "the whole file's. A ``frame_id`` that counts rotations and ``extra[\"packet_index\"]`` then count "
        "from the segment's start.", _SegmentOf())
    ports: Iterable[int] | None = _option(None, "pcap/pcapng: keep only packets sent to these UDP destination ports.",
                                          Several(PORT, example="[2368]"))
    src_addresses: Iterable[str] | None = _option(
        None, "pcap/pcapng: keep only packets from these source addresses.",
        Several(Text(), example="['192.168.1.201']"))
    payload_sizes: Iterable[int] | None = _option(None, "keep only packets of these UDP payload sizes (bytes).",
                                                  Several(Number(1, 65535, whole=True), example="[1206]"))
    topics: Iterable[str] | None = _option(
        None, "bags and MCAP: read only these topics (default: every topic of a known packet type).",
        Several(Text(), example="['/sensor/packets']"))
    batch_packets: int | None = _option(
        None, "pcap/pcapng: most packets per batch (the reader's default, 2048, when None).",
        Number(1, 1 << 20, whole=True, optional=True, example="2048"))
    workers: int | None = _option(
        None, "decoders working side by side: 1 decodes in this thread; N > 1 cuts a pcap/pcapng capture of at "
        "least 16 MB into segments decoded by N forked processes (threads where processes cannot be forked), other "
        "containers decoding in a thread of their own beside the read-ahead (:mod:`lidarpkt.pipeline.parallel`). "
        "``None`` (default): for a pcap/pcapng of at least 64 MB, N = the CPUs idle now (the CPUs less the load "
        "average, at most 4) when three or more are, else 1 (two workers on two cores measured slower than one). The frames, their order and arrays are those of "
        "``workers=1``. ``segment=`` reads in one thread.", dataclasses.replace(WORKERS, optional=True))

    @classmethod
    def from_keywords(cls, caller: str, options: dict[str, Any]) -> "OpenOptions":
        """The options named in ``options``, the others at their defaults.

        Raises:
            TypeError: a name that is no option (as Python says for a misspelt keyword of ``caller``).
            lidarpkt.errors.UsageError: a value the option does not take (its field's ``allowed``): the
                message names ``caller`` and the option, and says what it takes.
        """
        unknown = sorted(set(options) - _NAMES)
        if unknown:
            raise TypeError(f"{caller}() got an unexpected keyword argument {unknown[0]!r}")
        checked = {}
        for name, value in options.items():
            allowed = _ALLOWED[name]
            try:
                checked[name] = value if allowed is None else allowed.check(value, name)
            except UsageError as exc:
                raise UsageError(f"{caller}(): {exc}") from None
        return cls(**checked)

    def keywords(self) -> dict[str, Any]:
        """The options as keyword arguments (every field, by name)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def decoding(self) -> dict[str, Any]:
        """The options the vendors' decoders take (each those it knows), by name."""
        return {name: getattr(self, name) for name in DECODING_OPTIONS}

    def sensor_setup(self) -> tuple[list, DecodeSetup]:
        """(the sensor files of ``metadata``, loaded; the vendors' :class:`~lidarpkt.core.vendor.DecodeSetup`):
        what the router of files and live packets alike is given.

        Raises:
            lidarpkt.errors.MetadataError: a ``metadata`` file of no kind lidarpkt reads (or that its vendor
                cannot read); UsageError: a ``model`` no vendor has.
        """
        from lidarpkt.vendors import registry

        registry.check_model(self.model)
        files = registry.load_sensor_files(self.metadata)
        return files, registry.setup(files, self.decoding())

    def filters(self) -> dict[str, Any]:
        """The options the packet reader takes (``None``: the reader's default)."""
        return {"ports": self.ports, "src_addresses": self.src_addresses, "payload_sizes": self.payload_sizes,
                "topics": self.topics, "batch_packets": self.batch_packets}


class OpenKeywords(TypedDict, total=False):
    """The fields of :class:`OpenOptions` as the keywords of ``lidarpkt.open`` for static type checkers
    (``**options: Unpack[OpenKeywords]``): a misspelt or mistyped option is found before the script runs.
    A test holds it equal to :class:`OpenOptions`, name for name and type for type."""

    metadata: SensorFileArg | Iterable[SensorFileArg] | None
    model: str | None
    cut_angle_deg: float | None
    cut_on_block: bool
    source: str | None
    include_partial: bool
    verify_crc: bool
    soft_id_check: bool
    max_sensors: int
    read_ahead: bool | None
    segment: Segment | None
    ports: Iterable[int] | None
    src_addresses: Iterable[str] | None
    payload_sizes: Iterable[int] | None
    topics: Iterable[str] | None
    batch_packets: int | None
    workers: int | None


_NAMES = frozenset(f.name for f in dataclasses.fields(OpenOptions))
_ALLOWED: dict[str, Allowed | None] = {f.name: f.metadata["allowed"] for f in dataclasses.fields(OpenOptions)}

_F = TypeVar("_F", bound=Callable[..., Any])


def with_options(func: _F) -> _F:
    """Give ``func(<first parameters>, **options)`` the signature of its first parameters followed by every
    field of :class:`OpenOptions` as a keyword-only parameter (annotation and default), and put the
    fields' documentation where its docstring says ``{options}``."""
    own = [p for p in inspect.signature(func).parameters.values() if p.kind is not p.VAR_KEYWORD]
    hints = {f.name: f.type for f in dataclasses.fields(OpenOptions)}
    params = [inspect.Parameter(f.name, inspect.Parameter.KEYWORD_ONLY, default=f.default, annotation=hints[f.name])
              for f in dataclasses.fields(OpenOptions)]
    func.__signature__ = inspect.signature(func).replace(parameters=own + params)  # type: ignore[attr-defined]
    doc = func.__doc__  # None under python -OO
    if doc and "{options}" in doc:
        line = next(x for x in doc.splitlines() if "{options}" in x)
        indent = line[: len(line) - len(line.lstrip())]
        lines = [textwrap.fill(f"{f.name}: {f.metadata['doc']}", 108, initial_indent=indent,
                               subsequent_indent=indent + "    ") for f in dataclasses.fields(OpenOptions)]
        func.__doc__ = doc.replace(indent + "{options}", "\n".join(lines))
    return func
