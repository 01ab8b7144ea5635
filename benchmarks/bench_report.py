"""Report-stage speed: the per-frame statistics kernel on synthetic frames, and the whole report
task on a built dataset.

1. :func:`carlaocc.stages.quality.statistics.frame_statistics` (voxels per class and distinct instance
   pairs in one pass) on a synthetic street at 0.2 m and 0.1 m (semantic uint8 + instance uint32:
   buildings and cars are instances), one thread, best of ``REPEAT``.
2. With ``ROOT VOXEL_SIZE`` arguments (or ``CARLAOCC_BENCH_ROOT`` / ``CARLAOCC_BENCH_VOXEL_SIZE``, or its short alias ``CARLAOCC_BENCH_RES``), the report
   task on that dataset (built with ``carlaocc run --voxel-size VOXEL_SIZE --root ROOT``): wall time of the
   task alone (statistics over every frame, plots, frame rendering, page), and the page's size.

Usage: ``python -m benchmarks bench_report`` or ``python -m benchmarks.bench_report /tmp/ds02 0.2``.
Printed, no thresholds.
"""

from __future__ import annotations

import os
import sys
import time

import numba
import numpy as np

from benchmarks.street import BUILDING, CAR, street as semantic_street
from carlaocc.schemas.grid import GridSpec
from carlaocc.stages.quality.statistics import frame_statistics

REPEAT = 3


def street(grid: GridSpec, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Semantic and instance grids of a synthetic street: road, buildings (instances) along both
    sides, cars (instances) on the road."""
    sem = semantic_street(grid, seed)
    inst = np.zeros(sem.shape, np.uint32)
    # number the building and car blobs per x-slab run: enough distinct ids for the kernel
    for cls, base in ((BUILDING, 1), (CAR, 10_000)):
        m = sem == cls
        ids = base + (np.arange(sem.shape[0]) // 40)[:, None, None]
        inst[m] = np.broadcast_to(ids, sem.shape)[m]
    return sem, inst


def bench_kernel() -> None:
    numba.set_num_threads(1)
    frame_statistics(np.zeros((4, 4, 4), np.uint8), np.zeros((4, 4, 4), np.uint32))  # compile
    print(f"{'voxel':>5} {'voxels':>12} {'instance voxels':>16} {'pairs':>6} {'s/frame':>8}")
    for voxel_size in (0.2, 0.1):
        grid = GridSpec(voxel_size=voxel_size)
        sem, inst = street(grid)
        best = np.inf
        for _ in range(REPEAT):
            t0 = time.perf_counter()
            _, pairs = frame_statistics(sem, inst)
            best = min(best, time.perf_counter() - t0)
        print(f"{voxel_size:>5} {sem.size:>12,} {int((inst > 0).sum()):>16,} {len(pairs):>6} {best:>8.3f}")


def bench_task(root: str, voxel_size: float) -> None:
    from carlaocc.catalog.store import Store
    from carlaocc.pipeline.engine.registry import STAGES
    from carlaocc.pipeline.engine.spec import Context
    from carlaocc.pipeline.tasks.report import REPORT_HTML, report_task
    from carlaocc.schemas.configs import DatasetConfig

    store, spec, cfg = Store(root), STAGES["report"], DatasetConfig()
    (part,) = spec.partitions(Context(store, cfg, (voxel_size,)))
    t0 = time.perf_counter()
    outputs = report_task(store, spec.config(cfg), part)
    dt = time.perf_counter() - t0
    size = len(store.read_bytes(REPORT_HTML))
    print(f"report task on {root} at {voxel_size:g} m: {dt:.2f} s, {len(outputs)} outputs, report.html {size / 1e6:.2f} MB")


def main(argv: list[str] | None = None) -> None:
    argv = [] if argv is None else argv
    bench_kernel()
    root = argv[0] if argv else os.environ.get("CARLAOCC_BENCH_ROOT")
    voxel_size = float(argv[1]) if len(argv) > 1 else float(os.environ.get("CARLAOCC_BENCH_VOXEL_SIZE") or os.environ.get("CARLAOCC_BENCH_RES", "0.2"))
    if root:
        bench_task(root, voxel_size)
    else:
        print("(give ROOT VOXEL_SIZE, or set CARLAOCC_BENCH_ROOT, to time the report task on a built dataset)")


if __name__ == "__main__":
    main(sys.argv[1:])
