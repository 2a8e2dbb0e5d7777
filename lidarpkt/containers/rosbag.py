"""ROS 1 and rosbag2 bags opened through ``rosbags``: what it leaves open when opening fails or damage is
met (:func:`close_failed_open`, :func:`release`), damage met while stepping its messages as one
:class:`~lidarpkt.errors.CaptureFormatError` after the messages before it (:func:`guarded`), and a
rosbag2 ``metadata.yaml`` whose fields an old writer left empty, completed in a temporary folder
(:func:`with_default_metadata`)."""

from __future__ import annotations

import os
import traceback
from pathlib import Path
from typing import Any, Iterator

from ..errors import CaptureFormatError
from .inflate import next_bounded
from .magic import MCAP_MAGIC, SQLITE_MAGIC


# the modules whose frames are still running when release() is called (the bag reader's and this one)
_CALLERS = frozenset({__name__, __name__.rsplit(".", 1)[0] + ".bags"})


def release(exc: BaseException | None) -> None:
    """Clear the locals of the library frames that ``exc`` (and what it chains) keeps, then close the
    sqlite3 connections among them. An error met while stepping a query keeps rosbags' cursor, and so
    the ``.db3``, open; rosbags' sqlite3 storage does not close the connection it opened when the
    tables are missing. Either file would stay open while the caller keeps our error, and after it
    until a garbage collection (a sqlite3 connection lives in a reference cycle). Cursors go first: a
    connection closed under a live cursor stays open for as long as the cursor."""
    import sqlite3

    connections = []
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        for frame, _ in traceback.walk_tb(exc.__traceback__):
            if frame.f_globals.get("__name__") in _CALLERS:
                continue  # ours, still running
            names = frame.f_locals
            connections += [v for v in names.values() if isinstance(v, sqlite3.Connection)]
            try:
                frame.clear()
            except RuntimeError:  # still running
                continue
            if isinstance(names, dict):
                names.clear()  # before Python 3.13, the f_locals snapshot outlives frame.clear()
        exc = exc.__cause__ or exc.__context__
    for connection in connections:
        connection.close()


def close_failed_open(reader: Any, exc: BaseException) -> None:
    """Close what rosbags opened before its ``open()`` failed, which it leaves open: the ROS 1 reader's
    file (first line not UTF-8), a rosbag2's MCAP storage files (bad magic, cut index), its sqlite3
    connections, the folder of a decompressed bag."""
    for sub in getattr(reader, "readers", ()):
        storage = getattr(sub, "storage", None)
        opened = [getattr(sub, "bio", None), *getattr(storage, "dbconns", ()),
                  *(getattr(f, "bio", None) for f in getattr(storage, "readers", ()))]
        for obj in opened:
            if obj is not None:
                obj.close()
        if getattr(sub, "tmpdir", None) is not None:
            sub.tmpdir.cleanup()
    release(exc)


def guarded(messages: Iterator, path: Path, scoped: bool = False) -> Iterator:
    """The bag's messages; damage met on the way (a corrupt chunk, a truncated file) becomes a
    :class:`CaptureFormatError` once every message before it was delivered. ``scoped``: each step inflates
    a rosbag2's MCAP chunks boundedly (:func:`~lidarpkt.containers.inflate.next_bounded`)."""
    it = iter(messages)
    while True:
        try:
            # bounded around each step only: the caller's code between steps sees rosbags' own inflaters
            item = next_bounded(it, path) if scoped else next(it)
        except StopIteration:
            return
        except Exception as exc:  # rosbags / sqlite3 raise their own types
            release(exc)
            if isinstance(exc, CaptureFormatError):  # ours (a bounded inflater's), naming the file already
                raise CaptureFormatError(str(exc)) from None
            raise CaptureFormatError(f"{path}: the bag is damaged after the messages already read: {exc}") from None
        yield item


def with_default_metadata(bag: Path) -> tuple[Any, str] | None:
    """A temporary rosbag2 folder whose ``metadata.yaml`` fills the fields an old rosbag2 writer left
    empty or out, and links to ``bag``'s storage files; ``None`` when nothing is missing (or the YAML is
    not a rosbag2's: rosbags says what is wrong with it). A missing ``storage_identifier`` is the storage
    its files are (sqlite3 or mcap, by their first bytes); a missing ``serialization_format`` is ``cdr``,
    the only one rosbag2 writes. Returns ``(TemporaryDirectory, what was filled in)``."""
    import tempfile

    from ruamel.yaml import YAML, YAMLError

    try:
        doc = YAML(typ="safe").load((bag / "metadata.yaml").read_text())
        info = doc["rosbag2_bagfile_information"]
        files = [bag / Path(str(name)).name for name in info.get("relative_file_paths") or []]
        topics = [t["topic_metadata"] for t in info.get("topics_with_message_count") or []]
    except (OSError, YAMLError, KeyError, TypeError, AttributeError, UnicodeDecodeError):
        return None
    notes = []
    if not info.get("storage_identifier"):
        storage = None
        for file in files:
            try:
                with file.open("rb") as fh:
                    head = fh.read(max(len(SQLITE_MAGIC), len(MCAP_MAGIC)))
            except OSError:
                continue
            storage = "sqlite3" if head.startswith(SQLITE_MAGIC) else "mcap" if head.startswith(MCAP_MAGIC) else None
            if storage:
                break
        if storage is None:
            return None  # rosbags names the missing plugin
        info["storage_identifier"] = storage
        notes.append(f"names no storage plugin (its files are {storage})")
    empty = [t.get("name", "?") for t in topics if isinstance(t, dict) and not t.get("serialization_format")]
    for topic in topics:
        if isinstance(topic, dict) and not topic.get("serialization_format"):
            topic["serialization_format"] = "cdr"
    if empty:
        notes.append(f"names no serialization format for {', '.join(map(str, empty[:4]))} (cdr, rosbag2's own)")
    if not notes:
        return None
    folder = tempfile.TemporaryDirectory(prefix="lidarpkt-bag-")
    try:
        for file in files:
            if file.exists():
                os.symlink(file.resolve(), Path(folder.name, file.name))
        yaml = YAML(typ="safe")
        yaml.default_flow_style = False
        with Path(folder.name, "metadata.yaml").open("w") as fh:
            yaml.dump(doc, fh)
    except OSError as exc:
        folder.cleanup()
        raise CaptureFormatError(f"{bag}: metadata.yaml {'; '.join(notes)}, and completing it in a temporary "
                                 f"folder failed: {exc}") from exc
    return folder, "; ".join(notes)
