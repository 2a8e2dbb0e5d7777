"""The command line's conventions, in one place: the common flags, their checks, the error line.

Every verb builds its options from these helpers, so a flag means the same thing everywhere:

``-o/--output PATH``   the output; its suffix picks the format and must be one the verb writes.
``--json``             the verb's JSON document to stdout, wherever the flag stands (a switch).
``-o REPORT.json``     the same document to a file, in the verbs whose output is that document
                       (info, analyze, compare-returns, registration-impact; catalog's ``-o`` takes
                       ``.parquet`` or ``.json``). Where ``-o`` names another output (record's MCAP),
                       ``--report FILE.json`` writes the JSON. ``--json -o F.json`` does both.
``--plot DIR``         always a folder for figures (created if missing; its parent must exist).
``--metadata FILE``    repeatable, one per sensor: any vendor's description file, told apart by content
                       (``--calibration FILE`` is a second spelling); ``--model NAME`` where packets
                       cannot tell the model (:func:`add_sensor_options`, :func:`sensor_options`).
``-q/--quiet``         no progress bar and no status lines.
``--workers N``        the CPU cores a verb may use (threads that decode, Dask processes over an
                       archive, the threads of scan matching: the verb's help says which).
``--pixel ROW,COL``    a raypath; repeatable where several make sense.
``--port N``           a UDP port, 1–65535.

Outputs are checked before any computing (:func:`check_output`, :func:`check_folder`), by one
rule: the parent folder of an output must exist (nothing is created at the filesystem root by a
typo), and must be writable. Outputs a failed run created are removed (:func:`discard_outputs`),
so a failure leaves no half-written file. Errors are :class:`~lidarpkt.errors.UsageError`, and
the CLI prints them as one line, ``lidarpkt: error: <file or flag>: <what is wrong>; <what to do>``,
with exit status 2 (:func:`error_line`).

This module imports nothing heavy: ``lidarpkt --help`` goes through it.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
from pathlib import Path
from typing import Any, Iterable, Sequence

from lidarpkt.core.checks import PORT, WORKERS, Number
from lidarpkt.errors import InputFileError, LidarpktError, OutputError, UsageError

__all__ = [
    "add_output", "add_json", "check_json", "json_file", "emit_json", "wants_json", "add_plot", "add_sensor_options",
    "sensor_options", "add_quiet", "add_workers", "add_pixel",
    "parse_pixel", "port", "positive_int", "NUMBERS", "number", "check_output", "check_folder", "check_inputs",
    "discard_outputs", "error_line",
]

JSON_STDOUT = "-"


# ------------------------------------------------------------------------------ numeric flags
#: Every numeric flag of the command line and the values it takes, declared once: a flag means the same in
#: every verb that has it, and is checked the same way (:func:`number`: one line naming the flag and the
#: range, exit 2). The tests drive each with :meth:`~lidarpkt.core.checks.Number.bad_values`.
NUMBERS: dict[str, Number] = {
    "--workers": WORKERS,
    "--frames-per-file": Number(1, whole=True, example="100"),
    "--frames": Number(1, whole=True, example="10"),
    "--seed": Number(0, 2**32 - 1, whole=True, example="0"),
    "--grid": Number(0.05, 10, unit="degrees", example="0.2"),
    "--gap": Number(0, 1000, low_open=True, unit="metres", example="0.1"),
    "--threshold": Number(0, 1000, low_open=True, unit="metres", example="0.1"),
    "--neighbourhood": Number(1, 99, whole=True, odd=True, example="5"),
    "--monitor-frame": Number(0, whole=True, example="0"),
    "--gmm-components": Number(1, 16, whole=True, example="4"),
    "--downsample": Number(0, 100, low_open=True, unit="metres", example="0.25"),
    "--max-correspondence": Number(0, 1000, low_open=True, unit="metres", example="1"),
    "--voxel": Number(0, 100, low_open=True, unit="metres", example="1"),
    "--rate": Number(0, 1000, low_open=True, example="2"),
    "--duration": Number(0, low_open=True, unit="seconds", example="10"),
    "--start-after-fetch": Number(0, 3600, unit="seconds", example="1"),
    "--rotate-size": Number(0.1, 1 << 20, unit="MB", example="512"),
    "--rotate-time": Number(0.5, unit="seconds", example="60"),
    "--chunk-seconds": Number(0.01, 60, unit="seconds", example="0.5"),
    "--baud": Number(50, 4_000_000, whole=True, example="9600"),
    "--rcvbuf": Number(0.001, 2047, unit="MB", example="32"),  # the kernel's option is a C int of bytes
    "--queue": Number(0.0625, 1 << 16, unit="MB", example="256"),
}


def number(flag: str):
    """argparse ``type=`` for the numeric flag ``flag``, as :data:`NUMBERS` declares it."""
    return _argparse_type(NUMBERS[flag].parse, flag)


# ------------------------------------------------------------------------------ flag parsers
def parse_pixel(text: str, flag: str = "--pixel") -> tuple[int, int]:
    """``"ROW,COL"`` → (row, col), two non-negative integers. Raises :class:`UsageError`."""
    parts = text.replace(" ", "").split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        row, col = int(parts[0]), int(parts[1])
    except ValueError:
        raise UsageError(f"{flag} {text}: expected ROW,COL, two integers; write e.g. {flag} 7,900") from None
    if row < 0 or col < 0:
        raise UsageError(f"{flag} {text}: row and column count from 0; give non-negative numbers, e.g. {flag} 7,900")
    return row, col


def _argparse_type(fn, flag: str):
    """An argparse ``type=`` that raises our UsageError (one line, exit 2) rather than argparse's usage dump."""

    def convert(text: str):
        return fn(text, flag)

    convert.__name__ = flag.lstrip("-")
    return convert


def port(text: str, flag: str = "--port") -> int:
    """A UDP port number, 1–65535 (:data:`lidarpkt.core.checks.PORT`). Raises :class:`UsageError`."""
    return int(PORT.parse(text, flag))


def positive_int(text: str, flag: str) -> int:
    """An integer >= 1 (as :data:`NUMBERS` declares ``flag``, when it does). Raises :class:`UsageError`."""
    return int((NUMBERS.get(flag) or Number(1, whole=True, example="2")).parse(text, flag))


def _json_file(text: str, flag: str) -> str:
    if text.lower().endswith(".json"):
        return text
    raise UsageError(f"{flag} {text}: a JSON output must end in .json; give e.g. {flag} report.json "
                     "(or --json to print it)")


def port_type(flag: str = "--port"):
    """argparse ``type=`` for a UDP port (1-65535)."""
    return _argparse_type(port, flag)


def positive_int_type(flag: str):
    """argparse ``type=`` for a whole number ≥ 1 (``--workers``, ``--frames-per-file`` ...)."""
    return _argparse_type(positive_int, flag)


def json_type(flag: str = "--report"):
    """argparse ``type=`` for a JSON output file (``.json``)."""
    return _argparse_type(_json_file, flag)


# ------------------------------------------------------------------------------ adders
def add_output(parser: argparse.ArgumentParser, suffixes: Sequence[str], *, required: bool = True,
               help: str | None = None) -> None:
    """``-o/--output PATH``; ``suffixes`` (e.g. ``(".mcap", ".npz")``) are checked by :func:`check_output`."""
    what = " or ".join(f"OUT{s}" for s in suffixes) if suffixes else "DIR"
    parser.add_argument("-o", "--output", dest="output", required=required, metavar=what.split(" or ")[0],
                        help=help or f"the output: {what}")
    parser.set_defaults(_output_suffixes=tuple(suffixes))


_JSON_LEGACY = "--json-file-given"  # where preparse_json puts the file of the old ``--json FILE`` spelling


def add_json(parser: argparse.ArgumentParser, help: str = "the results as one JSON document", *,
             file_flag: str | None = "-o", aliases: Sequence[str] = ()) -> None:
    """``--json``: the JSON document to stdout (a switch, wherever it stands), and the flag that
    writes it to a file: ``file_flag="-o"`` adds ``-o/--output REPORT.json`` (the verbs whose output
    is that document); ``"--report"`` adds ``--report FILE.json`` (the verbs whose ``-o`` is another
    output); ``None`` when the verb's own ``-o`` takes ``.json`` and sets ``args.json_file`` itself.
    ``aliases`` are older spellings of the file flag."""
    parser.add_argument("--json", action="store_true",
                        help=f"{help}, printed to stdout" + (f" (to a file: {file_flag} FILE.json)" if file_flag else ""))
    if file_flag == "-o":
        parser.add_argument("-o", "--output", *aliases, dest="json_file", metavar="REPORT.json",
                            type=json_type("-o"), help=f"{help}, written to this file")
    elif file_flag:
        parser.add_argument(file_flag, *aliases, dest="json_file", metavar="FILE.json",
                            type=json_type(file_flag), help=f"{help}, written to this file")
    parser.add_argument(_JSON_LEGACY, dest="_json_legacy", default=None, help=argparse.SUPPRESS)
    parser.set_defaults(_json_file_flag=file_flag or "-o")


def preparse_json(argv: list[str]) -> list[str]:
    """The old spellings of ``--json`` with a value (``--json FILE.json``, ``--json -``, ``--json=FILE``)
    are set aside so that :func:`check_json` says what to write now, rather than the value being taken
    for an input."""
    out = []
    i = 0
    while i < len(argv):
        a = argv[i]
        nxt = argv[i + 1] if i + 1 < len(argv) else None
        if a == "--json" and nxt is not None and (nxt == JSON_STDOUT or nxt.lower().endswith(".json")):
            out += ["--json", f"{_JSON_LEGACY}={nxt}"]
            i += 2
            continue
        if a.startswith("--json="):
            value = a.split("=", 1)[1]
            out += ["--json"] + ([f"{_JSON_LEGACY}={value}"] if value else [])
            i += 1
            continue
        out.append(a)
        i += 1
    return out


def json_file(args: argparse.Namespace) -> str | None:
    """The file the JSON document goes to (``-o REPORT.json``, ``--report``), or None."""
    return getattr(args, "json_file", None)


def check_json(args: argparse.Namespace) -> None:
    """Before any work: the old ``--json FILE`` spelling named with its replacement, and the JSON
    file checked like any output. Raises :class:`UsageError` / :class:`OutputError`."""
    legacy = getattr(args, "_json_legacy", None)
    flag = getattr(args, "_json_file_flag", "-o")
    if legacy == JSON_STDOUT:
        raise UsageError("--json -: --json alone prints to stdout and takes no value; drop the -")
    if legacy:
        raise UsageError(f"--json {legacy}: --json prints the JSON to stdout and takes no file; "
                         f"write it to a file with {flag} {legacy}")
    target = json_file(args)
    if target:
        check_output(target, flag, (".json",))


def emit_json(args: argparse.Namespace, text: str) -> str | None:
    """Write the JSON document ``text``: to stdout with ``--json``, to the JSON file when one is
    named (under a temporary name, renamed when complete). Returns the file written, or None."""
    if not text.endswith("\n"):
        text += "\n"
    if getattr(args, "json", False):
        sys.stdout.write(text)
        sys.stdout.flush()
    target = json_file(args)
    if not target:
        return None
    from lidarpkt.writers.base import write_atomic

    flag = getattr(args, "_json_file_flag", "-o")
    try:
        write_atomic(target, lambda tmp: tmp.write_text(text, encoding="utf-8"))
    except OutputError as exc:
        raise OutputError(f"{flag} {exc}; choose a writable path") from exc
    return target


def wants_json(args: argparse.Namespace) -> bool:
    """A JSON document is asked for (stdout or a file)."""
    return bool(getattr(args, "json", False) or json_file(args))


def add_plot(parser: argparse.ArgumentParser, help: str = "write the figures (PNG) into this folder") -> None:
    """``--plot DIR``: always a folder (created if missing; its parent must exist)."""
    parser.add_argument("--plot", metavar="DIR", help=help)


def add_quiet(parser: argparse.ArgumentParser, help: str = "no progress bar and no status lines") -> None:
    parser.add_argument("-q", "--quiet", action="store_true", help=help)


def add_workers(parser: argparse.ArgumentParser) -> None:
    """``--workers N``: parallelism of the verbs that decode (1 = this thread only)."""
    parser.add_argument("--workers", type=number("--workers"), default=None, metavar="N",
                        help="use N CPU cores: a pcap/pcapng capture is cut into segments decoded by N processes "
                             "side by side (1: in this one; default: the idle CPUs, at most 4, for a capture of 64 MB "
                             "or more when three or more are idle, else 1)")


def add_pixel(parser: argparse.ArgumentParser, *, required: bool, help: str) -> None:
    """``--pixel ROW,COL``, repeatable; parsed into (row, col) tuples (a leading ``-`` is read as a value)."""
    parser.add_argument("--pixel", metavar="ROW,COL", action="append", default=[] if not required else None,
                        required=required, type=_argparse_type(parse_pixel, "--pixel"), help=help)


def preparse_pixel(argv: list[str]) -> list[str]:
    """``--pixel -1,5`` → ``--pixel=-1,5``, so that argparse passes a negative value to the parser
    (which names the problem) instead of saying "expected one argument"."""
    out = []
    i = 0
    while i < len(argv):
        a = argv[i]
        if a == "--pixel" and i + 1 < len(argv) and argv[i + 1].startswith("-") and argv[i + 1] != "-":
            out.append(f"--pixel={argv[i + 1]}")
            i += 2
            continue
        out.append(a)
        i += 1
    return out


# ------------------------------------------------------------------------------ sensor options
class _SensorFile(argparse.Action):
    """``--metadata FILE`` and ``--calibration FILE``: one list of files, each remembered with the flag that
    named it (the errors name the flag the user wrote)."""

    def __call__(self, parser, namespace, value, option_string=None):
        files = list(getattr(namespace, "metadata", None) or [])
        namespace.metadata = files + [value]
        flags = dict(getattr(namespace, "_sensor_flags", None) or {})
        flags.setdefault(value, option_string or "--metadata")
        namespace._sensor_flags = flags


def add_sensor_options(parser: argparse.ArgumentParser, help: str | None = None) -> None:
    """The sensor options of every verb that opens a capture: ``--metadata FILE`` (repeatable, one per
    sensor, any vendor's description file; ``--calibration FILE`` is a second spelling) and ``--model
    NAME``. :func:`sensor_options` turns them into the library's options."""
    parser.add_argument("--metadata", action=_SensorFile, default=None, metavar="FILE",
                        help=help or "a sensor's description file (its metadata or calibration, of any vendor, told "
                                     "apart by its content); repeat, one per sensor (sensors whose packets say "
                                     "enough need none; MCAP files recorded by lidarpkt carry theirs)")
    parser.add_argument("--calibration", action=_SensorFile, dest="metadata", metavar="FILE",
                        help="a second spelling of --metadata (the same files, told apart by content)")
    parser.add_argument("--model", "--velodyne-model", dest="model", metavar="NAME",
                        help="the sensor model where its packets cannot tell it (two models sharing a factory "
                             "byte); the second spelling is the former one")
    parser.set_defaults(_sensor_flags={})


def sensor_options(args: argparse.Namespace) -> dict[str, Any]:
    """The sensor options of the command line (:func:`add_sensor_options`) as the keyword options of
    ``lidarpkt.open``: every file to ``metadata`` (each checked: it exists, and it is a sensor file of some
    vendor, told apart by its content), the model to ``model`` (a model some vendor has), before any work.

    Raises:
        lidarpkt.errors.InputFileError: a file that does not exist.
        lidarpkt.errors.UsageError: a file of no known kind (or that its vendor cannot read), an unknown model;
            the message names the flag the user wrote.
    """
    from lidarpkt.vendors import registry

    flags = getattr(args, "_sensor_flags", None) or {}
    files: list[str] = []
    for path in getattr(args, "metadata", None) or ():
        flag = flags.get(path, "--metadata")
        if "://" not in path:  # a URL (archive jobs) is read where the capture is read
            check_inputs([path], flag)
            try:
                registry.load_sensor_files([path])
            except LidarpktError as exc:
                raise UsageError(f"{flag} {_after_name(str(exc), path)}") from None
        files.append(path)
    options: dict[str, Any] = {}
    if files:
        options["metadata"] = files
    model = getattr(args, "model", None)
    if model:
        try:
            registry.check_model(model)
        except UsageError as exc:
            raise UsageError(f"--model {model}: {str(exc).split(': ', 1)[1]}") from None
        options["model"] = model
    return options


def _after_name(message: str, path: str) -> str:
    """``"PATH: what"`` of a library message about ``path`` (the path in front once, whatever the message)."""
    return message if message.startswith(path) else f"{path}: {message}"


# ------------------------------------------------------------------------------ checks
_created: list[tuple[Path, bool]] = []  # outputs this run created (path, is_folder): removed on failure


def _writable_folder(folder: Path, flag: str, path: Path) -> None:
    if not folder.is_dir():
        raise OutputError(f"{flag} {path}: the folder {folder} does not exist; create it first or choose another path")
    import tempfile  # here, not at the top: every command's start-up would pay for it

    try:  # the real test: root ignores permission bits, /proc and read-only mounts do not
        fd, probe = tempfile.mkstemp(prefix=".lidarpkt-probe-", dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise OutputError(f"{flag} {path}: cannot write in {folder} ({exc.strerror or exc}); "
                          "choose a writable folder") from None


def check_output(path: str | os.PathLike[str], flag: str = "-o", suffixes: Sequence[str] = (), *,
                 keep_on_error: bool = False) -> Path:
    """Check an output file before any work: known suffix, existing and writable parent folder,
    not a folder itself. Remembers it for :func:`discard_outputs` if it does not exist yet, unless
    ``keep_on_error`` (a recording: what was written before a disk filled up stays readable).

    Raises :class:`~lidarpkt.errors.OutputError` naming the flag, the path and what to do.
    """
    out = Path(path)
    if suffixes and out.suffix.lower() not in suffixes:
        accepted = ", ".join(suffixes)
        raise OutputError(f"{flag} {out}: unknown output type {out.suffix or '(no suffix)'!r}; "
                          f"the accepted suffixes are {accepted}")
    if out.is_dir():
        raise OutputError(f"{flag} {out}: is a folder; give a file name ending in {', '.join(suffixes) or 'a suffix'}")
    _writable_folder(out.parent if str(out.parent) else Path("."), flag, out)
    if out.exists() and not os.access(out, os.W_OK):
        raise OutputError(f"{flag} {out}: the file exists and is not writable; choose another path")
    if not out.exists() and not keep_on_error:
        _created.append((out, False))
    return out


def check_folder(path: str | os.PathLike[str], flag: str = "--plot") -> Path:
    """Check (and create) an output folder before any work: its parent must exist and be writable.

    Raises :class:`~lidarpkt.errors.OutputError`.
    """
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise OutputError(f"{flag} {out}: is a file, not a folder; {flag} takes a folder (give a new name or an existing folder)")
    if out.is_dir():
        _writable_folder(out, flag, out)
        return out
    _writable_folder(out.parent if str(out.parent) else Path("."), flag, out)
    try:
        out.mkdir()
    except OSError as exc:
        raise OutputError(f"{flag} {out}: cannot create the folder ({exc.strerror or exc}); choose another") from None
    _created.append((out, True))
    return out


def check_inputs(paths: Iterable[str | os.PathLike[str]], flag: str | None = None) -> None:
    """Each input exists and is readable. Raises :class:`~lidarpkt.errors.InputFileError`:
    ``<flag> <path>: no such file or directory; ...``."""
    for path in paths:
        p = Path(path)
        name = f"{flag} {p}" if flag else str(p)
        if not p.exists():
            raise InputFileError(f"{name}: no such file or directory; check the path")
        if p.is_file() and not os.access(p, os.R_OK):
            raise InputFileError(f"{name}: not readable (permission denied); check its permissions")


def outputs_mark() -> int:
    """Where a run's outputs start in the list of remembered ones (runs nest: ``demo`` runs ``decode``)."""
    return len(_created)


def forget_outputs(since: int = 0) -> None:
    """Forget the outputs remembered since ``since`` (the run that made them is over)."""
    del _created[since:]


def discard_outputs(since: int = 0) -> list[Path]:
    """Remove the outputs created since ``since`` (that run failed): files, and folders it made."""
    removed = []
    for out, is_folder in reversed(_created[since:]):
        try:
            if is_folder and out.is_dir():
                shutil.rmtree(out)
                removed.append(out)
            elif not is_folder and out.exists():
                out.unlink()
                removed.append(out)
        except OSError:
            pass
    forget_outputs(since)
    return removed


def error_line(exc: BaseException) -> str:
    """The one line the CLI prints for an error."""
    text = " ".join(str(exc).split())  # one line whatever the message held
    return f"lidarpkt: error: {text}"
