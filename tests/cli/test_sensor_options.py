"""One set of sensor options in every verb that opens a capture: ``--metadata FILE`` (any vendor's description
file, told apart by content), ``--calibration FILE`` (its second spelling) and ``--model NAME``; the same file
gives the same frames whichever verb reads it, and a file of no known kind is one line and exit 2."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import lidarpkt
from lidarpkt.vendors.registry import VENDORS

REPO = Path(__file__).resolve().parents[2]
XT32 = "nebula/hesai/xt32/1673400677802009732"
XT32_CSV = "nebula/hesai/PandarXT32.csv"


def _cli(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "lidarpkt", *args], capture_output=True, text=True, timeout=timeout,
                          cwd=REPO, env=dict(os.environ, PYTHONPATH=str(REPO)))


def _points(folder: Path):
    import pyarrow.parquet as pq

    (path,) = folder.glob("**/*.parquet") if folder.is_dir() else [folder]
    table = pq.read_table(path).to_pandas()
    return table.sort_values(["frame_id", "return_slot", "row", "column"]).reset_index(drop=True)


def test_export_calibration_gives_the_xyz_of_decode_calibration(ext, tmp_path):
    bag, csv = ext(XT32), ext(XT32_CSV)
    exported = _cli("export", str(bag), "-o", str(tmp_path / "export"), "--format", "parquet", "--workers", "1",
                    "-q", "--calibration", str(csv))
    assert exported.returncode == 0, exported.stderr
    decoded = _cli("decode", str(bag), "-o", str(tmp_path / "decode.parquet"), "-q", "--calibration", str(csv))
    assert decoded.returncode == 0, decoded.stderr
    a, b = _points(tmp_path / "export"), _points(tmp_path / "decode.parquet")
    assert len(a) == len(b) > 400_000
    xyz = ["x", "y", "z"]
    assert np.isfinite(a[xyz].to_numpy()).all() and np.abs(a[xyz].to_numpy()).max() > 1.0  # the CSV's geometry
    np.testing.assert_array_equal(a[xyz].to_numpy(), b[xyz].to_numpy())
    frames = [f for f in lidarpkt.open(bag, metadata=csv)]  # and what the library gives
    f = frames[2]
    mine = a[a.frame_id == f.frame_id]
    slot, row, col = np.nonzero(f.range_mm)
    np.testing.assert_allclose(mine[xyz].to_numpy(), f.xyz()[slot, row, col], atol=1e-6)


def test_metadata_and_calibration_are_one_option_told_apart_by_content(ext, tmp_path):
    """The CSV under another name and either spelling gives the same frames: the content decides."""
    bag, csv = ext(XT32), ext(XT32_CSV)
    renamed = tmp_path / "pandar-angles.txt"
    renamed.write_bytes(csv.read_bytes())
    outs = []
    for flag, path in (("--metadata", csv), ("--calibration", csv), ("--metadata", renamed)):
        out = tmp_path / f"{flag.strip('-')}-{path.name}.npz"
        r = _cli("decode", str(bag), "-o", str(out), "-q", flag, str(path))
        assert r.returncode == 0, (flag, path, r.stderr)
        with np.load(out) as npz:
            outs.append({k: npz[k] for k in ("range_mm", "sensor_json")})
    assert all(np.array_equal(o["range_mm"], outs[0]["range_mm"]) for o in outs)
    assert all(str(o["sensor_json"]) == str(outs[0]["sensor_json"]) for o in outs)
    assert "PandarXT32" in str(outs[0]["sensor_json"])


def _argv(verb: str, capture: str, out: Path) -> list[str]:
    return {
        "decode": ["decode", capture, "-o", str(out / "x.npz")],
        "export": ["export", capture, "-o", str(out / "x"), "--format", "parquet", "--workers", "1"],
        "catalog": ["catalog", capture, "--json", "--workers", "1"],
        "info": ["info", capture],
        "view": ["view", capture, "--ws", "127.0.0.1:0", "--duration", "1"],
        "record": ["record", "-o", str(out / "x.mcap"), "--port", "45999", "--duration", "1"],
        "replay": ["replay", capture, "--to", "127.0.0.1:45998", "--max"],
        "analyze": ["analyze", capture, "--pixel", "1,1"],
        "multireturn": ["multireturn", capture, "-o", str(out / "x.npz")],
        "compare-returns": ["compare-returns", capture],
        "registration-impact": ["registration-impact", capture],
    }[verb]


@pytest.mark.parametrize("verb", ["decode", "export", "catalog", "info", "view", "record", "replay", "analyze",
                                  "multireturn", "compare-returns", "registration-impact"])
@pytest.mark.parametrize("flag", ["--metadata", "--calibration"])
def test_a_file_of_no_known_kind_is_one_line_and_exit_2_before_any_work(verb, flag, tmp_path):
    from lidarpkt.fixtures import canned

    junk = tmp_path / "notes.txt"
    junk.write_text("not a sensor description\n1,2,3\n")
    out = tmp_path / "out"
    out.mkdir()
    r = _cli(*_argv(verb, str(canned("vlp16-dual")), out), flag, str(junk), timeout=120)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith(f"lidarpkt: error: {flag} {junk}: not a sensor file lidarpkt reads (it starts with "), r.stderr
    whats = [v.sensor_files.what for v in VENDORS if v.sensor_files is not None]  # every vendor's, in order
    assert lines[0].endswith(f"; give {', '.join(whats[:-1])} or {whats[-1]}"), r.stderr
    assert "Ouster metadata JSON, Velodyne calibration (ROS YAML or VeloView XML), Hesai angle-correction CSV" in lines[0]
    assert sorted(p.name for p in out.iterdir()) == []  # nothing written


def test_model_names_what_the_packets_cannot_in_an_archive_job_too(tmp_path):
    """A VLP-32A/B capture needs ``--model``: export forwards it to every unit as decode does."""
    sys.path.insert(0, str(REPO / "tests" / "velodyne"))
    from test_velodyne_line import hand_built

    from lidarpkt.core.packet import Endpoint, Packet
    from lidarpkt.writers.pcap import write_pcap

    batch = hand_built("VLP-32A", "strongest", n=300)
    src, dst = Endpoint("192.168.1.201", 2368), Endpoint("255.255.255.255", 2368)
    pcap = tmp_path / "vlp32.pcap"
    write_pcap(pcap, (Packet(int(t), src, dst, row.tobytes()) for t, row in zip(batch.timestamp_ns, batch.payload)),
               udp_checksum=False)
    without = _cli("export", str(pcap), "-o", str(tmp_path / "a"), "--format", "parquet", "--workers", "1", "-q")
    assert without.returncode == 1 and "VLP-32A or a VLP-32B" in without.stderr
    with_model = _cli("export", str(pcap), "-o", str(tmp_path / "b"), "--format", "parquet", "--workers", "1", "-q",
                      "--model", "VLP-32B")
    assert with_model.returncode == 0, with_model.stderr
    decoded = _cli("decode", str(pcap), "-o", str(tmp_path / "c.parquet"), "-q", "--model", "VLP-32B")
    assert decoded.returncode == 0, decoded.stderr
    a, b = _points(tmp_path / "b"), _points(tmp_path / "c.parquet")
    assert len(a) == len(b) > 0
    np.testing.assert_array_equal(a[["x", "y", "z"]].to_numpy(), b[["x", "y", "z"]].to_numpy())
    bad = _cli("catalog", str(pcap), "--json", "--workers", "1", "--model", "VLP-99")
    assert bad.returncode == 2 and bad.stderr.strip().splitlines()[0].startswith("lidarpkt: error: --model VLP-99: no such")
