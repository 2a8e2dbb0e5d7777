"""One grid, one summary of drops, a CLI that starts at once (issues 14 and 16).

- The README's Python example, ``lidarpkt decode -o x.npz`` and ``lidarpkt analyze`` put VeloView's
  20 Hz capture on the same grid and report the same returns for the same pixel.
- ``column_valid`` is False only where a packet was lost, not where encoder jitter left a bin empty.
- Every read that drops packets says so once, in the same words, in the API and the CLI.
- ``lidarpkt --help`` / ``--version`` import no verb module (nor NumPy); ``info`` imports no
  recorder, analysis, scipy or matplotlib.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import lidarpkt
from conftest import external
from lidarpkt.errors import DroppedPacketsWarning
from lidarpkt.core.sequence import FrameStack
from lidarpkt.core.grid import default_grid_deg, destagger, restagger

REPO = Path(__file__).resolve().parents[2]
VLP20 = "veloview/vlp-16-test-90deg-1-50-frames.pcap"
VLP10 = "rust-lidar-utils/velodyne_example.pcap"
PIXELS = ((7, 449), (7, 624), (0, 10), (15, 899))


def _cli(*argv: str, cwd: Path = REPO) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "lidarpkt", *map(str, argv)], capture_output=True, text=True,
                          cwd=cwd, env=dict(os.environ, PYTHONPATH=str(REPO)), timeout=300)


def test_readme_example_decode_npz_and_analyze_agree_on_the_grid_and_the_returns(tmp_path):
    from lidarpkt import analysis

    pcap = external(VLP20)
    stack = FrameStack.from_frames(lidarpkt.open(pcap))  # the README's Python example
    # SOURCES.md: 20 Hz (0.8° per block, two firing sequences each): 0.4° columns, 900 of them
    assert stack.sensor.frequency_hz == pytest.approx(20, abs=0.1)
    assert default_grid_deg(stack.sensor) == pytest.approx(0.4) and stack.range_mm.shape[1:] == (1, 16, 900)
    assert len(stack) == 50  # 52 frames (vlp-16.test), the partial first and last left out

    r = _cli("decode", pcap, "-o", tmp_path / "x.npz", "-q")
    assert r.returncode == 0, r.stderr
    npz = np.load(tmp_path / "x.npz")
    complete = ~npz["partial"]
    assert npz["range_mm"].shape[1:] == stack.range_mm.shape[1:]
    assert np.array_equal(npz["range_mm"][complete], stack.range_mm)
    assert np.array_equal(npz["column_valid"][complete], stack.column_valid)
    assert np.array_equal(npz["azimuth_deg"][complete], stack.azimuth_deg)

    args = [a for rc in PIXELS for a in ("--pixel", f"{rc[0]},{rc[1]}")]
    r = _cli("analyze", pcap, *args, "--gmm", "none", "-o", tmp_path / "a.json")
    assert r.returncode == 0, r.stderr
    assert "50 frames of 16x900" in r.stdout
    cli = {(p["row"], p["col"]): p for p in json.loads((tmp_path / "a.json").read_text())["pixels"]}
    for row, col in PIXELS:
        api = analysis.analyze_raypath(stack, row=row, col=col, slot=0, gmm=None)
        entry = cli[(row, col)]
        assert (entry["n_returns"], entry["n_nonreturn"], entry["n_missing"]) == (
            api.temporal.n_returns, api.temporal.n_nonreturn, api.temporal.n_missing)
        # the NPZ's samples of that pixel are the same ranges
        valid = npz["column_valid"][complete][:, col]
        ranges = npz["range_mm"][complete][valid, 0, row, col]
        assert np.count_nonzero(ranges) == entry["n_returns"]
        assert sorted((ranges[ranges > 0] / 1000.0).tolist()) == pytest.approx(entry["temporal_cdf"]["range_m"])


def test_column_valid_is_false_only_where_a_packet_was_lost():
    """Issue 14: half the columns of a 20 Hz capture on the 0.2° grid were invalid; on the firing
    rate's grid encoder jitter (0.39/0.40/0.41° steps) still emptied ~6 bins a frame. No packet of
    this capture is lost (1902 data packets, contiguous timestamps)."""
    frames = [f for f in lidarpkt.open(external(VLP20)) if not f.partial]
    assert sum(f.counters.lost_packets for f in frames) == 0
    invalid = [int(np.count_nonzero(~f.on_grid().column_valid)) for f in frames]
    # at most the one bin at the cut of a frame one firing short (904 firings) stays empty
    assert sum(invalid) <= 2 and max(invalid) <= 1, invalid

    # a lost packet (12 firing sequences of a strongest-mode packet) is an invalid stretch, exactly there
    frame = frames[10]
    valid = frame.column_valid.copy()
    valid[300:324] = False
    holed = replace(frame, column_valid=valid).on_grid()
    gone = np.flatnonzero(~holed.column_valid)
    az = np.mod(frame.azimuth_deg[300:324], 360.0)
    assert 20 <= gone.size <= 26 and gone.min() >= int(az.min() / 0.4) - 1 and gone.max() <= int(az.max() / 0.4) + 1


def test_destagger_has_one_home_and_round_trips():
    import lidarpkt.analysis.stack as stack_module

    assert stack_module.destagger is destagger and stack_module.restagger is restagger
    rng = np.random.default_rng(0)
    image = rng.integers(0, 1000, size=(2, 4, 16))
    shift = np.array([0, 3, 6, 9])
    out = destagger(image, shift)
    for u in range(4):  # destaggered[u, (c + shift[u]) % W] = staggered[u, c], as ouster-sdk
        assert np.array_equal(out[:, u, (np.arange(16) + shift[u]) % 16], image[:, u, :])
    assert np.array_equal(restagger(out, shift), image)


def _looped_capture(tmp_path: Path) -> Path:
    """The capture twice over, host times running on: what `replay --loop` into `record` gives;
    the second copy's sensor times go back, so its packets arrive after their frames were released."""
    from lidarpkt.containers.pcap_reader import read_packets
    from lidarpkt.writers.pcap import write_pcap

    packets = list(read_packets(external(VLP10)))
    span = packets[-1].timestamp_ns - packets[0].timestamp_ns + 1_000_000
    looped = packets + [replace(p, timestamp_ns=p.timestamp_ns + span) for p in packets]
    out = tmp_path / "loop.pcap"
    write_pcap(out, looped)
    return out


def test_a_read_that_drops_packets_warns_once_and_the_cli_says_it(tmp_path):
    path = _looped_capture(tmp_path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        reader = lidarpkt.open(path)
        frames = list(reader)
    dropped = [w for w in caught if issubclass(w.category, DroppedPacketsWarning)]
    assert frames and len(dropped) == 1
    (stats,) = [d.stats for d in reader.decoders.values()]
    # the second copy, all 84 data packets of the capture (SOURCES.md), is discarded, and said so
    assert stats.late_packets + stats.duplicate_packets == 84 and reader.stats.packets == 168
    said = str(dropped[0].message)
    phrases = [f"{n} {what}" for n, what in ((stats.late_packets, "discarded as late"),
                                             (stats.duplicate_packets, "discarded as duplicates")) if n]
    assert phrases and all(p in said for p in phrases) and "of 168 packets" in said

    r = _cli("decode", path, "-o", tmp_path / "loop.npz")
    assert r.returncode == 0, r.stderr
    warned = [ln for ln in r.stderr.splitlines() if ln.startswith("lidarpkt: warning: ")]
    assert len(warned) == 1 and all(p in warned[0] for p in phrases)
    # the same words in every verb that decodes
    r = _cli("multireturn", path, "-o", tmp_path / "m.npz")
    assert r.returncode == 0 and all(p in r.stderr for p in phrases), r.stderr


def test_a_clean_read_warns_nothing():
    with warnings.catch_warnings():
        warnings.simplefilter("error", DroppedPacketsWarning)
        assert list(lidarpkt.open(external(VLP10)))


def _imported(*argv: str) -> set[str]:
    r = subprocess.run([sys.executable, "-X", "importtime", "-m", "lidarpkt", *argv], capture_output=True, text=True,
                       cwd=REPO, env=dict(os.environ, PYTHONPATH=str(REPO)), timeout=120)
    assert r.returncode in (0, 2), r.stderr[-2000:]
    names = set()
    for line in r.stderr.splitlines():
        if line.startswith("import time:") and "|" in line:
            names.add(line.rsplit("|", 1)[1].strip())
    assert "lidarpkt.cli" in names
    return names


@pytest.mark.parametrize("argv", [("--help",), ("--version",)])
def test_help_and_version_import_no_verb_module_nor_numpy(argv):
    names = _imported(*argv)
    heavy = {n for n in names if n.split(".")[0] in ("numpy", "scipy", "matplotlib", "mcap", "dask", "tqdm", "rosbags")
             or n.startswith(("lidarpkt.recorder", "lidarpkt.analysis"))}
    verbs = {n for n in names if n in ("lidarpkt.cli.info", "lidarpkt.cli.demo", "lidarpkt.pipeline.reader", "lidarpkt.containers.pcap_reader")}
    assert not heavy and not verbs, sorted(heavy | verbs)


def test_info_imports_only_what_it_needs():
    names = _imported("info", str(external(VLP10)))
    heavy = {n for n in names if n.split(".")[0] in ("scipy", "matplotlib", "dask", "tqdm")
             or n.startswith(("lidarpkt.recorder", "lidarpkt.analysis"))}
    assert not heavy, sorted(heavy)
    # (importlib.import_module of the verb module itself is not timed; what it imports is)
    assert "lidarpkt.containers.pcap_reader" in names and "numpy" in names


# what ``info`` must not import (issue 16: the CLI starts at once): the frame assembly, encoders, XYZ
# and calibration of both sensor packages, the version lookup (``--version`` only) and importlib.abc
# and tempfile (pulled in by importlib.resources: ~10-40 ms each on this machine)
NOT_FOR_INFO = ("lidarpkt.vendors.ouster.frames", "lidarpkt.vendors.ouster.encode", "lidarpkt.vendors.ouster.geometry", "lidarpkt.core.frame",
                "lidarpkt.vendors.velodyne.frames", "lidarpkt.vendors.velodyne.encode", "lidarpkt.vendors.velodyne.geometry",
                "lidarpkt.vendors.velodyne.calibration", "lidarpkt.vendors.velodyne.points", "lidarpkt.pipeline.reader", "importlib.metadata",
                "importlib.abc", "tempfile")


@pytest.mark.parametrize("argv", [(VLP10,), ("rust-lidar-utils/velodyne_vlp16.pcap",),
                                  ("ouster-sdk/OS-2-32-U0_v2.0.0_1024x10.pcap", "--metadata",
                                   "ouster-sdk/OS-2-32-U0_v2.0.0_1024x10.json")])
def test_info_imports_only_the_detect_modules_of_the_sensor_packages(argv):
    names = _imported("info", *[str(external(a)) if "/" in a else a for a in argv])
    vendor = "ouster" if "--metadata" in argv else "velodyne"
    assert f"lidarpkt.vendors.{vendor}.detect" in names  # it did describe the streams
    assert not set(NOT_FOR_INFO) & names, sorted(set(NOT_FOR_INFO) & names)


def test_the_sensor_packages_still_give_every_public_name_and_submodule():
    import lidarpkt.vendors.ouster as ouster
    import lidarpkt.vendors.velodyne as velodyne

    for package in (ouster, velodyne):
        for name in package.__all__:
            assert getattr(package, name) is not None, (package.__name__, name)
        assert set(package.__all__) <= set(dir(package))
        with pytest.raises(AttributeError):
            package.no_such_name  # noqa: B018
    assert ouster.frames.OusterDecoder is ouster.OusterDecoder and velodyne.geometry.VelodyneGeometry
    star: dict = {}
    exec("from lidarpkt.vendors.velodyne import *", star)  # the star import follows __all__
    assert set(velodyne.__all__) <= set(star)


SENSOR_FLAGS = ("--metadata FILE", "--calibration FILE", "--model NAME")
SENSOR_VERBS = ("export", "catalog", "info", "view", "record", "replay", "analyze", "multireturn", "compare-returns",
                "registration-impact", "decode")


def test_a_verbs_help_lists_the_common_flags_the_same_way():
    common = {"decode": ("-o OUT.mcap", "-q, --quiet"),
              "analyze": ("--json", "-o REPORT.json", "--plot DIR", "--pixel ROW,COL", "-q, --quiet"),
              "multireturn": ("-o OUT", "--plot DIR", "--workers N", "-q, --quiet"),
              "compare-returns": ("--json", "-o REPORT.json", "--plot DIR", "-q, --quiet"),
              "info": ("--json", "-o REPORT.json", "-q, --quiet"),
              "registration-impact": ("--json", "-o REPORT.json", "--plot DIR", "-q, --quiet"),
              "catalog": ("--json", "-o CATALOG.parquet", "-q, --quiet"),
              "export": ("-o OUTDIR", "-q, --quiet"),
              "view": ("-q, --quiet",),
              "record": ("-o OUT.mcap", "--json", "--report FILE.json", "-q, --quiet"),
              "replay": ("-q, --quiet",),
              "demo": ("-o DIR", "-q, --quiet")}
    for verb, flags in common.items():
        r = _cli(verb, "--help")
        assert r.returncode == 0
        for flag in flags + (SENSOR_FLAGS if verb in SENSOR_VERBS else ()):
            assert flag in r.stdout, (verb, flag)
        if verb in SENSOR_VERBS:  # --calibration is said to be the same option
            assert "second spelling of --metadata" in " ".join(r.stdout.split()), verb
