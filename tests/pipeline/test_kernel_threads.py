"""Kernel threads per worker (issue 39): a task of a two-worker LocalCluster runs every kernel
library on one thread (numba, the BLAS and OpenMP runtimes, OpenCV, open3d's casts), so two
tasks on two cores never start a thread per core each; in process, a task run as those workers
run it finds the same."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

TWO_WORKERS = """
import json, sys
from carlaocc.pipeline.engine.executors import DaskExecutor
from carlaocc.pipeline.engine.spec import Partition, StageSpec

def report(store, cfg, part):
    # what a stage's task loads: numpy's BLAS, numba, OpenCV (open3d's casts take the cap as an argument)
    import cv2, numba, numpy
    from carlaocc.stages.threads import thread_report
    import os
    return {"report": json.dumps({**thread_report(), "numba_pool": numba.config.NUMBA_NUM_THREADS, "pid": os.getpid()})}

results = []
ex = DaskExecutor(None, processes=True, workers=2)
try:
    ex.map(StageSpec("threads", "t", (), (), (), lambda ctx: [], report), sys.argv[1], None,
           [Partition(f"t{i}") for i in range(4)], results.append)
finally:
    ex.close()
print(json.dumps([[r.status, r.error, json.loads(r.outputs.get("report", "null"))] for r in results]))
"""


@pytest.mark.slow  # 11-20 s (two worker processes start): the in-process test below covers the cap
def test_a_two_worker_local_cluster_runs_each_kernel_on_one_thread(tmp_path):
    out = subprocess.run([sys.executable, "-c", TWO_WORKERS, str(tmp_path / "root")], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    results = json.loads(out.stdout.strip().splitlines()[-1])
    assert len(results) == 4 and all(status == "completed" for status, _, _ in results), results
    reports = [r for _, _, r in results]
    for r in reports:
        assert r["numba"] == 1 and r["cv2"] == 1 and r["open3d"] == 1, r
        assert r["numba_pool"] == 1, r  # numba's pool itself: no idle thread per core
        # numpy's OpenBLAS at least, every runtime on one thread
        assert any(p["api"] in ("openblas", "mkl") for p in r["pools"]), r
        assert all(p["threads"] == 1 for p in r["pools"]), r


IN_PROCESS = """
import json, sys
from carlaocc.pipeline.engine.executors import DaskExecutor, execute_task
from carlaocc.pipeline.engine.spec import Partition
from carlaocc.stages.threads import thread_report
import numpy  # a BLAS loaded before the cap
before = thread_report()

def task(store, cfg, part):
    import cv2  # OpenCV (and its own OpenBLAS), loaded by the cap
    return {"report": json.dumps(thread_report())}

# a task as our own LocalCluster's workers run it
threads = DaskExecutor(None, processes=True).kernel_threads
res = execute_task(task, "threads", sys.argv[1], None, Partition("t"), threads)
print(json.dumps({"before": before, "after": json.loads(res.outputs["report"]), "threads": threads}))
"""


def test_the_cap_reaches_runtimes_loaded_before_and_after_it(tmp_path):
    # a process with every library's default (no thread variables), on a machine of >= 2 cores
    env = {k: v for k, v in __import__("os").environ.items()
           if k not in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", IN_PROCESS, str(tmp_path / "root")], capture_output=True, text=True,
                         env=env, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    r = json.loads(out.stdout.strip().splitlines()[-1])
    import os

    if (os.cpu_count() or 1) > 1:  # the default is a thread per core: the cap must change it
        assert r["before"]["numba"] > 1 and any(p["threads"] > 1 for p in r["before"]["pools"])
    after = r["after"]
    assert r["threads"] == 1
    assert after["numba"] == 1 and after["cv2"] == 1 and after["open3d"] == 1
    assert len(after["pools"]) > len(r["before"]["pools"])  # OpenCV's BLAS joined, capped too
    assert all(p["threads"] == 1 for p in after["pools"]), after


DRIVER_AFTER_A_CLUSTER = """
import json, os, sys
import numba
import numpy as np
from carlaocc.pipeline.engine.executors import DaskExecutor
from carlaocc.pipeline.engine.spec import Partition, StageSpec

@numba.njit(parallel=True)
def total(a):
    s = 0.0
    for i in numba.prange(a.size):
        s += a[i]
    return s

total(np.ones(8))  # the driver's numba pool is launched, at its default size
before = os.environ.get("NUMBA_NUM_THREADS")
ex = DaskExecutor(None, processes=True, workers=1)
try:
    ex.map(StageSpec("noop", "t", (), (), (), lambda ctx: [], lambda store, cfg, part: {}), sys.argv[1], None,
           [Partition("t0")], lambda res: None)
    after = os.environ.get("NUMBA_NUM_THREADS")
finally:
    ex.close()

@numba.njit
def plus_one(x):
    return x + 1

plus_one(1)  # compiling in the driver afterwards: numba re-reads its environment
print(json.dumps({"before": before, "after": after, "pool": numba.get_num_threads()}))
"""


def test_a_local_cluster_leaves_the_drivers_numba_alone(tmp_path):
    """Our LocalCluster's workers start with numba on one thread, but the driver's environment is
    not changed: a driver whose numba pool was already running (a notebook, the Python API) went
    on to fail its next compilation ("Cannot set NUMBA_NUM_THREADS to a different value once the
    threads have been launched")."""
    env = {k: v for k, v in __import__("os").environ.items() if k != "NUMBA_NUM_THREADS"}
    out = subprocess.run([sys.executable, "-c", DRIVER_AFTER_A_CLUSTER, str(tmp_path / "root")], capture_output=True,
                         text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    r = json.loads(out.stdout.strip().splitlines()[-1])
    assert r["before"] is None and r["after"] is None, r
