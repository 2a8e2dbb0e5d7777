"""Archive jobs on Dask equal the in-process job: a ``LocalCluster(n_workers=2, processes=True)``;
a cluster started as separate processes (``dask scheduler`` and two ``dask worker`` on 127.0.0.1)
driven by ``--scheduler`` with ``file://`` inputs and outputs; a worker killed (by its PID) in the
middle of a job; a whole job killed (SIGKILL) and re-run. Every process a test starts, it stops."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

distributed = pytest.importorskip("distributed")

from archive_cases import (CANNED, assert_same_outputs, cli_env, lidarpkt_cli, manifest_rows,  # noqa: E402
                           no_partial_files, output_files)
from conftest import end_process, external, start_process  # noqa: E402
from lidarpkt.archive import catalog, export  # noqa: E402
from lidarpkt.archive.engine import EngineOptions, run_all  # noqa: E402

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def archive(tmp_path_factory):
    """Five captures of both vendors (an Ouster one in a sub-folder with its metadata beside it) and
    two copies of VeloView's 52-frame capture, so that a job lasts long enough to be interrupted."""
    root = tmp_path_factory.mktemp("arch") / "archive"
    (root / "sub").mkdir(parents=True)
    for name in ("vlp16-dual.pcap", "os1-64-dual.pcap", "os1-64-dual.json"):
        shutil.copy(CANNED / name, root / name)
    shutil.copy(external("rust-lidar-utils/ouster_example.pcap"), root / "sub" / "ouster_example.pcap")
    shutil.copy(external("rust-lidar-utils/ouster_example.json"), root / "sub" / "ouster_example.json")
    big = external("veloview/vlp-16-test-90deg-1-50-frames.pcap")
    for i in range(2):
        shutil.copy(big, root / f"long-{i}.pcap")
    return root


@pytest.fixture(scope="module")
def reference(archive, tmp_path_factory):
    """The in-process (--workers 1) outputs of each format the tests run."""
    refs = {}
    for fmt in ("parquet", "las", "npz"):
        out = tmp_path_factory.mktemp("ref") / fmt
        rows = export([archive], out, format=fmt, workers=1).to_pylist()
        assert all(r["status"] == "done" for r in rows)
        refs[fmt] = out
    return refs


def test_local_cluster_equals_in_process(archive, reference, tmp_path):
    import dask

    # allowed-failures 0: the first death counts; saturation 1: a worker holds only the task it runs
    with dask.config.set({"distributed.scheduler.allowed-failures": 0, "distributed.scheduler.worker-saturation": 1.0}), \
            distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        pids = set(client.run(os.getpid).values())
        assert len(pids) == 2 and os.getpid() not in pids  # two worker processes, not this one
        for fmt in ("parquet", "npz"):
            rows = export([archive], tmp_path / fmt, format=fmt, client=client).to_pylist()
            assert all(r["status"] == "done" for r in rows)
            assert_same_outputs(tmp_path / fmt, reference[fmt])
        assert catalog([archive], client=client) == catalog([archive], workers=1)
        # a unit that kills its worker process (here os._exit; in life a crash or the memory limit)
        # is reported for that task and the others complete
        results = {}
        # (it dies half a second into its work: the worker has reported the task it finished before)
        dies_on_3 = lambda x: (time.sleep(0.5), os._exit(1)) if x == 3 else x * 10  # noqa: E731 - pickled by value
        run_all(dies_on_3, [1, 2, 3, 4], EngineOptions(client=client), results.__setitem__,
                lost=lambda task, why: f"lost: {why}")
        assert {k: v for k, v in results.items() if k != 3} == {1: 10, 2: 20, 4: 40}
        assert results[3].startswith("lost: the worker process died")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class DaskProcesses:
    """``dask scheduler`` and N ``dask worker --no-nanny`` processes on 127.0.0.1; stopped on exit."""

    def __init__(self, workers: int, tmp: Path) -> None:
        self.address = f"tcp://127.0.0.1:{_free_port()}"
        self.tmp = tmp
        self.procs: list[subprocess.Popen] = []
        self.n = workers

    def _start(self, *args: str) -> subprocess.Popen:
        log = open(self.tmp / f"dask-{len(self.procs)}.log", "w")
        proc = start_process([sys.executable, "-m", "distributed.cli.dask_" + args[0], *args[1:]],
                             stdout=log, stderr=subprocess.STDOUT, env=cli_env(), cwd=self.tmp)
        self.procs.append(proc)
        return proc

    def __enter__(self) -> "DaskProcesses":
        port = self.address.rsplit(":", 1)[1]
        self._start("scheduler", "--host", "127.0.0.1", "--port", port, "--no-dashboard")
        self.workers = [self._start("worker", self.address, "--nthreads", "1", "--no-nanny", "--host", "127.0.0.1",
                                    "--no-dashboard", "--local-directory", str(self.tmp))
                        for _ in range(self.n)]
        with distributed.Client(self.address, timeout="30s") as client:
            client.wait_for_workers(self.n, timeout=60)
        return self

    def __exit__(self, *exc) -> None:
        for proc in reversed(self.procs):
            if proc.poll() is None:
                proc.terminate()
        for proc in self.procs:
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                pass
            end_process(proc)


def _running_units(outdir: Path) -> int:
    staging = outdir / ".staging"
    return len(list(staging.iterdir())) if staging.is_dir() else 0


def _wait_until(outdir: Path, proc: subprocess.Popen, *, rows: int, running: int, timeout: float = 120) -> None:
    """Until the manifest has ``rows`` lines and ``running`` units are writing (their staging folders)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        done = len(manifest_rows(outdir)) if (outdir / "_manifest.jsonl").exists() else 0
        if done >= rows and _running_units(outdir) >= running:
            return
        if proc.poll() is not None:
            raise AssertionError(f"the job ended first ({done} rows): {proc.stderr.read()}")
        time.sleep(0.01)
    raise AssertionError("the job made no progress")


def test_separate_process_cluster_file_urls_and_a_killed_worker(archive, reference, tmp_path):
    with DaskProcesses(2, tmp_path) as cluster:
        out = tmp_path / "parquet"
        res = lidarpkt_cli("export", f"file://{archive}", "-o", f"file://{out}", "--format", "parquet",
                           "--scheduler", cluster.address, "-q", env=cli_env())
        assert res.returncode == 0, res.stderr
        assert_same_outputs(out, reference["parquet"])
        # the same cluster by DASK_SCHEDULER_ADDRESS; one of its two workers killed in the middle of the job
        out = tmp_path / "las"
        env = {**cli_env(), "DASK_SCHEDULER_ADDRESS": cluster.address}
        job = start_process([sys.executable, "-m", "lidarpkt", "export", str(archive), "-o", str(out),
                             "--format", "las", "-q"], env=env, stderr=subprocess.PIPE, text=True)
        try:
            _wait_until(out, job, rows=0, running=2)  # both workers inside a unit
            victim = cluster.workers[0]
            os.kill(victim.pid, signal.SIGKILL)
            victim.wait(timeout=20)
            assert job.wait(timeout=240) == 0, job.stderr.read()
        finally:
            end_process(job)
        assert len(manifest_rows(out)) == 5  # each unit recorded once (the killed worker's too)
        assert_same_outputs(out, reference["las"])
        assert not no_partial_files(out)


def test_killed_job_resumes_skips_done_units_and_leaves_no_partial_files(archive, reference, tmp_path):
    out = tmp_path / "parquet"
    args = [sys.executable, "-m", "lidarpkt", "export", str(archive), "-o", str(out), "--format", "parquet",
            "--workers", "1", "-q"]
    job = start_process(args, env=cli_env(), stderr=subprocess.PIPE, text=True)
    try:
        _wait_until(out, job, rows=1, running=1)  # one unit done, the next one writing
        job.send_signal(signal.SIGKILL)
        job.wait(timeout=20)
    finally:
        end_process(job)
    assert _running_units(out) == 1  # the killed unit's partial files, under .staging
    done_before = {r["key"] for r in manifest_rows(out) if r["status"] == "done"}
    total = len(reference_rows := manifest_rows(reference["parquet"]))
    assert 1 <= len(done_before) < total, "the kill came too late to test a resume"
    # every file with a final name belongs to a finished unit: the rest are hidden temporaries
    finished = {o for r in manifest_rows(out) for o in r["outputs"]}
    assert set(output_files(out)) <= finished | {o for r in reference_rows for o in r["outputs"]}
    assert not any(p.name.endswith(".parquet") and ".staging" not in p.parts and p.relative_to(out).as_posix()
                   not in finished for p in out.rglob("*.parquet"))
    res = lidarpkt_cli("export", str(archive), "-o", str(out), "--format", "parquet", "--workers", "1", env=cli_env())
    assert res.returncode == 0, res.stderr
    assert f"({len(done_before)} already done before)" in res.stderr
    assert not no_partial_files(out)
    assert_same_outputs(out, reference["parquet"])


def _malloc_trim_env(_: int) -> str | None:
    return os.environ.get("MALLOC_TRIM_THRESHOLD_")


def test_the_local_cluster_leaves_glibc_its_own_malloc_thresholds(monkeypatch):
    """Dask's nanny puts MALLOC_TRIM_THRESHOLD_=65536 in its workers' environment; any such variable
    turns off glibc's dynamic mmap threshold, and every frame-sized array is then mapped afresh (an
    export unit took 30x the page faults and 1.4x the time). The cluster lidarpkt starts keeps it out;
    Dask's own default still sets it (the check could fail)."""
    import dask

    from lidarpkt.archive.engine import WORKER_MALLOC_TRIM_KEY, dask_client

    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)  # the nanny copies it into this process too
    assert dask.config.get(WORKER_MALLOC_TRIM_KEY) is not None  # Dask's default, which the engine overrides
    with dask_client(EngineOptions(workers=2)) as client:
        seen = client.gather(client.map(_malloc_trim_env, range(4)))
        assert len(client.scheduler_info()["workers"]) == 2
    assert seen == [None] * 4
