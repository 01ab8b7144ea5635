"""The quality stage's speed, one core: its kernels on a synthetic 0.05 m street (issue 7: s_sc <= 1 s
a frame, s_tc <= 2 s a pair), and with ``--root`` its task on a built root (issue 25: under 1 s a
frame at 0.05 m).

Kernels (always): a synthetic street in the default region at 0.05 m (1536 x 1024 x 260 voxels,
409 M; :mod:`benchmarks.street`), frame t+1 the same street seen from a moved sensor. Both scores
run with ``numba.set_num_threads(1)`` after a warm-up on a small grid; every timing is the best of
``REPEAT`` runs.

Task (``--root``): runs the quality stage's task (:func:`carlaocc.pipeline.tasks.quality.quality_task`: continuity,
temporal consistency with both visibility masks, voxels and instances per class) in this process
with one numba thread over runs of ``--per-task`` frames of one sequence of a built root, and
prints the CPU seconds per frame (``time.process_time``: every thread of the process) after a
warm-up task. The rows go to a scratch root (the built root is only read).

Then the scores alone (no statistics), block-major as the task reads frames and frame-major as
the stage did before (each array decoded into a dense ``(X, Y, Z)`` frame with ``read_tile``,
the same kernels on the dense frames, one block). All must give the same scores (checked); the
ratio is printed.

Usage: ``python -m benchmarks.bench_quality`` (kernels), ``python -m benchmarks.bench_quality --root ROOT
[--sequence S] [--voxel-size 0.05] [--frames 20]`` (kernels and task)
(a 0.05 m root: ``python -m benchmarks.bench_scale --frames 0 --long-frames 40`` builds one under
``--work``'s ``long``).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

import numba
import numpy as np

from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.store import Store
from carlaocc.pipeline.engine.spec import Partition
from carlaocc.pipeline.tasks.quality import quality_task
from carlaocc.schemas.configs import QualityConfig
from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.records import FrameRecord, QualityRecord
from benchmarks.street import moved_pose, resample_nearest, street
from carlaocc.stages.quality import (continuity_and_ranges, spatial_continuity_counts, temporal_consistency_counts)
from carlaocc.stages.quality.temporal import relative_pose, warp_to_voxels

REPEAT = 3


def _scratch_root(root: str) -> Store:
    """A temporary root that sees the built root's occupancy and scenes (symlinks) and keeps the
    task's rows to itself."""
    tmp = tempfile.mkdtemp(prefix="bench_quality-")
    for name in ("occupancy.zarr", "scenes"):
        os.symlink(os.path.abspath(f"{root}/{name}"), f"{tmp}/{name}")
    return Store(tmp)


def _partition(seq: str, grid: GridSpec, first: int, stop: int) -> Partition:
    return Partition(f"{seq}/{grid.key}/{first:04d}", {"sequence_id": seq, "voxel_size": grid.voxel_size,
                                                        "grid": grid.model_dump(mode="json"), "first": first,
                                                        "stop": stop})


def scores_only(store: Store, seq: str, grid: GridSpec, first: int, stop: int,
                block_major: bool) -> list[tuple[str, int, float]]:
    """The scores of frames ``[first, stop)`` (and the pair after the last), without the
    statistics: frames decoded block-major (as the task does) or into dense ``(X, Y, Z)`` frames
    (as the stage did before), two reused buffers per array either way."""
    from carlaocc.stages.quality.blocks import BlockedGrid

    occ = OccupancyStore(store)
    shape = occ.open(seq, grid, "semantic").shape
    X = shape[1]
    poses = {f.frame_index: np.asarray(f.lidar_pose).reshape(4, 4) for f in ParquetTable(store, FrameRecord).load([seq])}
    masks = [n for n in ("mask_camera", "mask_lidar") if occ.exists(seq, grid, n)]
    names = ("semantic", *masks)
    if block_major:
        bufs = {n: [BlockedGrid.empty(shape[1:], occ.chunk_edges(seq, grid, n), np.uint8) for _ in range(2)]
                for n in names}
        read = lambda n, t: BlockedGrid(occ.read_blocks(seq, grid, t, n, out=bufs[n][t % 2].blocks), shape[1:])  # noqa: E731
    else:
        bufs = {n: [np.empty(shape[1:], np.uint8) for _ in range(2)] for n in names}
        read = lambda n, t: occ.read_tile(seq, grid, t, n, 0, X, out=bufs[n][t % 2])  # noqa: E731
    rows, prev = [], None
    for t in range(first, min(stop + 1, shape[0])):
        sem = read("semantic", t)
        counts, ranges = continuity_and_ranges(sem)
        if t < stop:
            rows.append(("spatial_continuity", t, counts.score))
        observed = tuple(read(n, t) for n in masks)
        if prev is not None:
            tc = temporal_consistency_counts(prev[0], sem, poses[t - 1], poses[t], grid.voxel_size, grid.origin,
                                             mask_t=prev[1], mask_t1=observed, ranges_t=prev[2], ranges_t1=ranges)
            rows.append(("temporal_consistency", t - 1, tc.score))
        prev = (sem, observed, ranges)
    return rows


def best(fn, repeat: int = REPEAT) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def kernels() -> None:
    """s_sc and s_tc on the synthetic 0.05 m street, one thread."""
    grid = GridSpec(voxel_size=0.05)
    p0, p1 = np.eye(4), moved_pose()
    t0 = time.perf_counter()
    s0 = street(grid)
    # frame t+1 samples frame t at its centres mapped back into frame t (inverse relative pose)
    A, c = warp_to_voxels(relative_pose(p1, p0), grid.origin, grid.voxel_size, grid.origin, grid.voxel_size)
    s1 = resample_nearest(s0, A, c)
    print(f"grid {grid.shape} = {s0.size / 1e6:.0f} M voxels at {grid.voxel_size} m; "
          f"occupied {np.count_nonzero(s0) / s0.size:.2%}; built in {time.perf_counter() - t0:.1f} s")

    numba.set_num_threads(1)
    small = s0[:64, :64, :64].copy()
    spatial_continuity_counts(small)  # warm-up: compile or load from the cache
    temporal_consistency_counts(small, small, p0, p1, grid.voxel_size, grid.origin)

    t_sc, sc = best(lambda: spatial_continuity_counts(s0))
    print(f"s_sc  one frame, 1 thread : {t_sc:6.3f} s  (s_sc = {sc.score:.5f}, "
          f"occupied {int(sc.occupied[1:].sum()):,}, isolated {int(sc.isolated[1:].sum()):,})")
    t_tc, tc = best(lambda: temporal_consistency_counts(s0, s1, p0, p1, grid.voxel_size, grid.origin))
    print(f"s_tc  one pair,  1 thread : {t_tc:6.3f} s  (s_tc = {tc.score:.5f}, "
          f"intersection {tc.total_intersection:,}, union {tc.total_union:,})")
    m = np.ones(s0.shape, np.bool_)
    t_m, _ = best(lambda: temporal_consistency_counts(s0, s1, p0, p1, grid.voxel_size, grid.origin,
                                                      mask_t=m, mask_t1=m))
    print(f"s_tc  with visibility masks: {t_m:6.3f} s")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--root", help="a built root (voxelize and scenes done): also time the stage's task on it")
    ap.add_argument("--sequence", help="sequence id (default: the root's first at --voxel-size)")
    ap.add_argument("--voxel-size", "--res", dest="voxel_size", type=float, default=0.05, help="voxel size, m")
    ap.add_argument("--frames", type=int, default=20, help="frames to time (after a one-frame warm-up)")
    ap.add_argument("--per-task", type=int, default=20, help="frames per quality task")
    args = ap.parse_args([] if argv is None else argv)  # `python -m benchmarks` runs the kernels alone
    kernels()
    if not args.root:
        return
    numba.set_num_threads(1)
    built = Store(args.root)
    occ = OccupancyStore(built)
    zroot = f"{args.root}/occupancy.zarr"
    seqs = sorted(d for d in os.listdir(zroot) if os.path.isdir(f"{zroot}/{d}"))
    seq = args.sequence or next(s for s in seqs if occ.stored_grid(s, args.voxel_size) is not None)
    grid = occ.stored_grid(seq, args.voxel_size)
    n = occ.open(seq, grid, "semantic").shape[0]
    frames = min(args.frames, n - 1)
    print(f"{seq} at {args.voxel_size} m: grid {grid.shape} ({np.prod(grid.shape) / 1e6:.0f} M voxels), "
          f"{frames} frames, runs of {args.per_task}, one thread")
    store = _scratch_root(args.root)
    cfg = QualityConfig(frames_per_task=args.per_task)
    quality_task(store, cfg, _partition(seq, grid, 0, 1))  # warm-up: numba, buffers, imports
    t0 = time.process_time()
    for first in range(1, 1 + frames, args.per_task):
        quality_task(store, cfg, _partition(seq, grid, first, min(first + args.per_task, 1 + frames)))
    task = (time.process_time() - t0) / frames
    timed = {}
    for label, block_major in (("scores only, block-major", True), ("scores only, frame-major", False)):
        scores_only(built, seq, grid, 0, 1, block_major)  # warm-up: its buffers
        t0 = time.process_time()
        timed[label] = (scores_only(built, seq, grid, 1, 1 + frames, block_major), (time.process_time() - t0) / frames)
    rows = sorted((r.metric, r.frame_index, r.value) for first in range(1, 1 + frames, args.per_task)
                  for r in ParquetTable(store, QualityRecord).load([f"{seq}/{grid.key}/{first:04d}"]))
    print(f"quality task (scores and statistics, block-major frames): {task:.3f} CPU s a frame")
    for label, (scores, cost) in timed.items():
        print(f"{label}: {cost:.3f} CPU s a frame")
    ratio = timed["scores only, frame-major"][1] / timed["scores only, block-major"][1]
    print(f"block-major against frame-major, scores only: {ratio:.2f}x")
    same = all(sorted(scores) == rows for scores, _ in timed.values())
    print(f"same scores: {same}")
    if not same:
        raise SystemExit("the paths disagree")


if __name__ == "__main__":
    main(sys.argv[1:])
