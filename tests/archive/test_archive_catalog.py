"""``lidarpkt catalog`` / ``lidarpkt.archive.catalog``: one row per (file, stream), checked against
what ``lidarpkt info`` describes and what ``lidarpkt.open`` decodes, for every external capture
and canned fixture; unreadable files still get a row; the Parquet file reads back in pyarrow and
DuckDB; the CLI's errors."""

from __future__ import annotations

import json
import warnings

import pyarrow.parquet as pq
import pytest

import lidarpkt
from archive_cases import build_archive, lidarpkt_cli
from conftest import external_root
from lidarpkt.archive import CATALOG_COLUMNS, catalog
from lidarpkt.archive.catalog import catalog_capture
from lidarpkt.archive.plan import Capture
from lidarpkt.errors import LidarpktError
from lidarpkt.pipeline.describe import describe_capture
from lidarpkt.vendors.ouster import load_metadata
from writers_cases import CASES, IDS, capture


def _decoded(cap, md) -> dict[str, int] | LidarpktError:
    """Frames per sensor source, as lidarpkt.open gives them (or the error it raises)."""
    counts: dict[str, int] = {}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for frame in lidarpkt.open(cap, metadata=[str(m) for m in md] if md else None):
                counts[frame.sensor.source] = counts.get(frame.sensor.source, 0) + 1
    except LidarpktError as exc:
        return exc
    return counts


@pytest.mark.parametrize("case", CASES, ids=IDS)
def test_catalog_rows_match_info_and_open(case):
    cap, md = capture(case)
    rows = catalog_capture(Capture(str(cap), cap.name, 123, 0, tuple(str(m) for m in md or ())))
    doc = describe_capture(cap, [load_metadata(m) for m in md or ()])
    decoded = _decoded(cap, md)
    assert [r["stream"].split(" -> ")[0] for r in rows] == [s["src"] or "?" for s in doc["streams"]]
    for row, stream in zip(rows, doc["streams"]):
        assert set(row) == set(CATALOG_COLUMNS)
        assert row["path"] == str(cap) and row["size_bytes"] == 123
        assert row["container"] == doc["format"]
        assert (row["packets"], row["start_ns"], row["end_ns"]) == (
            stream["packets"], stream["first_timestamp_ns"], stream["last_timestamp_ns"])
        assert row["kind"] == stream["kind"]
        assert row["vendor"] == ("ouster" if stream["kind"].startswith("Ouster") else "velodyne")
    if isinstance(decoded, LidarpktError):
        assert all(r["error"] == str(decoded) for r in rows)
        return
    assert all(r["error"] is None for r in rows)
    lidar = [r for r in rows if r["kind"] in ("VLP-16 data", "Ouster lidar")]
    assert sum(r["frames"] for r in lidar) == sum(decoded.values())
    assert len([r for r in lidar if r["frames"]]) == len(decoded)  # one lidar stream per decoded sensor
    for r in lidar:
        assert r["mode"] and r["model"] and r["lost_packets"] == 0


def test_catalog_of_the_whole_external_folder_gives_every_file_a_row(tmp_path):
    root = external_root()
    if not root.is_dir():
        pytest.skip("external fixtures absent")
    bad = tmp_path / "garbage.pcap"
    bad.write_bytes(b"this is not a capture at all" * 10)
    table = catalog([root, bad], workers=1)
    rows = table.to_pylist()
    assert table.column_names == list(CATALOG_COLUMNS)
    paths = {r["path"] for r in rows}
    captures = [p for p in root.rglob("*") if p.suffix == ".pcap"]
    assert {str(p) for p in captures} <= paths  # every pcap, even the unreadable ones
    assert not any(p.endswith((".json", ".yaml", ".xml", ".bin", ".test")) for p in paths)
    garbage = [r for r in rows if r["path"] == str(bad)]
    assert len(garbage) == 1 and "garbage.pcap" in garbage[0]["error"] and garbage[0]["packets"] is None
    empty = [r for r in rows if r["path"].endswith("empty_pcap.pcap")]
    assert len(empty) == 1 and empty[0]["packets"] == 0 and empty[0]["error"] is None
    hdl = [r for r in rows if r["path"].endswith("velodyne_vlp32.pcap")]
    assert hdl and any(r["model"] == "HDL-32E" and r["error"] is None for r in hdl)  # decoded since issue 24
    bag_folders = {str(p.parent) for p in root.rglob("metadata.yaml")}
    assert {r["path"] for r in rows if r["container"] == "rosbag2"} == bag_folders  # old writers' empty fields too
    nebula = [r for r in rows if r["path"].endswith("1673400471837873222")]  # the VLP-16 dual bag
    assert len(nebula) == 1 and nebula[0]["mode"] == "dual" and nebula[0]["frames"] == 5
    assert not any("not supported" in (r["error"] or "") for r in rows if r["container"] == "rosbag2")  # nor its metadata


def test_catalog_cli_parquet_and_json_agree_and_read_in_duckdb(tmp_path):
    duckdb = pytest.importorskip("duckdb")
    archive = build_archive(tmp_path / "archive")
    out = tmp_path / "catalog.parquet"
    res = lidarpkt_cli("catalog", str(archive), "-o", str(out), "--json", "--workers", "1", "-q")
    assert res.returncode == 0, res.stderr
    rows = json.loads(res.stdout)
    table = pq.read_table(out)
    assert table.to_pylist() == rows
    files = {r["path"] for r in rows}
    assert len(files) == 7 and any("drive2" in p for p in files)  # the sub-folder was walked
    con = duckdb.connect()
    got = con.execute(f"select sum(frames), count(*), count(error) from read_parquet('{out}')").fetchone()
    assert got == (sum(r["frames"] or 0 for r in rows), len(rows), 0)
    # --glob keeps only the matching names
    res = lidarpkt_cli("catalog", str(archive), "--json", "--glob", "vlp16-*.pcap", "--workers", "1", "-q")
    assert res.returncode == 0, res.stderr
    assert {r["path"].rsplit("/", 1)[1] for r in json.loads(res.stdout)} == {"vlp16-dual.pcap", "vlp16-strongest.pcap"}


@pytest.mark.parametrize("args, flag", [
    (["/no/such/folder", "-o", "{tmp}/c.parquet"], "/no/such/folder"),
    (["{tmp}"], "-o/--output"),
    (["{tmp}", "-o", "{tmp}/missing/c.parquet"], "-o {tmp}/missing/c.parquet"),
    (["{tmp}", "--json", "--workers", "0"], "--workers 0"),
])
def test_catalog_cli_errors_are_one_line_exit_2(tmp_path, args, flag):
    (tmp_path / "a.pcap").write_bytes(b"\xd4\xc3\xb2\xa1" + bytes(20))
    res = lidarpkt_cli("catalog", *[a.format(tmp=tmp_path) for a in args], "-q")
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"lidarpkt: error: {flag.format(tmp=tmp_path)}"), res.stderr
    assert not (tmp_path / "c.parquet").exists()
