"""``lidarpkt export`` / ``lidarpkt.archive.export`` in this process (``--workers 1``): outputs equal
to what ``lidarpkt.open`` decodes, read back with the format's own reader; the manifest; re-runs
skip what is done; damaged inputs are recorded and the job goes on; leftovers of a killed job are
cleaned; the CLI's exit status and one-line errors."""

from __future__ import annotations

import json
import os
import warnings

import numpy as np
import pyarrow as pa
import pyarrow.compute  # noqa: F401 - pa.compute
import pyarrow.dataset as ds
import pytest

import lidarpkt
from archive_cases import build_archive, lidarpkt_cli, manifest_rows, no_partial_files, output_files
from lidarpkt.archive import export
from lidarpkt.archive.manifest import LOCK_NAME, ExportBusyError


def _sidecar(path) -> list[str] | None:
    json_path = os.path.splitext(path)[0] + ".json"
    return [json_path] if os.path.exists(json_path) else None


def _expected_points(path, metadata=None) -> tuple[int, int]:
    """(frames, returns) of a capture as lidarpkt.open decodes it: every slot with range > 0 in a valid column."""
    frames = points = 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for f in lidarpkt.open(path, metadata=metadata):
            frames += 1
            points += int(np.count_nonzero((f.range_mm > 0) & f.column_valid[None, None, :]))
    return frames, points


@pytest.fixture(scope="module")
def archive(tmp_path_factory):
    return build_archive(tmp_path_factory.mktemp("arch") / "archive")


def test_parquet_export_equals_lidarpkt_open_and_reruns_skip(archive, tmp_path):
    out = tmp_path / "out"
    table = export([archive], out, format="parquet", workers=1)
    rows = table.to_pylist()
    assert len(rows) == 7 and all(r["status"] == "done" and r["error"] is None for r in rows)
    data = ds.dataset(out, format="parquet", partitioning="hive").to_table().to_pandas()
    for r in rows:
        path = r["input"]
        md = [str(os.path.splitext(path)[0] + ".json")] if os.path.exists(os.path.splitext(path)[0] + ".json") else None
        frames, points = _expected_points(path, md)
        mine = data[data["capture"] == r["capture"]]
        assert (r["frames"], r["points"]) == (frames, points), r["key"]
        assert len(mine) == points and mine["frame_id"].nunique() == len({*mine["frame_id"]}) <= frames
        assert r["outputs"] == [f"capture={r['capture']}/{os.path.splitext(r['capture'])[0]}.parquet"]
    before = {rel: p.stat().st_mtime_ns for rel, p in output_files(out).items()}
    again = export([archive], out, format="parquet", workers=1).to_pylist()
    assert again == rows  # every unit skipped: the rows are the earlier ones
    assert {rel: p.stat().st_mtime_ns for rel, p in output_files(out).items()} == before
    assert len(manifest_rows(out)) == 7 and not no_partial_files(out) and not (out / LOCK_NAME).exists()
    # another format or option is another job: not skipped
    frames = export([archive], out, format="parquet", layout="frames", workers=1, glob="vlp16-dual.pcap")
    assert frames.column("status").to_pylist() == ["done"] and len(manifest_rows(out)) == 8


def test_npz_export_equals_the_npz_writer_on_each_capture(archive, tmp_path):
    from lidarpkt.writers import open_writer

    out = tmp_path / "npz"
    rows = export([archive], out, format="npz", workers=1, glob="vlp16-*.pcap").to_pylist()
    assert [r["outputs"] for r in rows] == [["vlp16-dual.npz"], ["vlp16-strongest.npz"]]
    for r in rows:
        ref = tmp_path / f"ref-{r['capture']}.npz"
        with open_writer("npz", ref, capture=r["capture"]) as w:
            for f in lidarpkt.open(r["input"]):
                w.write(f)
        with np.load(out / r["outputs"][0]) as got, np.load(ref) as want:
            assert sorted(got.files) == sorted(want.files)
            for k in want.files:
                np.testing.assert_array_equal(got[k], want[k])


def test_damaged_inputs_are_recorded_and_the_job_goes_on(archive, tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    good = (archive / "vlp16-strongest.pcap").read_bytes()
    (src / "good.pcap").write_bytes(good)
    (src / "garbage.pcap").write_bytes(b"garbage!" * 100)
    (src / "cut.pcap").write_bytes(good[: len(good) * 2 // 3 + 7])  # ends inside a record
    (src / "ouster-no-metadata.pcap").write_bytes((archive / "os1-64-dual.pcap").read_bytes())
    out = tmp_path / "out"
    res = lidarpkt_cli("export", str(src), "-o", str(out), "--format", "parquet", "--workers", "1", "-q")
    assert res.returncode == 1, res.stderr
    rows = {r["capture"]: r for r in manifest_rows(out)}
    assert rows["good.pcap"]["status"] == "done" and rows["good.pcap"]["frames"] == 7
    assert rows["garbage.pcap"]["status"] == "failed" and "garbage.pcap" in rows["garbage.pcap"]["error"]
    assert "metadata" in rows["ouster-no-metadata.pcap"]["error"]  # says what to give
    cut = rows["cut.pcap"]  # truncated: the frames before the damage, and the warning that says so
    assert cut["status"] == "done" and 0 < cut["frames"] < 7 and any("cut.pcap" in w for w in cut["warnings"])
    assert "failed: garbage.pcap" in res.stderr and "failed: ouster-no-metadata.pcap" in res.stderr
    assert "2 failed" in res.stderr
    assert sorted(output_files(out)) == ["capture=cut.pcap/cut.parquet", "capture=good.pcap/good.parquet"]


def test_leftovers_of_a_killed_job_are_cleaned_and_redone(archive, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    stage = out / ".staging" / "vlp16-dual.pcap" / "capture=vlp16-dual.pcap"
    stage.mkdir(parents=True)
    (stage / ".vlp16-dual.parquet.1234abcd.tmp").write_bytes(b"PAR1 half a file")
    (out / LOCK_NAME).write_text("999999999\n")  # the PID of a job that no longer runs
    done = {"key": "vlp16-strongest.pcap", "status": "done"}
    (out / "_manifest.jsonl").write_text(json.dumps(done) + "\n" + '{"key": "vlp16-du')  # torn last line
    rows = export([archive], out, format="parquet", workers=1, glob="vlp16-*.pcap").to_pylist()
    assert [r["status"] for r in rows] == ["done", "done"]  # the stale "done" row lacked the job: redone
    assert not no_partial_files(out) and not (out / LOCK_NAME).exists()
    assert sorted(output_files(out)) == ["capture=vlp16-dual.pcap/vlp16-dual.parquet",
                                         "capture=vlp16-strongest.pcap/vlp16-strongest.parquet"]


def test_a_second_job_on_the_same_outdir_is_refused(archive, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / LOCK_NAME).write_text(f"{os.getppid()}\n")  # a live process holds it
    with pytest.raises(ExportBusyError, match="another export job"):
        export([archive], out, format="npz", workers=1)


def test_deleted_output_is_redone(archive, tmp_path):
    out = tmp_path / "out"
    export([archive], out, format="npz", workers=1, glob="vlp16-*.pcap")
    (out / "vlp16-dual.npz").unlink()
    rows = export([archive], out, format="npz", workers=1, glob="vlp16-*.pcap").to_pylist()
    assert (out / "vlp16-dual.npz").is_file() and len(manifest_rows(out)) == 3 and len(rows) == 2


@pytest.mark.parametrize("args, flag", [
    (["--format", "parquet", "--workers", "0"], "--workers 0"),
    (["--format", "parquet", "--segment-size", "lots"], "--segment-size lots"),
    (["--format", "las", "--layout", "frames"], "--layout frames"),
    (["--format", "parquet", "--frames-per-file", "3"], "--frames-per-file 3"),
    (["--format", "npz", "--metadata", "/no/such.json"], "--metadata /no/such.json"),
    (["--format", "npz", "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "--workers and --scheduler"),
])
def test_export_cli_errors_are_one_line_exit_2(archive, tmp_path, args, flag):
    out = tmp_path / "out"
    res = lidarpkt_cli("export", str(archive / "vlp16-dual.pcap"), "-o", str(out), *args, "-q")
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"lidarpkt: error: {flag}"), res.stderr
    assert not out.exists() or not output_files(out)


def test_export_cli_output_is_a_file(archive, tmp_path):
    f = tmp_path / "afile"
    f.write_text("x")
    res = lidarpkt_cli("export", str(archive), "-o", str(f), "--format", "npz", "--workers", "1")
    assert res.returncode == 2 and res.stderr.startswith(f"lidarpkt: error: -o {f}: is a file, not a folder")


def test_segmented_export_equals_whole_file_export_row_for_row(archive, tmp_path):
    """Captures cut by a small threshold (boundaries mid-frame, beside position/IMU packets and
    Ouster's IPv4 fragments) give the same points as whole-file units."""
    pick = [archive / "os1-64-dual.pcap", archive / "vlp16-dual.pcap", archive / "drive2" / "crc_test.pcap"]
    whole = export(pick, tmp_path / "whole", format="parquet", workers=1).to_pylist()
    cut = export(pick, tmp_path / "cut", format="parquet", workers=1, segment_bytes="150kB").to_pylist()
    assert all(r["status"] == "done" for r in whole + cut)
    parts = [r for r in cut if r["part"]]
    assert len(parts) > 2 * len(whole)  # the larger captures really were cut
    assert {r["key"].split("#")[0] for r in cut} == {r["key"] for r in whole}
    for field in ("frames", "points", "lost_packets"):
        for w in whole:
            assert sum(r[field] for r in cut if r["key"].split("#")[0] == w["key"]) == w[field], (w["key"], field)
    a = _plain(ds.dataset(tmp_path / "whole", format="parquet", partitioning="hive").to_table())
    files = sorted((tmp_path / "cut").rglob("*.parquet"))
    b = _plain(pa.concat_tables([_part_table(f) for f in files]))
    key = [(k, "ascending") for k in ("capture", "sensor", "timestamp_ns", "return_slot", "row", "column")]
    a, b = a.sort_by(key), b.sort_by(key)
    assert a.num_rows == b.num_rows > 0
    for name in a.column_names:  # frame_id too: a segment knows the whole file's VLP-16 ordinals
        assert a.column(name).to_pylist() == b.column(name).to_pylist(), name


def _plain(table):
    """Dictionary-encoded columns as plain strings (pyarrow does not sort dictionaries)."""
    import pyarrow as pa

    for i, f in enumerate(table.schema):
        if pa.types.is_dictionary(f.type):
            table = table.set_column(i, f.name, table.column(i).cast(pa.string()))
    return table


def _part_table(path):
    """One part file of a segmented export, with its capture (the partition) and file name."""
    table = ds.dataset(path, format="parquet").to_table()
    n = table.num_rows
    return table.append_column("capture", pa.array([path.parent.name.split("=", 1)[1]] * n)).append_column(
        "file", pa.array([path.name] * n))


def test_names_that_differ_only_by_folder_or_suffix_get_distinct_outputs(archive, tmp_path):
    src = tmp_path / "in"
    for sub in ("day1", "day2"):
        (src / sub).mkdir(parents=True)
        import shutil

        shutil.copy(archive / "vlp16-strongest.pcap", src / sub / "drive.pcap")
    shutil.copy(archive / "vlp16-dual.pcap", src / "day1" / "drive.pcapng")  # pcap inside; the magic decides
    rows = export([src], tmp_path / "out", format="npz", workers=1).to_pylist()
    assert [r["status"] for r in rows] == ["done"] * 3
    outs = sorted(o for r in rows for o in r["outputs"])
    assert outs == ["day1__drive.npz", "day2__drive.npz", "drive.npz"]
    (src / "day2" / "drive.pcap").unlink()  # now drive.pcap and drive.pcapng differ by their suffix only
    rows = export([src], tmp_path / "out2", format="npz", workers=1).to_pylist()
    assert sorted(o for r in rows for o in r["outputs"]) == ["drive_pcap.npz", "drive_pcapng.npz"]


@pytest.mark.parametrize("fmt", ["las", "laz", "ply", "pcd", "mcap"])
def test_every_format_through_the_unit_reads_back_with_its_own_reader(archive, tmp_path, fmt):
    out = tmp_path / fmt
    opts = {"frames_per_file": 2} if fmt == "laz" else {}
    rows = export([archive / "vlp16-dual.pcap", archive / "os1-64-dual.pcap"], out, format=fmt, workers=1,
                  **opts).to_pylist()
    assert [r["status"] for r in rows] == ["done", "done"]
    for r in rows:
        files = [out / o for o in r["outputs"]]
        assert files and all(f.is_file() for f in files)
        if fmt in ("las", "laz"):
            import laspy

            points = 0
            for f in files:
                las = laspy.read(f)
                points += len(las.points)
                assert (np.asarray(las.return_number) <= np.asarray(las.number_of_returns)).all()
            assert points == r["points"] > 0
            assert len(files) == (1 if fmt == "las" else -(-r["frames"] // 2))  # one per 2 frames of one sensor
        elif fmt == "ply":
            from plyfile import PlyData

            assert len(files) == r["frames"]
            assert sum(PlyData.read(f)["vertex"].count for f in files) == r["points"]
        elif fmt == "pcd":
            from pypcd4 import PointCloud

            assert len(files) == r["frames"]
            assert sum(PointCloud.from_path(f).points for f in files) == r["points"]
        else:
            from mcap.reader import make_reader

            with open(files[0], "rb") as fh:
                summary = make_reader(fh).get_summary()
            topics = {summary.channels[c].topic: n for c, n in summary.statistics.channel_message_counts.items()}
            assert r["frames"] == _expected_points(r["input"], _sidecar(r["input"]))[0]
            packets = topics.get("/velodyne_packets", 0) + topics.get("/ouster/lidar_packets", 0)
            assert packets >= r["frames"] > 0  # decode's output: the raw packets too (VelodyneScan: one per frame)
            from lidarpkt.cli.decode import decode_captures

            ref = tmp_path / f"decode-{r['capture']}.mcap"
            decode_captures([r["input"]], ref, **({"metadata": _sidecar(r["input"])} if _sidecar(r["input"]) else {}))
            assert files[0].read_bytes() == ref.read_bytes()  # exactly what `lidarpkt decode IN -o OUT.mcap` writes


def test_in_process_job_does_not_import_dask(archive, tmp_path):
    code = ("import sys; from lidarpkt.archive import export, catalog; "
            f"export([{str(archive / 'vlp16-dual.pcap')!r}], {str(tmp_path / 'o')!r}, format='npz', workers=1); "
            f"catalog([{str(archive / 'vlp16-dual.pcap')!r}], workers=1); "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('dask', 'distributed')))")
    import subprocess
    import sys

    from archive_cases import cli_env

    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=cli_env(), timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "[]"


def test_remote_urls_are_fetched_and_put_through_fsspec(archive, tmp_path):
    """An fsspec filesystem other than file:// (here fsspec's in-memory one, in this process):
    inputs copied to scratch, outputs written locally and put, the manifest written whole."""
    fsspec = pytest.importorskip("fsspec")
    mem = fsspec.filesystem("memory")
    for name in ("vlp16-dual.pcap", "os1-64-dual.pcap", "os1-64-dual.json"):
        mem.pipe(f"/in/{name}", (archive / name).read_bytes())
    rows = export(["memory://in"], "memory://out", format="parquet", workers=1).to_pylist()
    assert [(r["capture"], r["status"]) for r in rows] == [("os1-64-dual.pcap", "done"), ("vlp16-dual.pcap", "done")]
    local = export([archive / "vlp16-dual.pcap", archive / "os1-64-dual.pcap"], tmp_path / "local", format="parquet",
                   workers=1).to_pylist()
    for r, want in zip(rows, sorted(local, key=lambda r: r["capture"])):
        (rel,) = r["outputs"]
        assert mem.cat(f"/out/{rel}") == (tmp_path / "local" / rel).read_bytes()
        assert (r["frames"], r["points"]) == (want["frames"], want["points"])
    assert len(mem.cat("/out/_manifest.jsonl").splitlines()) == 2
    again = export(["memory://in"], "memory://out", format="parquet", workers=1).to_pylist()
    assert again == rows  # done units skipped on a remote OUTDIR too
    mem.rm("/in", recursive=True)
    mem.rm("/out", recursive=True)


def test_unwritable_outdir_is_an_error_per_unit_not_a_traceback(archive, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / ".staging").write_text("a file where the staging folder goes")  # works as root too
    rows = export([archive / "vlp16-dual.pcap", archive / "vlp16-strongest.pcap"], out, format="npz",
                  workers=1).to_pylist()
    assert [r["status"] for r in rows] == ["failed", "failed"]
    assert all("cannot create the staging folder" in r["error"] and str(out) in r["error"] for r in rows)
    res = lidarpkt_cli("export", str(archive / "vlp16-dual.pcap"), "-o", str(out), "--format", "npz",
                       "--workers", "1", "-q")
    assert res.returncode == 1 and "Traceback" not in res.stderr and "failed: vlp16-dual.pcap" in res.stderr
