"""Where ``kmpipe run``'s tasks run: in this process, on a pool of spawned processes, or on a Dask cluster."""

from __future__ import annotations

import collections
import concurrent.futures
import multiprocessing
import os
import re
from collections.abc import Callable, Sequence
from pathlib import Path

from kmpipe.errors import InputError
from kmpipe.formats.files import within


def call_task(function: Callable[..., dict], kwargs: dict, root: str | None = None, paths: Sequence[str] = ()) -> dict:
    """Run a task function; a bad input comes back as data (an InputError's fields do not survive pickling).

    ``paths`` (under the output folder ``root``) are checked again first, where the task runs, right before it
    writes: a symlink made since planning that leads out of the output folder is refused.
    """
    try:
        for path in paths:
            within(Path(root), path, field="-o")
        return function(**kwargs)
    except InputError as err:
        return {"input_error": {"message": err.message, "path": None if err.path is None else str(err.path),
                                "line": err.line, "field": err.field}}  # fmt: skip


#: The variables of the libraries that start a thread per core in every process: llvmpipe's rasterizer (Mesa) and
#: the BLAS under numpy and scipy (OpenBLAS, or OpenMP or MKL builds).
THREAD_VARIABLES = ("LP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def worker_environment(workers: int) -> dict[str, str]:
    """The environment each of ``workers`` local worker processes starts with, beyond this one's: the cores this
    process may use shared among the workers (at least one each) for llvmpipe's and the BLAS's threads, so that the
    workers do not each run a thread per core and contend for them (OpenBLAS's idle threads spin); a variable the
    user set is left as it is."""
    share = str(max(1, len(os.sched_getaffinity(0)) // workers))
    return {name: share for name in THREAD_VARIABLES if name not in os.environ}


class _InProcess:
    """Runs tasks in this process (its GL context is this process's), one each time it is waited on, so that each
    task is recorded before the next one starts."""

    #: Tasks handed out at a time.
    capacity = 1

    def __init__(self) -> None:
        self.queue: collections.deque = collections.deque()

    def submit(self, function, *args):
        future: concurrent.futures.Future = concurrent.futures.Future()
        self.queue.append((future, function, args))
        return future

    def wait(self, futures):
        """Run the first task submitted (``futures`` holds it); it is done."""
        future, function, args = self.queue.popleft()
        try:
            future.set_result(function(*args))
        except Exception as err:  # handed to the caller through the future
            future.set_exception(err)
        return {future}, set(futures) - {future}

    def close(self) -> None:
        self.queue.clear()


class _Pool:
    """A pool of spawned worker processes (a fork after a GL context exists hangs), each with its share of the cores
    (:func:`worker_environment`: in this process's environment while the pool lives, since the pool spawns its
    workers as tasks come, and they load the libraries that read it while they start)."""

    def __init__(self, workers: int) -> None:
        self.environment = worker_environment(workers)
        os.environ.update(self.environment)
        context = multiprocessing.get_context("spawn")
        self.pool = concurrent.futures.ProcessPoolExecutor(max_workers=workers, mp_context=context)
        self.capacity = 2 * workers

    def submit(self, function, *args):
        return self.pool.submit(function, *args)

    @staticmethod
    def wait(futures):
        return concurrent.futures.wait(futures, return_when=concurrent.futures.FIRST_COMPLETED)

    def close(self) -> None:
        try:
            self.pool.shutdown()
        finally:
            for name in self.environment:
                os.environ.pop(name, None)


#: Dask settings of the local cluster, which has no dashboard to show what these feed: its workers' statistical
#: profiler off (a stack sample every 10 ms), the system monitor every 5 s (not 0.5 s), the event loop's responsiveness
#: checked every second (not every 20 ms) and the workers' memory every second (not every 0.1 s). An idle 2-worker
#: cluster used 3.2 CPU-s in 20 s with Dask's defaults and 1.8 with these; on a 2-core machine that time is the
#: workers', and the 16-product line of ``benchmarks/bench_run.py`` went from 12 % slower than the local pool to 7 %.
QUIET = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.admin.tick.interval": "1s",
    "distributed.worker.memory.monitor-interval": "1s",
}


class _Dask:
    """A Dask distributed client: of the scheduler at ``address``, or of a local cluster of ``workers`` processes (each
    with its share of the cores for llvmpipe, :func:`worker_environment`)."""

    def __init__(self, address: str | None, workers: int) -> None:
        import dask
        from distributed import Client, LocalCluster

        self.cluster = None
        if address is None:
            # The nanny sets its workers' environment before it spawns them (its pre-spawn-environ): the cores shared
            # among them as in the local pool, and glibc's adaptive malloc kept. Dask's MALLOC_TRIM_THRESHOLD_ would
            # also fix glibc's mmap threshold at 128 KiB: every frame-sized array mapped and unmapped anew, each page
            # faulted in again (a fifth of a 16-product line's CPU time, in the kernel).
            # The nanny also sets them in this process, where they would reach whatever it spawns later: restored.
            before = "distributed.nanny.pre-spawn-environ."
            settings = {before + "MALLOC_TRIM_THRESHOLD_": None, **QUIET}
            settings.update({before + name: value for name, value in worker_environment(workers).items()})
            saved = dict(os.environ)
            try:
                with dask.config.set(settings):
                    self.cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                                dashboard_address=None)  # fmt: skip
            finally:
                for name in set(os.environ) - set(saved):
                    del os.environ[name]
                os.environ.update(saved)
        try:
            self.client = Client(address or self.cluster.scheduler_address, timeout=10)
        except Exception as err:  # whatever Dask raises, the address is what to fix
            if self.cluster is not None:
                self.cluster.close()
            raise InputError(f"cannot connect to the Dask scheduler at {address or 'the local cluster'}: "
                             f"{type(err).__name__}: {err}", field="--scheduler") from None  # fmt: skip
        self.capacity = 2 * max(workers, sum(self.client.nthreads().values()))

    def submit(self, function, *args):
        return self.client.submit(function, *args, pure=False)

    @staticmethod
    def wait(futures):
        from distributed import wait

        return wait(futures, return_when="FIRST_COMPLETED")

    def close(self) -> None:
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()


#: Addresses of a Dask scheduler: tcp://HOST:PORT, tls://HOST:PORT, HOST:PORT (tcp), inproc://...; HOST a name, an
#: IPv4 address or an [IPv6] address.
SCHEDULER = re.compile(
    r"(?:(?:tcp|tls)://)?(?:\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9](?:[A-Za-z0-9.-]*[A-Za-z0-9])?):(?P<port>[0-9]{1,5})"
    r"|inproc://[^\s/]+(?:/[^\s/]+)*"
)


def check_executor(kind: str, workers: int, scheduler: str | None) -> None:
    """Refuse an executor, a number of workers or a scheduler address that cannot work (InputError naming it)."""
    if kind not in ("local", "dask"):
        raise InputError(f"is {kind!r}; expected local or dask", field="--executor")
    if workers < 1:
        raise InputError(f"is {workers}; expected at least 1 worker", field="--workers")
    if scheduler is None:
        return
    if kind != "dask":
        raise InputError("--scheduler needs --executor dask", field="--scheduler")
    found = SCHEDULER.fullmatch(scheduler)
    if found is None or (found["port"] is not None and not 0 < int(found["port"]) < 65536):
        raise InputError(f"is {scheduler!r}; expected the address of a Dask scheduler: tcp://HOST:PORT, "
                         "tls://HOST:PORT, HOST:PORT or inproc://...", field="--scheduler")  # fmt: skip


def make_executor(kind: str, workers: int, scheduler: str | None):
    if kind == "dask":
        return _Dask(scheduler, workers)
    return _InProcess() if workers <= 1 else _Pool(workers)
