"""Dask distributed against Ray on this machine: start-up of a local two-worker cluster, four
0.5 s tasks, a task whose worker process dies (os._exit), four tasks after it, shut-down.

    OMP_NUM_THREADS=1 python scripts/eval_engines.py dask   # one JSON line
    OMP_NUM_THREADS=1 python scripts/eval_engines.py ray    # needs `pip install ray` (not a dependency)

The choice it informed (Dask) and the numbers are in docs/studies.md.
"""

import json
import os
import sys
import time


def slow_square(x):
    time.sleep(0.5)
    return x * x


def die(x):
    time.sleep(0.5)
    os._exit(9)


def dask_eval() -> dict:
    import dask
    from distributed import Client, LocalCluster

    out: dict = {}
    t0 = time.perf_counter()
    with dask.config.set({"distributed.scheduler.allowed-failures": 1}):
        cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
        client = Client(cluster)
        out["startup_s"] = time.perf_counter() - t0
        t1 = time.perf_counter()
        out["results"] = client.gather([client.submit(slow_square, i, pure=False) for i in range(4)])
        out["four_tasks_s"] = time.perf_counter() - t1
        t2 = time.perf_counter()
        try:
            client.submit(die, 0, pure=False).result(timeout=120)
            out["killed"] = "no error"
        except Exception as e:
            out["killed"] = f"{type(e).__name__}: {str(e)[:200]}"
        out["killed_s"] = time.perf_counter() - t2
        t3 = time.perf_counter()
        out["after"] = client.gather([client.submit(slow_square, i, pure=False) for i in range(4)])
        out["after_s"] = time.perf_counter() - t3
        out["workers_after"] = len(client.scheduler_info()["workers"])
        t4 = time.perf_counter()
        client.close()
        cluster.close()
        out["shutdown_s"] = time.perf_counter() - t4
    return out


def ray_eval() -> dict:
    import ray

    out: dict = {}
    t0 = time.perf_counter()
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    rs = ray.remote(max_retries=0)(slow_square)
    rd = ray.remote(max_retries=0)(die)
    ray.get(rs.remote(0))  # workers start lazily: the first task completes the start-up
    out["startup_s"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    out["results"] = ray.get([rs.remote(i) for i in range(4)])
    out["four_tasks_s"] = time.perf_counter() - t1
    t2 = time.perf_counter()
    try:
        ray.get(rd.remote(0), timeout=120)
        out["killed"] = "no error"
    except Exception as e:
        out["killed"] = f"{type(e).__name__}: {str(e)[:200]}"
    out["killed_s"] = time.perf_counter() - t2
    t3 = time.perf_counter()
    out["after"] = ray.get([rs.remote(i) for i in range(4)])
    out["after_s"] = time.perf_counter() - t3
    t4 = time.perf_counter()
    ray.shutdown()
    out["shutdown_s"] = time.perf_counter() - t4
    return out


if __name__ == "__main__":
    which = sys.argv[1]
    print(json.dumps({which: {"dask": dask_eval, "ray": ray_eval}[which]()}))
