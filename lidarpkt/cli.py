"""The ``lidarpkt`` command line: one verb per job, each implemented in its own module.

Every verb module has ``add_arguments(parser)`` and ``run(args) -> int`` (exit status).
Modules are imported only when their verb runs, so ``lidarpkt info`` never pays for
the recorder or the analysis stack.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import warnings

from .errors import LidarpktError, LidarpktWarning

# verb -> (module implementing it, one-line help)
VERBS: dict[str, tuple[str, str]] = {
    "info": ("lidarpkt.info", "say what streams and sensors a capture holds"),
    "catalog": ("lidarpkt.archive.cli", "one row per capture file and sensor stream of an archive, in parallel"),
    "export": ("lidarpkt.archive.cli", "export an archive to Parquet, LAS/LAZ, PLY, PCD, NPZ or MCAP on Dask"),
    "decode": ("recorder.decode", "decode captures to MCAP (raw packets and frames) or NumPy .npz"),
    "record": ("recorder.record", "record a live sensor (and a serial GPS) to MCAP"),
    "replay": ("recorder.replay", "send a capture's packets over UDP at the original pace"),
    "analyze": ("analysis.cli", "range CDFs, motion compensation and GMMs of chosen raypaths"),
    "multireturn": ("analysis.cli", "whole-image multi-return statistics and monitor flags"),
    "compare-returns": ("analysis.cli", "compare return slots or captures of one scene in different modes"),
    "demo": ("lidarpkt.demo", "the whole pipeline on the bundled fixtures: decode, MCAP, analysis, figures"),
}


def _verb_module(verb: str):
    module = importlib.import_module(VERBS[verb][0])
    return module


def build_parser(verb: str | None = None) -> argparse.ArgumentParser:
    """The argument parser; only ``verb``'s sub-parser is filled in (all of them when None)."""
    parser = argparse.ArgumentParser(
        prog="lidarpkt",
        description="Decode, record and analyse Velodyne VLP-16 and Ouster OS1 lidar packets.",
    )
    from . import kernels

    # says which implementation runs: the compiled kernels, or why not (their NumPy twins are slower)
    parser.add_argument("--version", action="version", version=f"lidarpkt {_version()}, {kernels.describe()}")
    sub = parser.add_subparsers(dest="verb", metavar="VERB")
    for name, (_, help_text) in VERBS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if verb is None or verb == name:
            module = _verb_module(name)
            adder = getattr(module, f"add_{name.replace('-', '_')}_arguments", None) or module.add_arguments
            adder(p)
    return parser


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("lidarpkt")
    except Exception:  # not installed (running from a checkout)
        return "unknown"


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``lidarpkt`` console script. Returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    verb = next((a for a in argv if not a.startswith("-")), None)
    parser = build_parser(verb if verb in VERBS else None)
    args = parser.parse_args(argv)
    if args.verb is None:
        parser.print_help()
        return 2
    module = _verb_module(args.verb)
    runner = getattr(module, f"run_{args.verb.replace('-', '_')}", None) or module.run

    def show_warning(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, LidarpktWarning):
            print(f"lidarpkt: warning: {message}", file=sys.stderr)
        else:
            print(warnings.formatwarning(message, category, filename, lineno, line), file=sys.stderr, end="")

    warnings.showwarning = show_warning
    try:
        return int(runner(args) or 0)
    except LidarpktError as exc:
        print(f"lidarpkt: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("lidarpkt: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into head & co.
        return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
