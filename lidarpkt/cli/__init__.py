"""The ``lidarpkt`` command line: one verb per job, each implemented in its own module.

Every verb module has ``add_arguments(parser)`` and ``run(args) -> int`` (exit status).
Modules are imported only when their verb runs, so ``lidarpkt info`` never pays for
the recorder or the analysis stack.
"""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys
import threading
import warnings
from typing import Any

from lidarpkt.errors import LidarpktError, LidarpktWarning

# verb -> (module implementing it, one-line help). Other verbs are added as one line each.
VERBS: dict[str, tuple[str, str]] = {
    "info": ("lidarpkt.cli.info", "say what streams and sensors a capture holds"),
    "catalog": ("lidarpkt.cli.archive", "one row per capture file and sensor stream of an archive, in parallel"),
    "export": ("lidarpkt.cli.archive", "export an archive to Parquet, LAS/LAZ, PLY, PCD, NPZ or MCAP on Dask"),
    "decode": ("lidarpkt.cli.decode", "decode captures to MCAP, NPZ, Parquet, LAS/LAZ, PLY, PCD, CSV, KITTI, Rerun or "
                                     "ROS bags"),
    "record": ("lidarpkt.cli.record", "record a live sensor (and a serial GPS) to MCAP"),
    "replay": ("lidarpkt.cli.replay", "send a capture's packets over UDP at the original pace"),
    "view": ("lidarpkt.cli.view", "show a capture or a live sensor in Foxglove (WebSocket, ws://localhost:8765)"),
    "analyze": ("lidarpkt.cli.analysis", "range CDFs, motion compensation and GMMs of chosen raypaths"),
    "multireturn": ("lidarpkt.cli.analysis", "whole-image multi-return statistics and monitor flags"),
    "compare-returns": ("lidarpkt.cli.analysis", "compare return slots or captures of one scene in different modes"),
    "registration-impact": ("lidarpkt.cli.registration", "pose error multi-return raypaths cause in scan matching, with and without the monitor"),
    "demo": ("lidarpkt.cli.demo", "the whole pipeline on the bundled fixtures: decode, MCAP, analysis, figures"),
}


class _Parser(argparse.ArgumentParser):
    """argparse with the CLI's one-line errors: ``lidarpkt: error: <flag>: <what>; <what to do>``, exit 2,
    and no abbreviated flags (one spelling per flag: ``--out`` is not ``--output``)."""

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def error(self, message: str):  # noqa: D102 - argparse's hook
        verb = self.prog.split()[-1] if " " in self.prog else None
        hint = f"see lidarpkt {verb} --help" if verb else "see lidarpkt --help"
        print(f"lidarpkt: error: {message}; {hint}", file=sys.stderr)
        sys.exit(2)


def _verb_module(verb: str):
    return importlib.import_module(VERBS[verb][0])


def build_parser(verb: str | None = None) -> argparse.ArgumentParser:
    """The argument parser. Every verb is listed from :data:`VERBS`; only ``verb``'s sub-parser is
    filled in, so that ``lidarpkt --help`` imports no verb module (``"*"`` fills them all)."""
    parser = _Parser(
        prog="lidarpkt",
        description="Decode, record and analyse the UDP packets of spinning lidars.",
    )
    # says which implementation runs: the compiled kernels, or why not (their NumPy twins are slower)
    parser.add_argument("--version", action=_VersionAction)
    sub = parser.add_subparsers(dest="verb", metavar="VERB", parser_class=_Parser)
    for name, (_, help_text) in VERBS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if verb == "*" or verb == name:
            module = _verb_module(name)
            adder = getattr(module, f"add_{name.replace('-', '_')}_arguments", None) or module.add_arguments
            adder(p)
    return parser


class _VersionAction(argparse.Action):
    """``--version``: the version string is made only when asked for (importlib.metadata's import is
    start-up time every other command would pay)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest, nargs=0, default=default,
                         help=help or "show the version and which kernels run, and exit")

    def __call__(self, parser, namespace, values, option_string=None):
        parser._print_message(f"lidarpkt {_version()}, {_kernels()}\n", sys.stdout)
        parser.exit()


def _version() -> str:
    from lidarpkt._version import __version__

    return __version__


def _kernels() -> str:
    """:func:`lidarpkt.core.kernels.describe` without importing the extension (and so NumPy)."""
    import importlib.util

    if os.environ.get("LIDARPKT_NATIVE") == "0":
        return "pure NumPy (disabled by LIDARPKT_NATIVE=0)"
    if importlib.util.find_spec("lidarpkt._native") is None:
        return "pure NumPy (extension not built)"
    return "compiled kernels (lidarpkt._native)"


def _show_warning(message, category, filename, lineno, file=None, line=None):
    if issubclass(category, LidarpktWarning):
        print(f"lidarpkt: warning: {message}", file=sys.stderr)
    else:
        print(warnings.formatwarning(message, category, filename, lineno, line), file=sys.stderr, end="")


#: set in the ``lidarpkt`` command's own process (and so in the processes it starts) unless already set:
#: lidarpkt does no large matrix algebra, and OpenBLAS (NumPy's BLAS) otherwise starts a thread per CPU at
#: ``import numpy`` that spins before it sleeps, on the cores the decoding needs (docs: performance)
COMMAND_ENVIRONMENT = {"OPENBLAS_NUM_THREADS": "1"}


def command() -> int:
    """The ``lidarpkt`` console script (and ``python -m lidarpkt``): :func:`main` in a process of its own,
    with :data:`COMMAND_ENVIRONMENT` set before NumPy is imported."""
    for name, value in COMMAND_ENVIRONMENT.items():
        os.environ.setdefault(name, value)
    return main()


def main(argv: list[str] | None = None) -> int:
    """The ``lidarpkt`` command line, run in this process (``argv`` by default ``sys.argv[1:]``). Returns the
    exit status: 0 done, 1 done with losses (``record``), 2 error (one line on stderr, no output left behind),
    130 interrupted."""
    from . import args as cliargs

    argv = cliargs.preparse_json(cliargs.preparse_pixel(list(sys.argv[1:] if argv is None else argv)))
    verb = next((a for a in argv if not a.startswith("-")), None)
    mark = cliargs.outputs_mark()
    previous_showwarning = warnings.showwarning
    warnings.showwarning = _show_warning
    previous_sigint = _interruptible()
    args = None
    try:
        parser = build_parser(verb if verb in VERBS else None)
        args = parser.parse_args(argv)
        if args.verb is None:
            parser.print_help()
            return 2
        module = _verb_module(args.verb)
        runner = getattr(module, f"run_{args.verb.replace('-', '_')}", None) or module.run
        return int(runner(args) or 0)
    except LidarpktError as exc:
        cliargs.discard_outputs(mark)
        print(cliargs.error_line(exc), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("lidarpkt: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into head & co.
        return 0
    except OSError as exc:  # a file operation no check foresaw (disk full, a folder removed meanwhile)
        cliargs.discard_outputs(mark)
        output = getattr(args, "output", None)
        where = exc.filename or (f"-o {output}" if output else "output")
        print(f"lidarpkt: error: {where}: {exc.strerror or exc}; check the path, its folder and the free space",
              file=sys.stderr)
        return 2
    finally:
        cliargs.forget_outputs(mark)
        warnings.showwarning = previous_showwarning
        if previous_sigint is not None:
            signal.signal(signal.SIGINT, previous_sigint)


def _interruptible() -> Any:
    """Ctrl-C stops every verb, also one started with SIGINT ignored (as a shell's ``&`` in a script starts
    it): the default handler is put back; returns the disposition to restore (None: nothing changed)."""
    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:
        return None
    return signal.signal(signal.SIGINT, signal.default_int_handler)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
