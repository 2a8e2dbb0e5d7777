"""``lidarpkt info FILE... [--json] [-o OUT.json] [--metadata FILE ...]``: what streams and sensors a capture
holds (:func:`lidarpkt.pipeline.describe.describe_capture`).

One line per stream, then the reader's counts (:func:`~lidarpkt.pipeline.describe.format_capture`).
``--json`` prints the same as one JSON document (one capture object, or ``{"captures": [...]}`` for several
files) on stdout; ``-o OUT.json`` writes it to a file.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Sequence

from lidarpkt.containers.magic import CAPTURES_TEXT, find_captures
from lidarpkt.errors import LidarpktError

__all__ = ["add_arguments", "run"]


def _expand(paths: Sequence[str]) -> list[str]:
    """The files to describe: a directory (other than a rosbag2 folder) stands for every capture under it
    (:func:`lidarpkt.containers.magic.find_captures`, as the archive jobs find them), in name order."""
    out: list[str] = []
    for path in paths:
        if os.path.isdir(path) and not os.path.exists(os.path.join(path, "metadata.yaml")):
            found = find_captures(path)
            out.extend(found if found else [path])  # an empty folder still gets its error
        else:
            out.append(path)
    return out


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``lidarpkt info``."""
    from . import args as cliargs

    parser.add_argument(
        "files", nargs="+", metavar="FILE",
        help=f"captures ({CAPTURES_TEXT}); a directory stands for every capture under it",
    )
    cliargs.add_json(parser, "the descriptions as one JSON document instead of text")
    cliargs.add_sensor_options(parser, "the sensor file of a sensor in the capture (names what its packets are "
                                       "exactly); repeat, one per sensor")
    cliargs.add_quiet(parser, "accepted by every verb; info draws no progress bar or status line anyway")


def run(args: argparse.Namespace) -> int:
    """Describe each file; exit status 0, or 2 when a file could not be read (the others are still described)."""
    from lidarpkt.pipeline.describe import describe_capture, format_capture
    from lidarpkt.vendors import registry

    from . import args as cliargs

    options = cliargs.sensor_options(args)
    cliargs.check_json(args)
    metadata = registry.load_sensor_files(options.get("metadata", ()))
    docs = []
    status = 0
    for path in _expand(args.files):
        try:
            if not os.path.exists(path):
                cliargs.check_inputs([path])
            docs.append(describe_capture(path, metadata))
        except LidarpktError as exc:
            status = 2
            docs.append({"file": os.fspath(path), "error": str(exc)})
            print(cliargs.error_line(exc), file=sys.stderr)
    if cliargs.wants_json(args):
        doc = docs[0] if len(docs) == 1 else {"captures": docs}
        cliargs.emit_json(args, json.dumps(doc, indent=2))
    elif any("error" not in d for d in docs):
        print("\n\n".join(format_capture(d) for d in docs if "error" not in d))
    return status
