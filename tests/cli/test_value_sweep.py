"""Every numeric flag of every verb, with every value its declaration refuses, and every option of
``lidarpkt.open`` with values of the wrong range or type: one line naming the flag (option) and what it
takes, exit 2 (a :class:`UsageError` in the API), never a traceback. In process: the check runs while
the arguments are parsed, before any work, so no subprocess is needed to see it."""

from __future__ import annotations

import argparse

import pytest

import lidarpkt
from lidarpkt.cli import VERBS, build_parser, main
from lidarpkt.cli.args import NUMBERS
from lidarpkt.core.checks import Number
from lidarpkt.errors import UsageError
from lidarpkt.pipeline.options import OpenOptions

from conftest import external

VLP10 = "rust-lidar-utils/velodyne_example.pcap"


def _numeric_flags() -> list[tuple[str, str]]:
    """(verb, flag) of every numeric flag of every verb."""
    parser = build_parser("*")
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    out = []
    for verb, verb_parser in sub.choices.items():
        for action in verb_parser._actions:
            out += [(verb, flag) for flag in action.option_strings if flag in NUMBERS and action.type is not None]
    return out


def test_every_numeric_flag_is_declared_once_and_parsed_from_its_declaration():
    parser = build_parser("*")
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for verb, verb_parser in sub.choices.items():
        for action in verb_parser._actions:
            assert action.type not in (int, float), (verb, action.option_strings, "a number not checked by NUMBERS")
    flags = {flag for _, flag in _numeric_flags()}
    assert flags == set(NUMBERS)  # every declaration is used, every numeric flag declared
    assert {verb for verb, _ in _numeric_flags()} >= set(VERBS) - {"info"}


@pytest.mark.parametrize("verb,flag", _numeric_flags())
def test_every_bad_value_of_every_numeric_flag_is_one_line_and_exit_2(verb, flag, capsys, tmp_path):
    for bad in NUMBERS[flag].bad_values():
        try:
            status = main([verb, f"{flag}={bad}", str(tmp_path / "never-read.pcap")])
        except SystemExit as exc:
            status = exc.code
        err = capsys.readouterr().err
        lines = [ln for ln in err.splitlines() if ln.strip()]
        assert status == 2, (verb, flag, bad, err)
        assert len(lines) == 1 and "Traceback" not in err, (verb, flag, bad, err)
        assert lines[0].startswith(f"lidarpkt: error: {flag} {bad}: "), (verb, flag, bad, err)
        assert NUMBERS[flag].describe() in lines[0] and f"give e.g. {flag} " in lines[0], (flag, bad, err)


def test_the_declared_range_is_what_passes():
    grid = NUMBERS["--grid"]
    assert grid.parse("0.2", "--grid") == 0.2
    for bad in ("1e-9", "0", "-1", "inf", "nan", "x"):
        with pytest.raises(UsageError, match=r"--grid .*: .*in \[0\.05, 10\] degrees"):
            grid.parse(bad, "--grid")
    with pytest.raises(UsageError, match="odd"):
        NUMBERS["--neighbourhood"].parse("4", "--neighbourhood")
    assert Number(0, 360, high_open=True).bad_values()[-1] == "360"


BAD_OPTIONS = [
    ({"cut_angle_deg": 400}, "cut_angle_deg=400: out of range; cut_angle_deg takes a number in [0, 360)"),
    ({"cut_angle_deg": -10}, "cut_angle_deg=-10"),
    ({"cut_angle_deg": "abc"}, "cut_angle_deg='abc': not a number"),
    ({"cut_angle_deg": float("nan")}, "cut_angle_deg=nan"),
    ({"include_partial": "no"}, "include_partial='no': not True or False"),
    ({"verify_crc": 1}, "verify_crc=1"),
    ({"ports": [70000]}, "ports=[70000]: holds 70000"),
    ({"ports": ["2368"]}, "ports=['2368']"),
    ({"payload_sizes": [0]}, "payload_sizes=[0]"),
    ({"workers": 0}, "workers=0: out of range"),
    ({"workers": 2.5}, "workers=2.5"),
    ({"max_sensors": 0}, "max_sensors=0"),
    ({"batch_packets": -1}, "batch_packets=-1"),
    ({"model": 16}, "model=16: not a string"),
    ({"topics": [1]}, "topics=[1]"),
    ({"segment": "x"}, "segment='x': not a Segment"),
]


@pytest.mark.parametrize("options,expected", BAD_OPTIONS, ids=[next(iter(o)) + str(i) for i, (o, _) in enumerate(BAD_OPTIONS)])
def test_every_bad_option_of_open_is_one_usage_error_naming_open_and_the_option(options, expected):
    with pytest.raises(UsageError) as info:
        lidarpkt.open(external(VLP10), **options)
    assert str(info.value).startswith("lidarpkt.open(): "), info.value
    assert expected in str(info.value), info.value
    assert "give e.g." in str(info.value)


def test_a_lone_value_where_several_are_taken_is_one_and_a_misspelt_option_names_open():
    frames = list(lidarpkt.open(external(VLP10), ports=2368))
    assert len(frames) == len(list(lidarpkt.open(external(VLP10), ports=[2368]))) > 0
    assert list(lidarpkt.open(external(VLP10), ports=2369)) == []
    with pytest.raises(TypeError, match=r"^lidarpkt\.open\(\) got an unexpected keyword argument 'port'"):
        lidarpkt.open(external(VLP10), port=2368)


def test_every_option_of_open_declares_what_it_takes():
    import dataclasses

    undeclared = {f.name for f in dataclasses.fields(OpenOptions) if f.metadata["allowed"] is None}
    assert undeclared == {"metadata"}  # the sensor files are checked where they are loaded


def test_the_archive_recorder_and_receiver_apis_check_their_numbers(tmp_path):
    from lidarpkt.archive import catalog_rows
    from lidarpkt.containers.udp import UdpSource
    from lidarpkt.recorder.record import record

    for workers in (0, "2", 2.5):
        with pytest.raises(UsageError, match=r"^workers="):
            catalog_rows([str(external(VLP10))], workers=workers)
    for options in ({"duration_s": -1}, {"max_frames": 0}, {"rotate_bytes": -1}, {"rotate_seconds": 0},
                    {"chunk_seconds": 0}):
        with pytest.raises(UsageError, match=rf"^record\(\): {next(iter(options))}="):
            record(tmp_path / "r.mcap", ports=[2368], **options)
    assert not (tmp_path / "r.mcap").exists()  # refused before anything opened
    for options in ({"rcvbuf_bytes": 5000 << 20}, {"rcvbuf_bytes": -1}, {"queue_bytes": 0}):
        with pytest.raises(UsageError, match=next(iter(options))):
            UdpSource([2368], bind="127.0.0.1", **options)
    with pytest.raises(UsageError, match="ports"):
        UdpSource([70000], bind="127.0.0.1")


def test_decode_refuses_placement_flags_its_output_cannot_hold_before_decoding(tmp_path, capsys):
    vlp = str(external(VLP10))
    assert main(["decode", vlp, "-o", str(tmp_path / "m.npz"), "--mount", "1,2,3,0,0,0", "--base-frame", "b"]) == 2
    assert "drop them for npz" in capsys.readouterr().err and not (tmp_path / "m.npz").exists()
    assert main(["decode", vlp, "-o", str(tmp_path / "m.mcap"), "--mount", "1,2,3", "--base-frame", "b"]) == 2
    assert "--mount 1,2,3: give six numbers" in capsys.readouterr().err and not (tmp_path / "m.mcap").exists()
