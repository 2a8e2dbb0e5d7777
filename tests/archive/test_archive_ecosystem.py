"""The ecosystem formats through the archives on Dask (a ``LocalCluster`` of two worker processes):
``export --format csv|kitti|rrd|rosbag1|rosbag2`` gives, per capture, what ``lidarpkt decode IN -o OUT``
gives (read back by each format's own reader: DuckDB, NumPy, Rerun's dataframe API, rosbags), and a
rosbag2 folder reaches a remote OUTDIR file by file."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")
rosbag2 = pytest.importorskip("rosbags.rosbag2")

from archive_cases import CANNED  # noqa: E402
from lidarpkt.archive import export  # noqa: E402
from lidarpkt.cli.decode import decode_captures  # noqa: E402

pytestmark = pytest.mark.slow
CAPTURES = ("vlp16-dual.pcap", "os1-64-dual.pcap")


@pytest.fixture(scope="module")
def archive(tmp_path_factory):
    root = tmp_path_factory.mktemp("eco") / "archive"
    root.mkdir()
    for name in (*CAPTURES, "os1-64-dual.json"):
        shutil.copy(CANNED / name, root / name)
    return root


@pytest.fixture(scope="module")
def client():
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            distributed.Client(cluster) as dask_client:
        yield dask_client


def _decoded(archive: Path, name: str, out: Path, **options) -> Path:
    md = archive / (Path(name).stem + ".json")
    decode_captures([archive / name], out, **({"metadata": [md]} if md.exists() else {}), **options)
    return out


def _bag_messages(path: Path):
    if path.suffix == ".bag":
        from rosbags.rosbag1 import Reader
    else:
        from rosbags.rosbag2 import Reader
    with Reader(path) as reader:
        return sorted((c.topic, c.msgtype, t, bytes(raw)) for c, t, raw in reader.messages())


@pytest.mark.parametrize("fmt, options", [("csv", {}), ("kitti", {}), ("rosbag1", {}), ("rosbag2", {}),
                                          ("rosbag2", {"storage": "mcap"}), ("rrd", {})])
def test_export_on_dask_gives_what_decode_gives(archive, client, tmp_path, fmt, options):
    pytest.importorskip("rerun") if fmt == "rrd" else None
    out = tmp_path / "out"
    rows = export([archive], out, format=fmt, client=client, **options).to_pylist()
    assert sorted(r["capture"] for r in rows) == sorted(CAPTURES) and all(r["status"] == "done" for r in rows), rows
    assert not [p for p in out.rglob("*") if p.name.startswith(".") or p.name.endswith(".tmp")]
    for r in rows:
        stem = Path(r["capture"]).stem
        suffix = {"rosbag1": ".bag", "rosbag2": ".rosbag2"}.get(fmt, f".{fmt}")
        ref = _decoded(archive, r["capture"], tmp_path / f"ref-{stem}{suffix}", **options)
        if fmt == "csv":
            assert r["outputs"] == [f"{stem}.csv"] and (out / f"{stem}.csv").read_bytes() == ref.read_bytes()
        elif fmt == "kitti":
            mine = sorted(p.relative_to(out / stem) for p in (out / stem).rglob("*") if p.is_file())
            theirs = sorted(p.relative_to(ref) for p in ref.rglob("*") if p.is_file())
            assert mine == theirs and len(mine) == r["frames"] + 3  # the .bin files and 3 timestamp files
            assert all((out / stem / p).read_bytes() == (ref / p).read_bytes() for p in mine)
        elif fmt == "rrd":
            from test_writers_rerun import read_rrd

            table, want = read_rrd(out / f"{stem}.rrd"), read_rrd(ref)
            assert table.column("frame").to_pylist() == want.column("frame").to_pylist()
            assert table.num_rows == r["frames"] > 0
        else:
            assert _bag_messages(out / f"{stem}{suffix}") == _bag_messages(ref)
            if fmt == "rosbag2":
                assert sorted(r["outputs"]) == sorted(f"{stem}.rosbag2/{p.name.replace('ref-', '')}" for p in ref.iterdir())


def test_a_rosbag2_reaches_a_remote_outdir_file_by_file(archive, tmp_path):
    fsspec = pytest.importorskip("fsspec")
    mem = fsspec.filesystem("memory")
    mem.pipe("/eco-in/vlp16-dual.pcap", (archive / "vlp16-dual.pcap").read_bytes())
    rows = export(["memory://eco-in"], "memory://eco-out", format="rosbag2", workers=1).to_pylist()
    assert [r["status"] for r in rows] == ["done"]
    assert sorted(rows[0]["outputs"]) == ["vlp16-dual.rosbag2/metadata.yaml", "vlp16-dual.rosbag2/vlp16-dual_0.db3"]
    folder = tmp_path / "vlp16-dual.rosbag2"
    folder.mkdir()
    for rel in rows[0]["outputs"]:
        (tmp_path / rel).write_bytes(mem.cat(f"/eco-out/{rel}"))
    ref = _decoded(archive, "vlp16-dual.pcap", tmp_path / "ref.rosbag2")
    assert _bag_messages(folder) == _bag_messages(ref)
    frames = np.unique([t for topic, _, t, _ in _bag_messages(folder) if topic == "/velodyne_points"])
    assert frames.size == rows[0]["frames"] > 0
