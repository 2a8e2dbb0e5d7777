"""Planning an archive job: which captures, how big, cut into which segments, with which metadata.

PATHS may be files, directories (walked recursively), rosbag2 folders, or fsspec URLs
(``file://``, ``s3://`` ...). Nothing here decodes: it lists, stats and (above the segment
size) asks :func:`lidarpkt.containers.segments.plan_segments` for record-aligned byte ranges.
"""

from __future__ import annotations

import fnmatch
import os
import re
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING, Any, Iterable, Mapping, Sequence

from lidarpkt.errors import LidarpktError
from lidarpkt.containers.magic import CAPTURE_SUFFIXES, find_captures

if TYPE_CHECKING:
    from lidarpkt.containers.segments import Segment

_SIZE_UNITS = {"": 1, "b": 1, "k": 10**3, "kb": 10**3, "m": 10**6, "mb": 10**6, "g": 10**9, "gb": 10**9,
               "t": 10**12, "tb": 10**12, "kib": 2**10, "mib": 2**20, "gib": 2**30, "tib": 2**40}


class PlanError(LidarpktError):
    """A PATH or an option of an archive job is unusable (no such file, bad size, no capture found)."""


@dataclass(frozen=True)
class Capture:
    """One input of a job.

    Attributes:
        url: the input as the workers open it: a local path, or an fsspec URL for a remote one.
        name: a name unique within the job (the file name; parent folders are prefixed only when
            two inputs share a file name); outputs and the Parquet ``capture`` column use it.
        size_bytes: bytes of the file (of every file of a rosbag2 folder).
        mtime_ns: modification time, so a re-run redoes an input that changed.
        metadata: Ouster metadata JSONs (paths or URLs) for this input; empty for VLP-16 or when
            none was given or found beside it.
        open_options: the job's other keyword options of ``lidarpkt.open``, as sorted ``(name, value)`` pairs.
    """

    url: str
    name: str
    size_bytes: int
    mtime_ns: int = 0
    metadata: tuple[str, ...] = ()
    open_options: tuple[tuple[str, Any], ...] = ()


def parse_size(text: str | int) -> int:
    """Bytes from ``"256MB"``, ``"1GB"``, ``"512MiB"`` or a plain number of bytes.

    Raises:
        PlanError: not a positive size.
    """
    if isinstance(text, int):
        value = text
    else:
        m = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([a-zA-Z]*)\s*", str(text))
        unit = m.group(2).lower() if m else None
        if m is None or unit not in _SIZE_UNITS:
            raise PlanError(f"--segment-size {text}: not a size; write e.g. 256MB, 1GB or 512MiB")
        value = int(float(m.group(1)) * _SIZE_UNITS[unit])
    if value <= 0:
        raise PlanError(f"--segment-size {text}: must be more than 0 bytes")
    return value


def is_remote(url: str) -> bool:
    """True for an fsspec URL other than ``file://`` (those are opened in place)."""
    return "://" in url and not url.startswith("file://")


def local_path(url: str) -> str:
    """A local path for a local path or ``file://`` URL."""
    return url[len("file://"):] if url.startswith("file://") else url


def _filesystem(url: str):
    try:
        import fsspec
    except ImportError:
        raise PlanError(f"{url}: reading URLs needs fsspec: pip install 'lidarpkt[dask]'") from None
    try:
        fs, path = fsspec.core.url_to_fs(url)
    except (ImportError, ValueError) as exc:
        raise PlanError(f"{url}: {exc}; install the fsspec backend for this URL") from None
    return fs, path


def _walk_local(root: str, pattern: str | None) -> list[tuple[str, int, int]]:
    return [_stat_local(p) for p in find_captures(root, pattern)]


def _stat_local(path: str) -> tuple[str, int, int]:
    p = Path(path)
    if p.is_dir():
        stats = [f.stat() for f in p.iterdir() if f.is_file()]
        return str(p), sum(s.st_size for s in stats), max((s.st_mtime_ns for s in stats), default=0)
    st = p.stat()
    return str(p), st.st_size, st.st_mtime_ns


def _expand_remote(url: str, pattern: str | None) -> list[tuple[str, int, int]]:
    fs, path = _filesystem(url)
    protocol = url.split("://", 1)[0]
    if not fs.exists(path):
        raise PlanError(f"{url}: no such file or directory; check the URL")
    if fs.isdir(path):
        entries = fs.find(path, detail=True)
        out = []
        for name, info in sorted(entries.items()):
            base = PurePosixPath(name).name
            if (fnmatch.fnmatch(base, pattern) if pattern else base.lower().endswith(CAPTURE_SUFFIXES)):
                out.append((f"{protocol}://{name}", int(info.get("size") or 0), 0))
        return out
    info = fs.info(path)
    return [(url, int(info.get("size") or 0), 0)]


def expand_paths(paths: Sequence[str | os.PathLike[str]], *, glob: str | None = None) -> list[tuple[str, int, int]]:
    """``(url, size_bytes, mtime_ns)`` of every capture named by PATHS, in the order given (a
    directory's captures in name order). A directory stands for the captures under it: files
    with a capture suffix or magic bytes, or with ``glob``, the files whose name matches it.

    Raises:
        PlanError: a PATH does not exist, or no capture is found at all.
    """
    out: list[tuple[str, int, int]] = []
    for raw in paths:
        url = os.fspath(raw)
        if is_remote(url):
            out.extend(_expand_remote(url, glob))
            continue
        path = local_path(url)
        if not os.path.exists(path):
            raise PlanError(f"{url}: no such file or directory; check the path")
        if os.path.isdir(path) and not os.path.exists(os.path.join(path, "metadata.yaml")):
            out.extend(_walk_local(path, glob))
        else:
            out.append(_stat_local(path))
    first: dict[str, tuple[str, int, int]] = {}  # each capture once, where it was first found
    unique = [first.setdefault(e[0], e) for e in out if e[0] not in first]
    if not unique:
        where = ", ".join(os.fspath(p) for p in paths)
        raise PlanError(f"{where}: no capture found" + (f" matching --glob {glob}" if glob else "")
                        + "; give pcap/pcapng/MCAP/bag files or folders holding them")
    return unique


def _unique_names(urls: Sequence[str]) -> list[str]:
    """File names, with parent folders prefixed (``a__b__x.pcap``) only where names collide, and
    ``x_pcapng.pcapng`` where only the suffix tells two apart (outputs are named by the stem)."""
    names = _unique_paths(urls)
    stems = [PurePosixPath(n).stem for n in names]
    out = []
    for name, stem in zip(names, stems):
        suffix = PurePosixPath(name).suffix
        out.append(f"{stem}_{suffix[1:]}{suffix}" if suffix and stems.count(stem) > 1 else name)
    return out


def _unique_paths(urls: Sequence[str]) -> list[str]:
    parts = [PurePosixPath(local_path(u).replace(os.sep, "/")).parts for u in urls]
    depth = [1] * len(urls)
    while True:
        names = ["__".join(p[-d:]) for p, d in zip(parts, depth)]
        clashes = {n for n in names if names.count(n) > 1}
        if not clashes:
            return names
        grew = False
        for i, n in enumerate(names):
            if n in clashes and depth[i] < len(parts[i]):
                depth[i] += 1
                grew = True
        if not grew:
            return [f"{n}__{i}" if n in clashes else n for i, n in enumerate(names)]


def sidecar_metadata(url: str) -> str | None:
    """The Ouster metadata JSON beside a capture (same stem, ``.json``), if there is one."""
    if is_remote(url):
        fs, path = _filesystem(url)
        candidate = str(PurePosixPath(path).with_suffix(".json"))
        return url.split("://", 1)[0] + "://" + candidate if fs.exists(candidate) else None
    beside = Path(local_path(url)).with_suffix(".json")
    return str(beside) if beside.is_file() else None


def plan_captures(
    paths: Sequence[str | os.PathLike[str]],
    *,
    glob: str | None = None,
    metadata: Iterable[str | os.PathLike[str]] = (),
    open_options: Mapping[str, Any] | None = None,
) -> list[Capture]:
    """The captures of a job, each with its unique name and its Ouster metadata: ``metadata``
    (given once for every input, as ``decode --metadata`` does) or the JSON beside the capture; and the
    job's other options of ``lidarpkt.open`` (``open_options``).

    Raises:
        PlanError: see :func:`expand_paths`; a ``--metadata`` file that does not exist.
    """
    given = tuple(os.fspath(m) for m in metadata)
    options = tuple(sorted((open_options or {}).items()))
    for m in given:
        if not is_remote(m) and not os.path.isfile(local_path(m)):
            raise PlanError(f"--metadata {m}: no such file; give the sensor's description file")
    entries = expand_paths(paths, glob=glob)
    names = _unique_names([e[0] for e in entries])
    captures = []
    for (url, size, mtime), name in zip(entries, names):
        md = given
        if not md:
            found = sidecar_metadata(url)
            md = (found,) if found else ()
        captures.append(Capture(url=url, name=name, size_bytes=size, mtime_ns=mtime, metadata=md,
                                open_options=options))
    return captures


def plan_segments(capture: Capture, segment_bytes: int) -> Sequence[Segment | None]:
    """Segments of one capture: ``[None]`` (the whole file) at or below ``segment_bytes``, for
    remote inputs, rosbag2 folders and files :func:`lidarpkt.containers.segments.plan_segments` keeps
    whole (MCAP, bags); else its record-aligned :class:`~lidarpkt.containers.segments.Segment` s.

    Raises:
        lidarpkt.errors.LidarpktError: the capture cannot be indexed (the job records it as failed).
    """
    from lidarpkt.containers.segments import plan_segments as _plan

    if capture.size_bytes <= segment_bytes or is_remote(capture.url) or os.path.isdir(local_path(capture.url)):
        return [None]
    segments = _plan(local_path(capture.url), segment_bytes)
    return segments if len(segments) > 1 else [None]
