"""Every output lidarpkt writes, behind one small frame-writer interface.

>>> from lidarpkt.writers import open_writer, format_from_suffix     # doctest: +SKIP
>>> with open_writer(format_from_suffix("out.npz"), "out.npz", capture="drive1.pcap") as w:
...     for frame in lidarpkt.open("drive1.pcap"):
...         w.write(frame)
>>> w.close()          # the complete files written: [PosixPath('out.npz')]

===========  ===================  =============================================================  ===========
format       output               content                                                        module
===========  ===================  =============================================================  ===========
``mcap``     one file             ROS 2 MCAP: raw packets, PointCloud2, images, /tf_static       ``mcap``
``npz``      one file             frames on the azimuth grid, stacked per sensor                 ``npz``
``parquet``  dataset folder       one row per return (``layout="points"``) or per frame          ``parquet``
``las``      file, or folder      LAS 1.4 points, GPS time, return number / number of returns    ``las``
``laz``      file, or folder      the same, LAZ-compressed (lazrs)                               ``las``
``ply``      folder               one binary PLY per frame (x y z intensity ring time return)    ``cloud``
``pcd``      folder               one binary PCD per frame (the same fields)                     ``cloud``
``csv``      file, or folder      the Parquet points columns as text, per capture or N frames    ``csv``
``kitti``    folder               KITTI raw data: a float32 ``.bin`` per frame, timestamp files  ``kitti``
``rrd``      one file             Rerun recording: coloured points, range image, frame times     ``rerun``
``rosbag1``  one file (``.bag``)  ROS 1 bag: the MCAP output's topics, ROS 1 types and times     ``rosbag``
``rosbag2``  folder (rosbag2)     rosbag2 (``storage="sqlite3"`` or ``"mcap"``), the same        ``rosbag``
===========  ===================  =============================================================  ===========

Writers never open their inputs: :func:`write_captures` (:mod:`lidarpkt.writers.feed`) reads each
capture once and hands every writer its frames, and its raw packets with their capture times to a
writer that takes them (the MCAP and ROS bag writers' ``packets`` topic; see :mod:`lidarpkt.writers.base`):

>>> with open_writer("mcap", "out.mcap", topics=("packets", "points")) as w:    # doctest: +SKIP
...     write_captures(["drive1.pcap"], [w], workers=2)

Writing packets (not frames) to pcap/pcapng is :mod:`lidarpkt.writers.pcap`. To add a format:
a module with a :class:`~lidarpkt.writers.base.BaseWriter` subclass and a row in :data:`FORMATS`.
The format libraries (pyarrow, laspy, plyfile, pypcd4: the ``export`` extra; rerun-sdk: the
``rerun`` extra; rosbags is a dependency) are imported only by their writer.
"""

from __future__ import annotations

import importlib
import inspect
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lidarpkt.errors import OutputError

from .base import AtomicFiles, BaseWriter, FrameWriter, PacketWriter


@dataclass(frozen=True)
class Format:
    """An output format: its name, the suffixes that choose it, its writer class, its extra."""

    name: str
    suffixes: tuple[str, ...]
    writer: str  # "module:Class" under lidarpkt.writers
    directory: bool  # True: ``out`` is a folder (per-frame files or a dataset)
    requires: tuple[str, ...] = ()  # import names of the libraries it needs
    extra: str = "export"  # the lidarpkt extra that installs them
    whole_capture: bool = False  # one recording of the whole capture: the archives never cut it into segments


FORMATS: dict[str, Format] = {f.name: f for f in (
    Format("mcap", (".mcap",), "mcap.frames:McapFrameWriter", False, whole_capture=True),
    Format("npz", (".npz",), "npz:NpzWriter", False),
    Format("parquet", (".parquet",), "parquet:ParquetWriter", True, ("pyarrow",)),
    Format("las", (".las",), "las:LasWriter", False, ("laspy",)),
    Format("laz", (".laz",), "las:LazWriter", False, ("laspy", "lazrs")),
    Format("ply", (".ply",), "cloud:PlyWriter", True, ("plyfile",)),
    Format("pcd", (".pcd",), "cloud:PcdWriter", True, ("pypcd4",)),
    Format("csv", (".csv",), "csv:CsvWriter", False, ("pyarrow",)),
    Format("kitti", (".kitti",), "kitti:KittiWriter", True, whole_capture=True),
    Format("rrd", (".rrd",), "rerun:RrdWriter", False, ("rerun",), "rerun", whole_capture=True),
    Format("rosbag1", (".bag",), "rosbag:Rosbag1Writer", False, whole_capture=True),
    Format("rosbag2", (".rosbag2",), "rosbag:Rosbag2Writer", False, whole_capture=True),
)}


SUFFIXES: tuple[str, ...] = tuple(s for f in FORMATS.values() for s in f.suffixes)  # .mcap, .npz first


def format_from_suffix(path: str | os.PathLike[str], flag: str = "-o") -> str:
    """The format name chosen by ``path``'s suffix (``"x.mcap"`` → ``"mcap"``).

    Raises :class:`~lidarpkt.errors.OutputError` naming ``flag``, the path and the accepted suffixes.
    """
    suffix = Path(path).suffix.lower()
    for fmt in FORMATS.values():
        if suffix in fmt.suffixes:
            return fmt.name
    raise OutputError(f"{flag} {path}: unknown output type {suffix or '(no suffix)'!r}; "
                      f"the accepted suffixes are {', '.join(SUFFIXES)}")


def open_writer(fmt: str, out: str | os.PathLike[str], *, capture: str | os.PathLike[str] | None = None,
                part: str | None = None, **format_options: Any) -> BaseWriter:
    """A writer of format ``fmt`` (a key of :data:`FORMATS`) to ``out``.

    Args:
        fmt: a key of :data:`FORMATS`: ``"mcap"``, ``"npz"``, ``"parquet"``, ``"las"``, ``"laz"``,
            ``"ply"``, ``"pcd"``, ``"csv"``, ``"kitti"``, ``"rrd"``, ``"rosbag1"`` or ``"rosbag2"``.
        out: the output file (mcap, npz, rrd, rosbag1, las/laz/csv without ``frames_per_file``), the
            rosbag2 folder the writer makes, or a folder (the others). Local paths only.
        capture: the input the frames come from (its name goes into file names and columns).
        part: a segment name (e.g. ``"seg0003"``) that keeps this segment's file names apart
            from the other segments' of the same capture.
        **format_options: the format's own options (see each writer class).

    Raises:
        OutputError: unknown format or option, a missing library (names the extra to install),
            an output folder that does not exist.
    """
    spec = FORMATS.get(fmt)
    if spec is None:
        raise OutputError(f"--format {fmt}: unknown format; choose among {', '.join(FORMATS)}")
    for lib in spec.requires:
        try:
            importlib.import_module(lib)
        except ImportError:
            raise OutputError(f"--format {fmt}: needs the Python package {lib!r}; "
                              f"install it with pip install 'lidarpkt[{spec.extra}]'") from None
    cls = _writer_class(spec)
    accepted = accepted_options(fmt)
    unknown = sorted(set(format_options) - accepted)
    if unknown:
        raise OutputError(f"--format {fmt}: no option {', '.join(unknown)}; its options are "
                          f"{', '.join(sorted(accepted)) or 'none'}")
    return cls(out, capture=capture, part=part, **format_options)


def _writer_class(spec: Format) -> type:
    module_name, cls_name = spec.writer.split(":")
    return getattr(importlib.import_module(f"{__name__}.{module_name}"), cls_name)


def accepted_options(fmt: str) -> set[str]:
    """The names of the options format ``fmt`` takes (its writer's keyword arguments beyond ``out``,
    ``capture`` and ``part``): ``accepted_options("las")`` → ``{"frames_per_file"}``. Imports the
    writer's module, not its format library. Raises KeyError for an unknown format."""
    return set(inspect.signature(_writer_class(FORMATS[fmt])).parameters) - {"out", "capture", "part"}


def takes_packets(fmt: str) -> bool:
    """Whether format ``fmt``'s writer takes the capture's packets (``wants_packets``: MCAP, ROS bags), as
    ``decode`` writes them: with the ``packets`` topic. Raises KeyError for an unknown format."""
    return bool(getattr(_writer_class(FORMATS[fmt]), "wants_packets", False))


__all__ = ["AtomicFiles", "BaseWriter", "FORMATS", "Format", "FrameWriter", "PacketWriter", "SUFFIXES",
           "accepted_options", "format_from_suffix", "open_writer", "takes_packets", "write_captures", "Feed"]


def __getattr__(name: str) -> Any:
    if name in ("write_captures", "Feed"):  # the pass loads the pipeline: only when asked
        from . import feed

        return getattr(feed, name)
    raise AttributeError(name)
