"""``lidarpkt.archive.to_dask``: lazy partitions, one per capture, equal row for row to what
``export --format parquet`` writes (read back by pyarrow)."""

from __future__ import annotations

import pyarrow as pa
import pyarrow.dataset as ds
import pytest

dask = pytest.importorskip("dask")

from archive_cases import build_archive  # noqa: E402
from lidarpkt.archive import export, to_dask  # noqa: E402
from lidarpkt.archive.plan import PlanError  # noqa: E402

KEY = ["capture", "sensor", "frame_id", "return_slot", "row", "column"]


def test_to_dask_equals_the_parquet_export(tmp_path):
    archive = build_archive(tmp_path / "archive")
    export([archive], tmp_path / "out", format="parquet", workers=1)
    want = ds.dataset(tmp_path / "out", format="parquet", partitioning="hive").to_table()
    ddf = to_dask([archive])
    assert ddf.npartitions == 7  # one per capture, nothing decoded yet
    assert list(ddf.columns) == ["capture"] + [n for n in want.column_names if n != "capture"]
    with dask.config.set(scheduler="sync"):
        got = pa.Table.from_pandas(ddf.compute(), preserve_index=False)
    assert got.num_rows == want.num_rows > 0
    want = want.select(got.column_names)
    for name in ("capture", "sensor", "return_label"):  # dictionary-encoded in the files: compare as strings
        want = want.set_column(want.column_names.index(name), name, want.column(name).cast(pa.string()))
    got = got.sort_by([(k, "ascending") for k in KEY])
    want = want.sort_by([(k, "ascending") for k in KEY])
    for name in got.column_names:
        assert got.column(name).cast(want.schema.field(name).type).equals(want.column(name)), name


def test_to_dask_frames_layout_on_a_local_cluster_equals_the_exported_frames(tmp_path):
    """Segments (whole-file VLP-16 frame ids from the count pass in the graph) decoded on a real
    LocalCluster(n_workers=2) give the rows of a whole-file ``export --layout frames``."""
    distributed = pytest.importorskip("distributed")
    archive = build_archive(tmp_path / "archive")
    pick = [archive / "vlp16-dual.pcap", archive / "os1-64-dual.pcap"]
    export(pick, tmp_path / "out", format="parquet", layout="frames", workers=1)
    want = ds.dataset(tmp_path / "out", format="parquet", partitioning="hive").to_table()
    ddf = to_dask(pick, layout="frames", segment_bytes="300kB")
    assert ddf.npartitions > 4  # segments, nothing decoded yet
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cl, \
            distributed.Client(cl) as client:
        got = pa.Table.from_pandas(client.compute(ddf).result(), preserve_index=False)
    want = want.set_column(want.column_names.index("capture"), "capture", want.column("capture").cast(pa.string()))
    key = [(k, "ascending") for k in ("capture", "sensor", "frame_id")]
    got, want = got.sort_by(key), want.select(got.column_names).sort_by(key)
    assert got.num_rows == want.num_rows > 0
    for name in got.column_names:
        assert got.column(name).to_pylist() == want.column(name).to_pylist(), name


def test_to_dask_unknown_layout_is_refused(tmp_path):
    with pytest.raises(PlanError, match="points or frames"):
        to_dask([tmp_path], layout="voxels")
