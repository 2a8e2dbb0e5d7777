"""Catalog and export from and to ``s3://`` on a real S3-compatible HTTP server (moto's, on
127.0.0.1), through s3fs: the rows and files equal those of the same job on local paths."""

from __future__ import annotations

import shutil

import pytest

moto_server = pytest.importorskip("moto.server")
s3fs = pytest.importorskip("s3fs")

import pyarrow.dataset as ds  # noqa: E402

from archive_cases import build_archive, lidarpkt_cli, output_files  # noqa: E402
from lidarpkt.archive import catalog, export  # noqa: E402

BUCKET = "lidar-archive"
NAMES = ("vlp16-dual.pcap", "os1-64-dual.pcap", "os1-64-dual.json")


@pytest.fixture
def s3(monkeypatch):
    """A moto S3 server on 127.0.0.1 (stopped after the test), the environment pointing boto at it."""
    server = moto_server.ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    try:
        host, port = server.get_host_and_port()
        for name, value in {"AWS_ENDPOINT_URL": f"http://{host}:{port}", "AWS_ACCESS_KEY_ID": "testing",
                            "AWS_SECRET_ACCESS_KEY": "testing", "AWS_DEFAULT_REGION": "us-east-1"}.items():
            monkeypatch.setenv(name, value)
        s3fs.S3FileSystem.clear_instance_cache()
        fs = s3fs.S3FileSystem()
        # moto keeps its buckets in this process across servers: start empty (its reset endpoint)
        import urllib.request

        urllib.request.urlopen(urllib.request.Request(f"http://{host}:{port}/moto-api/reset", method="POST"))
        fs.mkdir(BUCKET)
        yield fs
    finally:
        s3fs.S3FileSystem.clear_instance_cache()
        server.stop()


@pytest.fixture(scope="module")
def local(tmp_path_factory):
    root = build_archive(tmp_path_factory.mktemp("s3") / "archive", nested=False)
    pick = tmp_path_factory.mktemp("s3") / "in"
    pick.mkdir(exist_ok=True)
    for name in NAMES:
        shutil.copy(root / name, pick / name)
    return pick


def _upload(fs, local) -> str:
    for name in NAMES:
        fs.put_file(str(local / name), f"{BUCKET}/in/{name}")
    return f"s3://{BUCKET}/in"


def test_catalog_and_export_from_and_to_s3_equal_the_local_job(s3, local, tmp_path):
    url = _upload(s3, local)
    remote = catalog([url], workers=1).to_pylist()
    here = catalog([local], workers=1).to_pylist()
    assert {r["path"] for r in remote} == {f"{url}/{n}" for n in NAMES[:2]}
    strip = lambda rows: [{k: v for k, v in r.items() if k != "path"} for r in rows]  # noqa: E731
    assert strip(remote) == strip(here) and all(r["error"] is None for r in remote)

    out = f"s3://{BUCKET}/out"
    rows = export([url], out, format="parquet", workers=1).to_pylist()
    want = export([local], tmp_path / "local", format="parquet", workers=1).to_pylist()
    assert [r["status"] for r in rows] == ["done"] * len(want) == ["done"] * 2
    mine = {rel: s3.cat(f"{BUCKET}/out/{rel}") for r in rows for rel in r["outputs"]}
    assert {rel: p.read_bytes() for rel, p in output_files(tmp_path / "local").items()} == mine
    table = ds.dataset(f"{BUCKET}/out", filesystem=s3, format="parquet", partitioning="hive",
                       exclude_invalid_files=True).to_table()
    assert table.num_rows == sum(r["points"] for r in rows) > 0
    again = export([url], out, format="parquet", workers=1).to_pylist()
    assert again == rows  # done units skipped: the manifest on S3 says so and the outputs are there


def test_cli_exports_s3_to_s3(s3, local, tmp_path):
    url = _upload(s3, local)
    res = lidarpkt_cli("export", url, "-o", f"s3://{BUCKET}/las", "--format", "las", "--workers", "1", "-q")
    assert res.returncode == 0, res.stderr
    export([local], tmp_path / "las", format="las", workers=1)
    want = {rel: p.read_bytes() for rel, p in output_files(tmp_path / "las").items()}
    assert {rel: s3.cat(f"{BUCKET}/las/{rel}") for rel in want} == want
    assert s3.exists(f"{BUCKET}/las/_manifest.jsonl")
