"""Engines: run jobs ``fn(*args)`` in worker processes and yield their results as they finish.

* ``local`` (default, embedded, no server): *spawned* worker processes (``ProcessPoolExecutor``
  with the ``spawn`` context: JAX must never be forked), one single-process pool per worker, each
  fed a queue of jobs that share what they compile (``plan_queues``). A worker that dies breaks
  its pool; the job it was running is retried once in a fresh pool and, when it dies again, comes
  back as a ``Crash``; the others go on.
* ``dask``: Dask distributed, on the cluster at ``address`` or on a local cluster of ``workers``
  single-threaded worker processes started here (the scheduler retries a job whose worker
  died once, then reports it as lost: a ``Crash``).

Every engine yields ``(key, result)`` pairs, one per job, in the order jobs finish; ``result``
is what ``fn`` returned or a ``Crash``. Workers get ``OMP_NUM_THREADS=1`` unless it is set.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import logging
import multiprocessing
import os
import pathlib
import tempfile
from collections.abc import Callable, Generator, Hashable, Iterator, Mapping, Sequence
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


Results = Generator[tuple[str, Any], None, None]


def plan_queues(jobs: Sequence[tuple[str, Hashable, float]], workers: int) -> list[list[str]]:
    """Deal jobs (key, group, cost) to at most ``workers`` queues so that a queue holds few groups:
    a worker sets up and compiles each distinct problem (a group: task, scheme, solver, grid) once.
    One group per distinct value, the largest groups halved while there are fewer groups than
    workers, then the groups dealt out largest cost first to the least loaded queue. Jobs keep
    their order within a group."""
    by_group: dict[Hashable, list[tuple[str, float]]] = {}
    for key, group, cost in jobs:
        by_group.setdefault(group, []).append((key, cost))
    groups = list(by_group.values())
    while len(groups) < workers and max(len(g) for g in groups) > 1:
        big = max(groups, key=len)
        groups.remove(big)
        groups += [big[: len(big) // 2], big[len(big) // 2 :]]
    queues: list[list[str]] = [[] for _ in range(max(1, min(workers, len(groups))))]
    load = [0.0] * len(queues)
    for members in sorted(groups, key=lambda g: -sum(c for _, c in g)):
        k = load.index(min(load))
        queues[k] += [key for key, _ in members]
        load[k] += sum(c for _, c in members)
    return queues


def run_local(
    fn: Callable, jobs: Sequence[Job], workers: int = 1, groups: Mapping[str, tuple[Hashable, float]] | None = None
) -> Results:
    """The local engine (module docstring): ``workers`` spawned processes, one single-process pool
    each, fed by ``plan_queues`` (``groups``: key -> (group, cost); default one group per job), so
    that a worker keeps the problems it has compiled and a dead worker breaks only its own pool."""
    todo = dict(jobs)
    attempts = dict.fromkeys(todo, 0)
    groups = groups or {key: (key, 1.0) for key in todo}
    ctx = multiprocessing.get_context("spawn")
    with tempfile.TemporaryDirectory(prefix="jaxhumanoid-running-") as running, worker_environment():
        while todo:
            queues = plan_queues([(key, *groups[key]) for key in todo], workers)
            pools = [cf.ProcessPoolExecutor(max_workers=1, mp_context=ctx) for _ in queues]
            try:
                futures = {
                    pool.submit(_marked, fn, key, running, todo[key]): key
                    for pool, queue in zip(pools, queues)
                    for key in queue
                }
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
            except BaseException:  # interrupted (Ctrl-C, the consumer stopped): stop the running cases too
                for pool in pools:
                    for proc in list((pool._processes or {}).values()):  # no public way before Python 3.14
                        proc.terminate()
                raise
            finally:
                for pool in pools:
                    pool.shutdown(wait=True, cancel_futures=True)


def run_dask(fn: Callable, jobs: Sequence[Job], workers: int = 1, address: str | None = None) -> Results:
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
                silence_logs=logging.ERROR,  # not the nanny's warnings when it stops a busy worker
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
    fn: Callable,
    jobs: Sequence[Job],
    engine: str = "local",
    workers: int = 1,
    address: str | None = None,
    groups: Mapping[str, tuple[Hashable, float]] | None = None,
) -> Results:
    """Run ``fn(*args)`` for every job on ``engine`` (``ENGINES``); yields (key, result or Crash).
    ``groups`` (key -> (group, cost)) keeps a group's jobs on few local workers (``plan_queues``);
    Dask's scheduler places jobs itself. Closing the generator early stops the workers (local) or
    the cluster it started (dask)."""
    if engine not in ENGINES:
        raise ValueError(f"engine: {engine!r} not in {ENGINES}")
    if engine == "local" and address is not None:
        raise ValueError("address: the local engine takes no address (it starts its own workers)")
    if not jobs:
        return
    if engine == "local":
        yield from run_local(fn, jobs, workers, groups)
    else:
        yield from run_dask(fn, jobs, workers, address)
