"""The words users read: counts with their plurals, damage warnings that say what repairs the file, errors
that show the bad line and the flag that fixes them, no Python reprs and no API jargon in the CLI."""

from __future__ import annotations

import warnings

import pytest

import lidarpkt
from lidarpkt.cli import main
from lidarpkt.errors import LidarpktError

from conftest import external

VLP20 = "veloview/vlp-16-test-90deg-1-50-frames.pcap"
VLP10 = "rust-lidar-utils/velodyne_example.pcap"
OS0 = "ouster-sdk/OS-0-32-U1_v2.2.0_1024x10"
HESAI = "nebula/hesai/"


def test_one_frame_is_one_frame(tmp_path, capsys):
    assert main(["decode", str(external(OS0 + ".pcap")), "--metadata", str(external(OS0 + ".json")),
                 "-o", str(tmp_path / "o.npz")]) == 0
    err = capsys.readouterr().err
    assert "1 frame from 1 sensor in" in err and "(s)" not in err, err


def test_a_cut_mcap_says_how_to_repair_it_and_why_it_stopped(tmp_path, capsys):
    full = tmp_path / "full.mcap"
    assert main(["decode", str(external(VLP10)), "-o", str(full), "-q"]) == 0
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(full.read_bytes()[: full.stat().st_size * 2 // 3])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        list(lidarpkt.open(cut))
    text = " ".join(str(w.message) for w in caught)
    assert "cut short or damaged after" in text and "()" not in text, text
    assert f"lidarpkt export {cut} -o FOLDER --format mcap" in text, text


def test_a_cut_ros1_bag_is_said_in_words_with_what_to_do(tmp_path):
    cut = tmp_path / "cut.bag"
    cut.write_bytes(external("ouster-sdk/512x10_raw.bag").read_bytes()[:5000])
    with pytest.raises(LidarpktError) as info:
        list(lidarpkt.open(cut))
    text = str(info.value)
    assert "('" not in text and ",)" not in text and "rosbag reindex" in text, text


def test_a_hesai_csv_numbering_error_shows_the_line_and_a_wrong_size_names_the_flag(tmp_path, capsys):
    lines = external(HESAI + "PandarXT32.csv").read_text().splitlines()
    gap = tmp_path / "gap.csv"
    gap.write_text("\n".join(lines[:5] + lines[6:]) + "\n")
    bag = str(external(HESAI + "xt32/1673400677802009732"))
    assert main(["decode", bag, "--metadata", str(gap), "-o", str(tmp_path / "g.npz")]) == 2
    err = capsys.readouterr().err
    assert f"line 6 {lines[6].strip()[:60]!r} is channel 6 where channel 5 should be" in err, err
    assert main(["decode", bag, "--metadata", str(external(HESAI + "Pandar40P.csv")), "-o", str(tmp_path / "h.npz")]) == 2
    err = capsys.readouterr().err
    assert "which has 32 (the lines of channels 33-40 are too many)" in err and "--metadata FILE" in err, err


def test_compare_returns_suggests_the_grid_that_fits_and_it_does(capsys):
    a, b = str(external(VLP20)), str(external(VLP10))  # 20 Hz and 10 Hz: 900 and 1800 columns
    assert main(["compare-returns", a, b]) == 2
    err = capsys.readouterr().err
    assert "16x900 and 16x1800" in err and "--grid 0.4" in err, err
    assert main(["compare-returns", a, b, "--grid", "0.4"]) == 0


def test_the_dropped_packets_warning_speaks_no_api_jargon():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        list(lidarpkt.open(external(HESAI + "xt32m/1660893203042895158"), metadata=str(external(HESAI + "PandarXT32M.csv"))))
    texts = [str(w.message) for w in caught if "lost" in str(w.message)]
    assert texts and not any(".decoders[" in t or ".stats" in t for t in texts), texts


def test_workers_means_the_cpu_cores_in_every_verb():
    import argparse

    from lidarpkt.cli import build_parser

    sub = next(a for a in build_parser("*")._actions if isinstance(a, argparse._SubParsersAction))
    helps = {verb: a.help for verb, p in sub.choices.items() for a in p._actions if "--workers" in a.option_strings}
    assert len(helps) >= 5 and all(h.startswith("use N CPU cores") for h in helps.values()), helps
