"""File magic, known in one place: which container a capture is, from its first bytes (never its name).

Used by the packet readers, :func:`lidarpkt.open`, ``lidarpkt info`` and the writers.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

from ..errors import UnsupportedContainerError

__all__ = [
    "PCAP_MAGIC_US", "PCAP_MAGIC_NS", "PCAP_MAGIC_MODIFIED", "PCAPNG_SHB", "PCAPNG_BOM", "PCAP_MAGIC_BYTES",
    "MCAP_MAGIC", "ROS1_MAGIC", "SQLITE_MAGIC", "OSF_IDENTIFIER", "FRAME_CONTAINERS", "CAPTURES_TEXT", "capture_format",
    "format_from_magic",
    "is_capture", "container_kind", "CAPTURE_SUFFIXES", "looks_like_capture", "find_captures",
]

PCAP_MAGIC_US = 0xA1B2C3D4
PCAP_MAGIC_NS = 0xA1B23C4D
PCAP_MAGIC_MODIFIED = 0xA1B2CD34  # Kuznetzov's patched libpcap: 24-byte record headers
PCAPNG_SHB = 0x0A0D0D0A
PCAPNG_BOM = 0x1A2B3C4D
PCAP_MAGIC_BYTES = frozenset(
    [m.to_bytes(4, order) for m in (PCAP_MAGIC_US, PCAP_MAGIC_NS, PCAP_MAGIC_MODIFIED) for order in ("little", "big")]
    + [PCAPNG_SHB.to_bytes(4, "little")]
)  # the first four bytes of the pcap/pcapng files lidarpkt.open takes (the pcap reader's magics, both byte orders)
MCAP_MAGIC = b"\x89MCAP0\r\n"
ROS1_MAGIC = b"#ROSBAG V2.0"
SQLITE_MAGIC = b"SQLite format 3\x00"
# ouster-sdk's OSF: a size-prefixed flatbuffer whose file identifier (bytes 8-12) names the OSF header
OSF_IDENTIFIER = b"OSF$"
#: the container kinds of files of decoded frames, not packets (the vendor that records them reads them)
FRAME_CONTAINERS = frozenset({"osf"})
#: the files lidarpkt reads, for people (help texts, messages)
CAPTURES_TEXT = "pcap/pcapng, MCAP, ROS bag (ROS 1 or rosbag2) or OSF"


def capture_format(path: str | os.PathLike[str]) -> str | None:
    """``"pcap"``, ``"pcapng"`` or None, from the first four bytes of the file."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(4)
    except OSError:
        return None
    return format_from_magic(head)


def format_from_magic(head: bytes) -> str | None:
    """``"pcap"``, ``"pcapng"`` or None for a file starting with ``head``."""
    if len(head) < 4:
        return None
    le, be = struct.unpack_from("<I", head)[0], struct.unpack_from(">I", head)[0]
    if PCAPNG_SHB in (le, be):
        return "pcapng"
    if {le, be} & {PCAP_MAGIC_US, PCAP_MAGIC_NS, PCAP_MAGIC_MODIFIED}:
        return "pcap"
    return None


def is_capture(path: str | os.PathLike[str]) -> bool:
    """True when the file starts with a pcap or pcapng magic number (never raises)."""
    return capture_format(path) is not None


def is_capture_folder(path: str | os.PathLike[str]) -> bool:
    """A folder that is one capture (a rosbag2 folder, with its ``metadata.yaml``), not a folder of captures."""
    p = Path(path)
    return p.is_dir() and (p / "metadata.yaml").exists()


def container_kind(path: str | os.PathLike[str]) -> str:
    """``"pcap"`` (pcap or pcapng), ``"mcap"``, ``"rosbag2"`` (directory or .db3), ``"rosbag1"`` or ``"osf"`` (ouster-sdk's
    frame files: frames, not packets), from the first bytes.

    Raises :class:`UnsupportedContainerError` naming the file and what it starts with.
    """
    p = Path(path)
    if p.is_dir():
        if is_capture_folder(p):
            return "rosbag2"
        raise UnsupportedContainerError(f"{p} is a directory without a rosbag2 metadata.yaml")
    try:
        with p.open("rb") as fh:
            head = fh.read(16)
    except FileNotFoundError:
        raise UnsupportedContainerError(f"{p}: no such file") from None
    except OSError as exc:
        raise UnsupportedContainerError(f"{p}: cannot read ({exc.strerror})") from None
    if head[:4] in PCAP_MAGIC_BYTES:
        return "pcap"
    if head.startswith(MCAP_MAGIC):
        return "mcap"
    if head.startswith(ROS1_MAGIC):
        return "rosbag1"
    if head.startswith(SQLITE_MAGIC):
        return "rosbag2"
    if head[8:12] == OSF_IDENTIFIER:
        return next(iter(FRAME_CONTAINERS))
    shown = head.hex(" ") if head else "nothing (empty file)"
    raise UnsupportedContainerError(
        f"{p} is not a capture lidarpkt reads ({CAPTURES_TEXT}): it starts with {shown}"
    )


# names a folder walk takes without reading them (the magic bytes decide for the rest)
CAPTURE_SUFFIXES = (".pcap", ".pcapng", ".cap", ".mcap", ".bag", ".db3", ".osf")


def looks_like_capture(path: str | os.PathLike[str]) -> bool:
    """A capture suffix (:data:`CAPTURE_SUFFIXES`), or first bytes a container reader knows (never raises)."""
    if os.fspath(path).lower().endswith(CAPTURE_SUFFIXES):
        return True
    try:
        container_kind(path)
        return True
    except UnsupportedContainerError:
        return False


def find_captures(root: str | os.PathLike[str], pattern: str | None = None) -> list[str]:
    """The captures under a local folder, in name order (folders walked depth first, sorted): a rosbag2
    folder (one with a ``metadata.yaml``) is one capture, not walked into; a file is one when it
    :func:`looks_like_capture`, or, with ``pattern`` (an ``fnmatch`` pattern), when its name matches.
    The one discovery of ``info`` and the archive jobs."""
    import fnmatch

    found: list[str] = []
    for dirpath, dirs, files in os.walk(root):
        dirs.sort()
        if "metadata.yaml" in files:
            dirs[:] = []
            if pattern is None or fnmatch.fnmatch(os.path.basename(dirpath), pattern):
                found.append(dirpath)
            continue
        for name in sorted(files):
            full = os.path.join(dirpath, name)
            if (fnmatch.fnmatch(name, pattern)) if pattern is not None else looks_like_capture(full):
                found.append(full)
    return found
