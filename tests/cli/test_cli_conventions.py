"""One tool, not eight (issue 14): every verb, driven as a user does, with bad inputs of every kind.

Each case runs through ``lidarpkt.cli.main`` in this process and as ``python -m lidarpkt`` in a
subprocess, and must give exit status 2, exactly one line on stderr of the form
``lidarpkt: error: <file or flag>: <what is wrong>; <what to do>`` naming the file or flag, no
traceback, and no output file left behind.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from lidarpkt.cli import VERBS, main

from conftest import external

REPO = Path(__file__).resolve().parents[2]
VLP20 = "veloview/vlp-16-test-90deg-1-50-frames.pcap"
VLP10 = "rust-lidar-utils/velodyne_example.pcap"
OS0 = "ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.pcap"
OS0_JSON = "ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.json"
OS2 = "ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.pcap"


def _cases(tmp: Path) -> list[tuple[str, list[str], str, list[Path]]]:
    """(case id, argv, text the error line must hold, outputs that must not exist afterwards)."""
    vlp, vlp10 = str(external(VLP20)), str(external(VLP10))
    os0, os0_json, os2 = str(external(OS0)), str(external(OS0_JSON)), str(external(OS2))
    missing = str(tmp / "missing.pcap")
    out = tmp / "out"
    return [
        # info
        ("info-missing", ["info", missing], f"{missing}: no such file or directory", []),
        ("info-metadata-missing", ["info", vlp, "--metadata", str(tmp / "m.json")], "--metadata", []),
        ("info-json-suffix", ["info", vlp, "-o", str(tmp / "i.txt")], "-o", [tmp / "i.txt"]),
        ("info-json-unwritable", ["info", vlp, "-o", "/proc/lidarpkt-i.json"], "/proc", []),
        ("info-json-old-spelling", ["info", vlp, "--json", str(tmp / "i.json")], f"-o {tmp / 'i.json'}",
         [tmp / "i.json"]),
        ("info-not-a-capture", ["info", str(external("einride-vlp16-go/packet.bin"))], "is not a capture lidarpkt reads",
         []),
        ("decode-not-a-capture", ["decode", str(external("einride-vlp16-go/packet.bin")), "-o", str(tmp / "n.npz")],
         "is not a capture lidarpkt reads", [tmp / "n.npz"]),
        # decode
        ("decode-missing", ["decode", missing, "-o", str(out / "x.npz")], "no such file or directory", []),
        ("decode-proc", ["decode", vlp10, "-o", "/proc/lidarpkt-out.npz"], "-o /proc/lidarpkt-out.npz", []),
        ("decode-sys", ["decode", vlp10, "-o", "/sys/lidarpkt-out.mcap"], "-o /sys/lidarpkt-out.mcap", []),
        ("decode-suffix", ["decode", vlp10, "-o", str(tmp / "x.png")], ".mcap, .npz", [tmp / "x.png"]),
        ("decode-no-folder", ["decode", vlp10, "-o", str(tmp / "nodir" / "x.npz")], "does not exist",
         [tmp / "nodir"]),
        ("decode-grid", ["decode", vlp10, "-o", str(tmp / "g.npz"), "--grid", "-1"], "--grid", [tmp / "g.npz"]),
        ("decode-ouster-no-metadata", ["decode", os0, "-o", str(tmp / "o.npz")], "no Ouster metadata",
         [tmp / "o.npz"]),
        ("decode-wrong-metadata", ["decode", os2, "--metadata", os0_json, "-o", str(tmp / "w.mcap")],
         "24832 B", [tmp / "w.mcap"]),
        # record
        ("record-port-range", ["record", "--port", "80000", "-o", str(tmp / "r.mcap")], "--port 80000",
         [tmp / "r.mcap"]),
        ("record-port-zero", ["record", "--port", "0", "-o", str(tmp / "r.mcap")], "--port 0", [tmp / "r.mcap"]),
        ("record-gps", ["record", "--port", "2368", "--gps", "/dev/ttyNOPE", "-o", str(tmp / "g.mcap")],
         "--gps /dev/ttyNOPE: no such file or directory", [tmp / "g.mcap"]),
        ("record-suffix", ["record", "--port", "2368", "-o", str(tmp / "r.bag")], ".mcap", [tmp / "r.bag"]),
        ("record-proc", ["record", "--port", "2368", "-o", "/proc/lidarpkt-r.mcap"], "/proc", []),
        ("record-base-frame-without-points", ["record", "--port", "2368", "--base-frame", "base_link", "-o",
                                              str(tmp / "b.mcap")], "add --points", [tmp / "b.mcap"]),
        ("record-mount-without-base", ["record", "--port", "2368", "--points", "--mount", "1,0,0,0,0,0", "-o",
                                       str(tmp / "m.mcap")], "--mount", [tmp / "m.mcap"]),
        # replay
        ("replay-missing", ["replay", missing, "--to", "127.0.0.1:2368"], "no such file or directory", []),
        ("replay-port-range", ["replay", vlp10, "--to", "127.0.0.1:80000"], "--to 127.0.0.1:80000", []),
        ("replay-port-map", ["replay", vlp10, "--to", "127.0.0.1:2368", "--port-map", "8308:0"], "--port-map", []),
        ("replay-rate", ["replay", vlp10, "--to", "127.0.0.1:2368", "--rate", "0"], "--rate", []),
        # view
        ("view-missing", ["view", missing, "--ws", "127.0.0.1:0"], "no such file or directory", []),
        ("view-ws-port", ["view", vlp10, "--ws", "127.0.0.1:80000"], "--ws", []),
        ("view-rate", ["view", vlp10, "--ws", "127.0.0.1:0", "--rate", "0"], "--rate 0", []),
        ("view-metadata-missing", ["view", vlp10, "--metadata", str(tmp / "m.json")], "--metadata", []),
        ("view-port-range", ["view", "--port", "80000"], "--port 80000", []),
        # analyze
        ("analyze-missing", ["analyze", missing, "--pixel", "7,100"], "no such file or directory", []),
        ("analyze-pixel-negative", ["analyze", vlp, "--pixel", "-1,5"], "--pixel -1,5", []),
        ("analyze-pixel-form", ["analyze", vlp, "--pixel", "7"], "--pixel 7", []),
        ("analyze-pixel-range", ["analyze", vlp, "--pixel", "7,5000"], "--pixel 7,5000: outside", []),
        ("analyze-plot-proc", ["analyze", vlp, "--pixel", "7,100", "--plot", "/proc/lidarpkt-figs"], "--plot", []),
        ("analyze-json-root", ["analyze", vlp, "--pixel", "7,100", "-o", "/nonexistent-lidarpkt/r.json"],
         "does not exist", [Path("/nonexistent-lidarpkt")]),
        ("analyze-ouster-no-metadata", ["analyze", os0, "--pixel", "1,1", "-o", str(tmp / "a.json"),
                                        "--plot", str(tmp / "afigs")], "--metadata",
         [tmp / "a.json", tmp / "afigs"]),
        # multireturn
        ("multireturn-png", ["multireturn", vlp, "-o", str(tmp / "x.png")], "accepted suffixes are .npz",
         [tmp / "x.png", tmp / "x.png.npz"]),
        ("multireturn-noext", ["multireturn", vlp, "-o", str(tmp / "mapnoext")], "accepted suffixes are .npz",
         [tmp / "mapnoext.npz"]),
        ("multireturn-root", ["multireturn", vlp, "-o", "/nonexistent-lidarpkt/m.npz"], "does not exist",
         [Path("/nonexistent-lidarpkt")]),
        ("multireturn-plot-proc", ["multireturn", vlp, "-o", str(tmp / "m.npz"), "--plot", "/proc/x/m.png"],
         "--plot", [tmp / "m.npz"]),
        ("multireturn-wrong-metadata", ["multireturn", os2, "--metadata", os0_json, "-o", str(tmp / "mm.npz"),
                                        "--plot", str(tmp / "mfigs")], "does not fit", [tmp / "mm.npz", tmp / "mfigs"]),
        # compare-returns
        ("compare-json-proc", ["compare-returns", vlp, "-o", "/proc/lidarpkt-c.json"], "-o /proc", []),
        ("compare-plot-file", ["compare-returns", vlp, "--plot", str(tmp / "c.png")], "--plot", [tmp / "c.png"]),
        ("compare-missing-second", ["compare-returns", vlp, missing], "no such file or directory", []),
        # catalog and export
        ("catalog-suffix", ["catalog", vlp10, "-o", str(tmp / "c.csv")], ".parquet", [tmp / "c.csv"]),
        ("catalog-proc", ["catalog", vlp10, "-o", "/proc/lidarpkt-c.parquet"], "/proc", []),
        ("catalog-json-suffix", ["catalog", vlp10, "-o", str(tmp / "c.txt")], "-o", [tmp / "c.txt"]),
        ("catalog-workers", ["catalog", vlp10, "-o", str(tmp / "c.parquet"), "--workers", "0"], "--workers 0",
         [tmp / "c.parquet"]),
        ("export-missing-input", ["export", missing, "-o", str(tmp / "ex"), "--format", "npz", "--workers", "1"],
         "no such file or directory", [tmp / "ex"]),
        ("export-proc", ["export", vlp10, "-o", "/proc/lidarpkt-ex", "--format", "npz", "--workers", "1"],
         "-o /proc/lidarpkt-ex", []),
        ("multireturn-folder-missing-input", ["multireturn", vlp10, missing, "-o", str(tmp / "mr"), "--workers", "1"],
         "no such file or directory", [tmp / "mr"]),
        ("export-format", ["export", vlp10, "-o", str(tmp / "e"), "--format", "tiff"], "--format", [tmp / "e"]),
        ("export-metadata-missing", ["export", vlp10, "-o", str(tmp / "e"), "--format", "npz", "--metadata",
                                     str(tmp / "m.json")], "--metadata", [tmp / "e"]),
        ("export-frames-per-file", ["export", vlp10, "-o", str(tmp / "e"), "--format", "las", "--frames-per-file",
                                    "0"], "--frames-per-file 0", [tmp / "e"]),
        # registration-impact
        ("registration-missing", ["registration-impact", missing], "no such file or directory", []),
        ("registration-json-proc", ["registration-impact", vlp, "-o", "/proc/lidarpkt-r.json"], "-o /proc", []),
        ("record-json-old-spelling", ["record", "--port", "2368", "-o", str(tmp / "r.mcap"), "--json",
                                      str(tmp / "r.json")], f"--report {tmp / 'r.json'}", [tmp / "r.mcap"]),
        ("registration-plot-file", ["registration-impact", vlp, "--plot", str(tmp / "r.png")], "--plot",
         [tmp / "r.png"]),
        ("registration-workers", ["registration-impact", vlp, "--workers", "0"], "--workers 0", []),
        ("registration-map-missing", ["registration-impact", vlp, "--map", str(tmp / "g.npz")], "--map", []),
        # demo
        ("demo-out-proc", ["demo", "-o", "/proc/lidarpkt-demo"], "/proc/lidarpkt-demo", []),
        ("demo-root", ["demo", "-o", "/nonexistent-lidarpkt/demo"], "does not exist", [Path("/nonexistent-lidarpkt")]),
        ("demo-frames", ["demo", "-o", str(tmp / "demo"), "--frames", "0"], "--frames 0", [tmp / "demo"]),
        # argparse's own errors are one line too
        ("decode-no-output", ["decode", vlp10], "-o/--output", []),
        ("unknown-flag", ["info", vlp10, "--bogus"], "--bogus", []),
    ]




def _check(case: str, status: int, err: str, expected: str, outputs: list[Path]) -> None:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("lidarpkt: error: ")]
    assert status == 2, (case, status, err)
    assert "Traceback" not in err, (case, err)
    assert len(errors) == 1, (case, err)
    assert expected in errors[0], (case, expected, err)
    if "not-a-capture" not in case:  # the container error says what the file starts with instead
        assert "; " in errors[0], (case, "no 'what to do' part", err)  # <what is wrong>; <what to do>
    # the error is the only line, but for warnings that came before it (what a decode skipped)
    assert all(ln.startswith("lidarpkt: warning: ") for ln in lines if ln not in errors), (case, err)
    for out in outputs:
        assert not out.exists(), (case, f"{out} left behind")


def _all_cases(tmp_path: Path):
    cases = _cases(tmp_path)
    assert {argv[0] for _, argv, _, _ in cases if argv[0] in VERBS} == set(VERBS)  # every verb is driven
    return cases


def test_every_verb_with_bad_input_gives_one_line_and_status_2_in_process(tmp_path, capsys):
    for case, argv, expected, outputs in _all_cases(tmp_path):
        try:
            status = main(list(argv))
        except SystemExit as exc:  # argparse's errors exit: through our one-line hook
            status = exc.code
        captured = capsys.readouterr()
        _check(case, status, captured.err, expected, outputs)


def test_every_verb_with_bad_input_gives_one_line_and_status_2_as_a_subprocess(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(REPO))
    for case, argv, expected, outputs in _all_cases(tmp_path):
        r = subprocess.run([sys.executable, "-m", "lidarpkt", *argv], capture_output=True, text=True, cwd=tmp_path,
                           env=env, timeout=120)
        _check(case, r.returncode, r.stderr, expected, outputs)


def test_an_unreadable_input_is_named(tmp_path, capsys):
    src = tmp_path / "locked.pcap"
    src.write_bytes(external(VLP10).read_bytes())
    src.chmod(0)
    if os.access(src, os.R_OK):
        pytest.skip("needs root to be absent: as root chmod 000 does not stop reads (the /proc cases cover unwritable paths)")
    status = main(["decode", str(src), "-o", str(tmp_path / "x.npz")])
    _check("unreadable", status, capsys.readouterr().err, f"{src}: not readable", [tmp_path / "x.npz"])


def _lidarpkt(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "lidarpkt", *argv], capture_output=True, text=True, cwd=REPO,
                          env=dict(os.environ, PYTHONPATH=str(REPO)), timeout=120)


def _json_verbs() -> dict[str, list[str]]:
    """Every verb that writes a JSON document (record: below), with the arguments of a small run."""
    vlp = str(external(VLP10))
    return {
        "info": ["info", vlp],
        "analyze": ["analyze", vlp, "--pixel", "7,100", "--gmm", "none", "-q"],
        "compare-returns": ["compare-returns", vlp, vlp, "--paired", "-q"],
        "registration-impact": ["registration-impact", vlp, "--algorithm", "icp_point_to_point",
                                "--mode", "scan_to_scan", "--downsample", "1", "-q"],
        "catalog": ["catalog", vlp, "--workers", "1", "-q"],
    }


def test_info_json_before_or_after_the_capture_prints_the_same_document():
    """The spellings users type, as a real command line: `lidarpkt info --json CAPTURE` and
    `lidarpkt info CAPTURE --json` print the same JSON document alone on stdout."""
    import json

    vlp = str(external(VLP10))
    first, last = _lidarpkt("info", "--json", vlp), _lidarpkt("info", vlp, "--json")
    assert first.returncode == 0 and last.returncode == 0, (first.stderr, last.stderr)
    assert first.stdout == last.stdout and json.loads(first.stdout)["file"] == vlp


@pytest.mark.parametrize("verb", ["info", "analyze", "compare-returns", "registration-impact", "catalog"])
def test_json_prints_to_stdout_wherever_it_stands_and_o_writes_the_file(tmp_path, capsys, verb):
    """--json is a switch: before or after the input it prints the same document, alone, on stdout
    (text reports go to stderr); -o REPORT.json writes that document to a file; both together do both."""
    import json

    def run(*argv: str) -> str:
        assert main(list(argv)) == 0, capsys.readouterr().err
        return capsys.readouterr().out

    argv = _json_verbs()[verb]
    head, tail = argv[:1], argv[1:]
    doc = json.loads(run(*head, "--json", *tail))
    assert doc and json.loads(run(*argv, "--json")) == doc
    out = tmp_path / "report.json"
    stdout = run(*argv, "-o", str(out))
    assert json.loads(out.read_text()) == doc
    assert not stdout.lstrip().startswith(("{", "["))  # the document went to the file, not stdout
    assert json.loads(run(*head, "--json", *tail, "-o", str(tmp_path / "both.json"))) == doc
    assert json.loads((tmp_path / "both.json").read_text()) == doc


def test_record_prints_its_summary_with_json_and_writes_it_with_report(tmp_path):
    """record's -o is the MCAP: --json prints the summary, --report FILE.json writes it (a 1 s
    recording of an idle loopback port: no packets, a summary all the same)."""
    import json
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = str(s.getsockname()[1])
    r = _lidarpkt("record", "--json", "--port", port, "--bind", "127.0.0.1", "--duration", "1",
                  "-o", str(tmp_path / "r.mcap"), "--report", str(tmp_path / "r.json"), "-q")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert doc == json.loads((tmp_path / "r.json").read_text()) and doc["packets"] == 0
    assert (tmp_path / "r.mcap").stat().st_size > 0


def test_json_takes_no_value(tmp_path):
    """`--json FILE.json` (and `--json -`) of before: one line naming the flag that does it now, not a
    FILE read as an input or a JSON printed by mistake."""
    vlp = str(external(VLP10))
    r = _lidarpkt("info", vlp, "--json", "-")
    assert r.returncode == 2 and r.stdout == "" and "--json -: --json alone prints to stdout" in r.stderr
    r = _lidarpkt("info", "--json", str(tmp_path / "i.json"), vlp)
    assert r.returncode == 2 and r.stdout == "" and f"write it to a file with -o {tmp_path / 'i.json'}" in r.stderr
    assert not (tmp_path / "i.json").exists()


def test_old_spellings_are_gone(tmp_path, capsys):
    """demo --out and multireturn --monitor-by-row are no flags (one spelling per flag); --plot is always
    a folder. (record --report is the flag that writes record's JSON summary: its -o is the MCAP.)"""
    from lidarpkt.cli import build_parser

    for verb, argv in (("demo", ["demo", "--out", str(tmp_path / "d")]),
                       ("multireturn", ["multireturn", "x.pcap", "-o", "m.npz", "--monitor-by-row"])):
        with pytest.raises(SystemExit) as exc:
            build_parser(verb).parse_args(argv)
        assert exc.value.code == 2 and "unrecognized arguments" in capsys.readouterr().err
    vlp = str(external(VLP10))
    status = main(["multireturn", vlp, "-o", str(tmp_path / "m2.npz"), "--plot", str(tmp_path / "figs")])
    assert status == 0 and sorted(p.name for p in (tmp_path / "figs").iterdir()) == [
        "multireturn_map.png", "multireturn_roc.png"]
