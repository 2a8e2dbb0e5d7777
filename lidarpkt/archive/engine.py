"""Where units run: in this process (``workers=1``, no Dask imported), on a local Dask cluster of
processes (``workers=N``), or on an existing Dask cluster (``scheduler=`` / ``DASK_SCHEDULER_ADDRESS``
/ a ``client=``).

Dask does the scheduling, the retries and the recovery from lost workers; this module only
submits picklable calls and hands each result back as it arrives, telling a progress callback.
"""

from __future__ import annotations

import os
import uuid
from contextlib import contextmanager
from dataclasses import dataclass, replace
from typing import Any, Callable, Iterator, Sequence

from lidarpkt.core.checks import WORKERS
from lidarpkt.errors import LidarpktError

DEFAULT_RETRIES = 2  # a task whose worker died is re-run by Dask anyway; this covers other transient failures


class EngineError(LidarpktError):
    """The engine cannot start: Dask is not installed, or the scheduler cannot be reached."""


@dataclass(frozen=True)
class EngineOptions:
    """How to run a job: ``client`` (a ``distributed.Client``) wins, then ``scheduler`` (or the
    environment's ``DASK_SCHEDULER_ADDRESS``), then ``workers`` (default: the CPU count; 1 runs in
    this process without Dask)."""

    workers: int | None = None
    scheduler: str | None = None
    client: Any = None
    retries: int = DEFAULT_RETRIES

    def in_process(self) -> bool:
        return self.client is None and self._scheduler() is None and self._workers() == 1

    def _scheduler(self) -> str | None:
        """``scheduler``, else the environment's when no worker count was given (an explicit
        ``--workers N`` runs locally whatever the environment says)."""
        if self.scheduler:
            return self.scheduler
        return os.environ.get("DASK_SCHEDULER_ADDRESS") or None if self.workers is None else None

    def __post_init__(self) -> None:
        if self.workers is not None:  # None: the CPU count
            WORKERS.check(self.workers, "workers")  # raises UsageError naming the option and its range

    def _workers(self) -> int:
        return self.workers or os.cpu_count() or 1


def _import_distributed():
    try:
        import distributed
    except ImportError:
        raise EngineError("--workers N > 1 and --scheduler need Dask: pip install 'lidarpkt[dask]' "
                          "(or run with --workers 1)") from None
    return distributed


#: the Dask setting that puts MALLOC_TRIM_THRESHOLD_ in the environment of a nanny's worker process
WORKER_MALLOC_TRIM_KEY = "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_"


@contextmanager
def dask_client(options: EngineOptions) -> Iterator[Any]:
    """The ``distributed.Client`` a job runs on; a local cluster it starts is closed on exit."""
    if options.client is not None:
        yield options.client
        return
    distributed = _import_distributed()
    address = options._scheduler()
    if address:
        try:
            client = distributed.Client(address, timeout="20s", set_as_default=False)
        except (OSError, TimeoutError) as exc:
            raise EngineError(f"--scheduler {address}: cannot reach the Dask scheduler ({exc}); "
                              "start it with `dask scheduler` or check the address") from None
        with client:
            yield client
        return
    import logging

    import dask

    # one thread per worker process: the decode holds the GIL between NumPy calls; Dask's sampling
    # profiler (a thread every 10 ms) only costs CPU on a job nobody watches on a dashboard. Dask's
    # nanny sets MALLOC_TRIM_THRESHOLD_=65536 in its workers, and any such variable turns off glibc's
    # dynamic mmap threshold: every frame-sized array is then mapped and unmapped afresh (an export
    # unit took 30x the page faults and 1.4x the time); None keeps glibc's own behaviour
    with dask.config.set({"distributed.worker.profile.enabled": False,
                          WORKER_MALLOC_TRIM_KEY: None}), \
            distributed.LocalCluster(n_workers=options._workers(), threads_per_worker=1, processes=True,
                                     dashboard_address=None, silence_logs=logging.ERROR) as cluster:
        with distributed.Client(cluster, set_as_default=False) as client:
            yield client


def run_all(
    fn: Callable[[Any], Any],
    tasks: Sequence[Any],
    options: EngineOptions,
    on_result: Callable[[Any, Any], None],
    lost: Callable[[Any, str], Any] | None = None,
) -> None:
    """Run ``fn(task)`` for every task and call ``on_result(task, result)`` in this process as each
    finishes (in completion order). Exceptions of ``fn`` (programming errors: bad input is in its
    result) propagate after Dask's retries. A task that killed its worker every time Dask tried it
    (a crash or the memory limit: ``KilledWorker``) becomes ``on_result(task, lost(task, why))``
    when ``lost`` is given, so one such input does not stop the job."""
    if not tasks:
        return
    if options.in_process():
        for task in tasks:
            on_result(task, fn(task))
        return
    distributed = _import_distributed()
    with dask_client(options) as client:
        token = uuid.uuid4().hex[:8]
        keys = [f"lidarpkt-{getattr(fn, '__name__', 'task')}-{i}-{token}" for i in range(len(tasks))]
        futures = client.map(fn, tasks, key=keys, retries=options.retries, pure=False)
        by_key = dict(zip(keys, tasks))
        try:
            for future, result in distributed.as_completed(futures, with_results=True, raise_errors=False,
                                                           loop=client.loop):
                if future.status == "error":
                    exc = future.exception()
                    if lost is None or not isinstance(exc, distributed.KilledWorker):
                        raise exc
                    result = lost(by_key[future.key], "the worker process died each time it ran this unit (a "
                                  "crash or the worker's memory limit); try a smaller --segment-size")
                on_result(by_key[future.key], result)
        finally:
            client.cancel(futures)


def run_rows(
    fn: Callable[[Any], list[dict]],
    tasks: Sequence[Any],
    sizes: Sequence[int],
    options: EngineOptions,
    *,
    label: str,
    progress: ProgressCallback | None,
    lost: Callable[[Any, str], list[dict]],
) -> list[dict]:
    """:func:`run_all` of a function that returns a list of row dicts per task (catalog,
    multi-return maps): every row, in task order, telling ``progress`` as each task ends (a task is
    failed when one of its rows has an ``error``)."""
    results: dict[int, list[dict]] = {}
    index = {id(t): i for i, t in enumerate(tasks)}
    bar = Progress(sum(sizes), len(tasks), callback=progress, label=label)

    def record(task: Any, rows: list[dict]) -> None:
        i = index[id(task)]
        results[i] = rows
        bar.advance(sizes[i], failed=any(r.get("error") for r in rows))

    try:
        run_all(fn, tasks, options, record, lost=lost)
    finally:
        bar.close()
    return [row for i in range(len(tasks)) for row in results[i]]


@dataclass(frozen=True)
class JobProgress:
    """How far one pass of a job is, as given to a job's ``progress`` callback: after the pass starts,
    after each unit (capture or segment) and once more when the pass ends (``finished``).

    Attributes:
        label: the pass (``"catalog"``, ``"count frames"``, ``"export parquet"`` ...).
        bytes_done, bytes_total: input bytes of the units done, of all units.
        units_done, units_total: units done (failed ones included), all units.
        failed: units that failed.
        finished: the pass is over.
    """

    label: str
    bytes_done: int
    bytes_total: int
    units_done: int
    units_total: int
    failed: int = 0
    finished: bool = False

    def status(self) -> str:
        """``"3/8 units, 1 failed"``."""
        text = f"{self.units_done}/{self.units_total} units"
        return text + (f", {self.failed} failed" if self.failed else "")


ProgressCallback = Callable[[JobProgress], None]


class Progress:
    """One pass's progress, told to the job's ``progress`` callback (nothing when it is None)."""

    def __init__(self, total_bytes: int, total_units: int, *, callback: ProgressCallback | None, label: str) -> None:
        self.callback = callback
        self.state = JobProgress(label, 0, total_bytes, 0, total_units)
        self._tell()

    def _tell(self) -> None:
        if self.callback is not None:
            self.callback(self.state)

    def advance(self, size_bytes: int, *, failed: bool = False) -> None:
        s = self.state
        self.state = replace(s, bytes_done=s.bytes_done + size_bytes, units_done=s.units_done + 1,
                             failed=s.failed + int(failed))
        self._tell()

    def close(self) -> None:
        if not self.state.finished:
            self.state = replace(self.state, finished=True)
            self._tell()
