"""The manifest of an export job: one JSON line per input and segment, in OUTDIR.

``OUTDIR/_manifest.jsonl`` (the leading ``_`` keeps Parquet readers off it) gets one line
per finished unit: status (``done`` or ``failed``), outputs (relative to OUTDIR), counts and
error. Lines are appended and flushed as units finish, so a job killed at any point leaves a
manifest of what is complete; a torn last line is ignored. A re-run skips the units whose
latest line says ``done`` for the same job options and the same input (size and mtime), and
whose outputs are all still there.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any, Iterable

from lidarpkt.errors import LidarpktError

from .plan import is_remote, local_path
from .unit import UnitResult, UnitTask

MANIFEST_NAME = "_manifest.jsonl"
LOCK_NAME = "_lidarpkt_export.lock"
COLUMNS = ("key", "input", "capture", "part", "status", "outputs", "frames", "points", "lost_packets",
           "skipped_packets", "malformed_packets", "warnings", "seconds", "cpu_seconds", "error", "size_bytes",
           "mtime_ns", "job", "finished_at")


class ExportBusyError(LidarpktError):
    """Another export job is writing the same OUTDIR."""


def job_fingerprint(fmt: str, options: Iterable[tuple[str, Any]]) -> str:
    """What makes outputs differ besides the input: the format and the writer options (and, since
    segments write whole-file VLP-16 frame ids, ``ordinals``: outputs of earlier jobs are redone)."""
    return json.dumps({"format": fmt, "ordinals": "whole-file", **{k: v for k, v in options}}, sort_keys=True,
                      default=str)


def make_row(task: UnitTask, result: UnitResult, *, capture_mtime_ns: int, job: str) -> dict[str, Any]:
    """The manifest row of one finished unit."""
    row = asdict(result)
    row.update(capture=task.capture, status="done" if result.ok else "failed", outputs=list(result.outputs),
               warnings=list(result.warnings), mtime_ns=capture_mtime_ns, job=job,
               finished_at=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), size_bytes=task.size_bytes)
    return {c: row.get(c) for c in COLUMNS}


class Manifest:
    """The manifest of one OUTDIR (local path or fsspec URL), read at the start and appended to."""

    def __init__(self, outdir: str) -> None:
        self.outdir = outdir
        self.remote = is_remote(outdir)
        self.url = f"{outdir.rstrip('/')}/{MANIFEST_NAME}" if self.remote else str(Path(local_path(outdir)) / MANIFEST_NAME)
        self.rows: list[dict[str, Any]] = self._read()
        self._last_flush = 0.0
        self._dirty = False

    def _read(self) -> list[dict[str, Any]]:
        try:
            if self.remote:
                import fsspec

                with fsspec.open(self.url, "rt", encoding="utf-8") as fh:
                    text = fh.read()
            else:
                text = Path(self.url).read_text(encoding="utf-8")
        except FileNotFoundError:
            return []
        rows = []
        for line in text.splitlines():
            try:
                row = json.loads(line)
            except json.JSONDecodeError:  # the torn last line of a killed job
                continue
            if isinstance(row, dict) and "key" in row:
                rows.append(row)
        return rows

    def latest(self) -> dict[str, dict[str, Any]]:
        """The last row of each unit key."""
        return {row["key"]: row for row in self.rows}

    def is_done(self, task: UnitTask, *, mtime_ns: int, job: str) -> bool:
        """Did an earlier run finish this unit, with these options, on this very input?"""
        row = self.latest().get(task.key)
        if not row or row.get("status") != "done" or row.get("job") != job:
            return False
        if row.get("size_bytes") != task.size_bytes or row.get("mtime_ns") != mtime_ns:
            return False
        if self.remote:
            return True
        root = Path(local_path(self.outdir))
        return all((root / rel).is_file() for rel in row.get("outputs") or ())

    def append(self, row: dict[str, Any]) -> None:
        """Record a finished unit (flushed to disk before returning, for a local OUTDIR)."""
        self.rows.append(row)
        if self.remote:
            self._dirty = True
            if time.monotonic() - self._last_flush > 2.0:
                self.flush()
            return
        with open(self.url, "a", encoding="utf-8") as fh:
            fh.write(json.dumps(row, default=str) + "\n")
            fh.flush()
            os.fsync(fh.fileno())

    def flush(self) -> None:
        """Write the whole manifest to a remote OUTDIR (object stores have no append)."""
        if not self.remote or not self._dirty:
            return
        import fsspec

        with fsspec.open(self.url, "wt", encoding="utf-8") as fh:
            fh.write("".join(json.dumps(r, default=str) + "\n" for r in self.rows))
        self._dirty = False
        self._last_flush = time.monotonic()


class OutdirLock:
    """``OUTDIR/_lidarpkt_export.lock`` holding the job's PID while it runs (local OUTDIR only):
    a second job on the same OUTDIR is refused; the lock of a killed job (its PID gone) is taken over."""

    def __init__(self, outdir: str) -> None:
        self.path = None if is_remote(outdir) else Path(local_path(outdir)) / LOCK_NAME

    def __enter__(self) -> "OutdirLock":
        if self.path is None:
            return self
        for _ in range(2):
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                if _alive(self.path):
                    raise ExportBusyError(
                        f"{self.path.parent}: another export job (PID {self.path.read_text().strip()}) is writing this "
                        "folder; wait for it or choose another -o") from None
                self.path.unlink(missing_ok=True)
                continue
            with os.fdopen(fd, "w") as fh:
                fh.write(f"{os.getpid()}\n")
            return self
        raise ExportBusyError(f"{self.path}: cannot take the lock; remove it if no export job is running")

    def __exit__(self, *exc) -> None:
        if self.path is not None:
            self.path.unlink(missing_ok=True)


def _alive(lock: Path) -> bool:
    try:
        pid = int(lock.read_text().strip())
    except (OSError, ValueError):
        return False
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
