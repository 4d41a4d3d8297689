"""Engines: run jobs ``fn(*args)`` in worker processes and yield their results as they finish.

* ``local`` (default, embedded, no server): a pool of *spawned* processes
  (``ProcessPoolExecutor`` with the ``spawn`` context: JAX must never be forked). A worker that
  dies breaks the pool; the jobs it was running are retried once in a fresh pool and, when they
  die again, come back as a ``Crash``; the others go on.
* ``dask``: Dask distributed, on the cluster at ``address`` or on a local cluster of ``workers``
  single-threaded worker processes started here (the scheduler retries a job whose worker
  died once, then reports it as lost: a ``Crash``).

Every engine yields ``(key, result)`` pairs, one per job, in the order jobs finish; ``result``
is what ``fn`` returned or a ``Crash``. Workers get ``OMP_NUM_THREADS=1`` unless it is set.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import multiprocessing
import os
import pathlib
import tempfile
from collections.abc import Callable, Iterator, Sequence
from typing import Any, NamedTuple

ENGINES = ("local", "dask")
RETRIES = 1  # a job whose worker died runs once more before it is reported as crashed


class Crash(NamedTuple):
    """A job that did not come back: its worker died, or the engine lost it."""

    message: str


Job = tuple[str, tuple]  # (key, args of fn)


@contextlib.contextmanager
def worker_environment() -> Iterator[None]:
    """``OMP_NUM_THREADS=1`` (unless set) while workers start: they inherit it before they load
    any numerical library; the parent's environment is restored afterwards."""
    old = os.environ.get("OMP_NUM_THREADS")
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    try:
        yield
    finally:
        if old is None:
            os.environ.pop("OMP_NUM_THREADS", None)


def _marked(fn: Callable, key: str, running: str, args: tuple) -> Any:
    """``fn(*args)`` with a marker file ``running/key`` while it runs: after a broken pool, the
    markers left say which jobs were running (and count an attempt) and which never started."""
    marker = pathlib.Path(running) / key
    marker.touch()
    result = fn(*args)
    marker.unlink()
    return result


def run_local(fn: Callable, jobs: Sequence[Job], workers: int = 1) -> Iterator[tuple[str, Any]]:
    """The local engine (module docstring): ``workers`` spawned processes."""
    todo = dict(jobs)
    attempts = dict.fromkeys(todo, 0)
    ctx = multiprocessing.get_context("spawn")
    with tempfile.TemporaryDirectory(prefix="jaxhumanoid-running-") as running, worker_environment():
        while todo:
            pool = cf.ProcessPoolExecutor(max_workers=max(1, min(workers, len(todo))), mp_context=ctx)
            try:
                futures = {pool.submit(_marked, fn, key, running, args): key for key, args in todo.items()}
                broken = False
                for fut in cf.as_completed(futures):
                    key = futures[fut]
                    try:
                        result = fut.result()
                    except cf.process.BrokenProcessPool:
                        broken = True
                        continue
                    except Exception as exc:  # the job raised past fn's own handling, or did not pickle
                        result = Crash(f"{type(exc).__name__}: {exc}")
                    del todo[key]
                    yield key, result
                if not broken:
                    continue
                markers = list(pathlib.Path(running).iterdir())
                if not markers:  # no job had started: the workers cannot start at all
                    for key in list(todo):
                        del todo[key]
                        yield key, Crash("the pool's worker processes died before they ran a case")
                for marker in markers:
                    key = marker.name
                    marker.unlink()
                    attempts[key] += 1
                    if attempts[key] > RETRIES:
                        del todo[key]
                        yield key, Crash(f"the worker process died while running the case ({attempts[key]} times)")
            finally:
                pool.shutdown(wait=True, cancel_futures=True)


def run_dask(
    fn: Callable, jobs: Sequence[Job], workers: int = 1, address: str | None = None
) -> Iterator[tuple[str, Any]]:
    """The Dask engine (module docstring). With ``address`` the cluster's own workers run the jobs
    (they must import jaxhumanoid); without it a local cluster of ``workers`` processes."""
    import dask  # third-party, optional: only this engine needs it
    from distributed import Client, LocalCluster, as_completed  # third-party, optional: only this engine

    with dask.config.set({"distributed.scheduler.allowed-failures": RETRIES}), worker_environment():
        cluster = None
        if address is None:
            cluster = LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=True,
                dashboard_address=None,
                env={"OMP_NUM_THREADS": os.environ["OMP_NUM_THREADS"]},
            )
        client = Client(address or cluster)
        try:
            futures = {client.submit(fn, *args, key=f"case-{key}", pure=False): key for key, args in jobs}
            for fut in as_completed(futures):
                key = futures[fut]
                try:
                    result = fut.result()
                except Exception as exc:  # KilledWorker (its worker died twice) or a lost job
                    result = Crash(f"{type(exc).__name__}: {exc}")
                yield key, result
        finally:
            client.close()
            if cluster is not None:
                cluster.close()


def run_jobs(
    fn: Callable, jobs: Sequence[Job], engine: str = "local", workers: int = 1, address: str | None = None
) -> Iterator[tuple[str, Any]]:
    """Run ``fn(*args)`` for every job on ``engine`` (``ENGINES``); yields (key, result or Crash)."""
    if engine not in ENGINES:
        raise ValueError(f"engine: {engine!r} not in {ENGINES}")
    if engine == "local":
        if address is not None:
            raise ValueError("address: the local engine takes no address (it starts its own workers)")
        return run_local(fn, jobs, workers)
    return run_dask(fn, jobs, workers, address)
