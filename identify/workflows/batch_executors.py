"""The executors of a batch: where its jobs run (a thread pool here, or a dask cluster).

:data:`EXECUTORS` maps a name (a configuration's ``executor = "..."``) to a class with
``submit_all(fn, jobs)`` yielding ``(job, result)`` as jobs finish, ``cancel()`` (drop the
jobs not started yet) and ``close()``. ``"local"`` (:class:`LocalExecutor`) runs the jobs
from threads of the batch process, each job being a subprocess already; ``"dask"``
(:class:`DaskExecutor`) runs them on a ``dask.distributed`` cluster. Register more with
:func:`register_executor`. An executor knows nothing of what a job is: it calls ``fn(job)``
(:func:`identify.workflows.batch_run.run_job` for a batch) and names a dask task by the
job's ``key``. The batch itself is described in :mod:`identify.workflows.batch`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import CancelledError, ThreadPoolExecutor, as_completed

__all__ = ["EXECUTORS", "register_executor", "get_executor", "LocalExecutor", "DaskExecutor"]

#: name -> executor class (``cls(workers, **executor_options)``).
EXECUTORS: dict[str, type] = {}


def register_executor(name: str):
    """Class decorator: make an executor available to configs as ``executor = name``."""

    def decorate(cls):
        EXECUTORS[name] = cls
        return cls

    return decorate


def get_executor(name: str, workers: int, **options):
    """An executor instance by name (clear error listing the known names)."""
    try:
        cls = EXECUTORS[name]
    except KeyError:
        raise ValueError(f"unknown executor {name!r}; known: {', '.join(EXECUTORS)}") from None
    return cls(workers, **options)


@register_executor("local")
class LocalExecutor:
    """Jobs run from ``workers`` threads of this process (each job is its own subprocess).

    Parameters
    ----------
    workers : int
        Jobs at the same time.
    start_method : str, optional
        Accepted for configs written for the former process pool; ignored.
    """

    def __init__(self, workers: int, start_method: str | None = None):
        self._pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="batch-job")
        self._futures: dict = {}

    def submit_all(self, fn: Callable, jobs: Iterable) -> Iterator[tuple[object, object]]:
        """Yield ``(job, result)`` as jobs finish; an exception in ``fn`` is yielded as the result.

        A job cancelled before it started (:meth:`cancel`) is yielded with None as its result.
        """
        self._futures = {self._pool.submit(fn, job): job for job in jobs}
        try:
            for future in as_completed(self._futures):
                job = self._futures[future]
                try:
                    yield job, future.result()
                except CancelledError:
                    yield job, None
                except Exception as exc:  # run_job itself failed
                    yield job, exc
        finally:
            self.cancel()

    def cancel(self):
        """Drop the jobs that have not started."""
        for future in self._futures:
            future.cancel()

    def close(self):
        self._pool.shutdown(wait=True, cancel_futures=True)


@register_executor("dask")
class DaskExecutor:
    """Jobs on a ``dask.distributed`` cluster (``pip install .[dask]``).

    Parameters
    ----------
    workers : int
        Workers of the local cluster started when no ``address`` is given.
    address : str, optional
        A running scheduler (e.g. ``"tcp://10.0.0.5:8786"``); its workers need this
        package installed and the records and output folder on a shared file system.
    processes : bool, default True
        Local cluster only: worker processes (True) or threads in this process.
    threads_per_worker : int, default 1
        Local cluster only.
    """

    def __init__(self, workers: int, address: str | None = None, processes: bool = True, threads_per_worker: int = 1):
        try:
            # deferred: dask.distributed is an optional extra (msma-gpi[dask])
            from distributed import Client, LocalCluster
        except ImportError:
            raise RuntimeError(
                "executor 'dask' needs dask.distributed: pip install 'msma-gpi[dask]' (or pip install distributed)"
            ) from None
        self._cluster = None
        if address:
            self._client = Client(address)
        else:
            self._cluster = LocalCluster(
                n_workers=workers, threads_per_worker=threads_per_worker, processes=processes, dashboard_address=None
            )
            self._client = Client(self._cluster)

    def submit_all(self, fn: Callable, jobs: Iterable) -> Iterator[tuple[object, object]]:
        # deferred: dask.distributed is an optional extra (msma-gpi[dask])
        from distributed import as_completed

        futures = {}
        for job in jobs:
            future = self._client.submit(fn, job, pure=False, key=f"msma-batch-{job.key}-{time.monotonic_ns()}")
            futures[future] = job
        self._futures = futures
        try:
            for future in as_completed(list(futures)):
                job = futures[future]
                if future.cancelled():
                    yield job, None
                    continue
                try:
                    yield job, future.result()
                except Exception as exc:
                    yield job, exc
        finally:
            self.cancel()

    def cancel(self):
        """Drop the jobs that have not started (running ones see the batch's stop file)."""
        for future in getattr(self, "_futures", {}):
            future.cancel()

    def close(self):
        self._client.close()
        if self._cluster is not None:
            self._cluster.close()
