"""RayIoU speed: frames per second of ``RayAccumulator.update`` (ground truth and prediction, 8
origins x 14,040 rays each, numba first-hit traversal on all cores) on a synthetic street at the
Occ3D grid (200 x 200 x 16, 0.4 m) and at 0.2 m (400 x 400 x 32), against a vectorised numpy
march of the same rays in steps of a tenth of a voxel (what one would write without a DDA), on
a subset of the rays, scaled. No thresholds. Usage: ``python -m benchmarks.bench_rays [frames]``.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from carlaocc.schemas import taxonomy
from carlaocc.stages.evaluation.rays import RayAccumulator, first_hits, query_directions


def street(shape, voxel_size, rng) -> np.ndarray:
    """Free space, a road layer, building walls either side, boxes for cars (Occ3D ids)."""
    sem = np.full(shape, 17, np.uint8)
    X, Y, Z = shape
    ground = max(1, int(round(0.8 / voxel_size)))
    sem[:, :, :ground] = 11
    wall = int(round(12 / voxel_size))
    sem[:, :Y // 2 - wall, ground:] = 15
    sem[:, Y // 2 + wall:, ground:] = 15
    for _ in range(30):
        x, y = rng.integers(0, X - 12), rng.integers(Y // 2 - wall, Y // 2 + wall - 6)
        sem[x:x + int(4.5 / voxel_size), y:y + int(1.8 / voxel_size), ground:ground + int(1.5 / voxel_size)] = 4
    return sem


def numpy_march(occ, origins, dirs, origin, voxel_size, step=0.1):
    """First occupied voxel of every ray by stepping (voxel units), all rays at once."""
    d = np.broadcast_to(dirs[None], (len(origins), *dirs.shape))
    o = np.broadcast_to((origins[:, None, :] - origin) / voxel_size, d.shape)
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    t = np.zeros(len(o))
    alive = np.ones(len(o), bool)
    shape = np.array(occ.shape)
    hit = np.full(len(o), -1)
    for _ in range(int(np.sqrt((shape ** 2).sum()) / step) + 1):
        v = np.floor(o[alive] + t[alive, None] * d[alive]).astype(np.int64)
        inside = np.all((v >= 0) & (v < shape), axis=1)
        idx = np.flatnonzero(alive)
        occd = np.zeros(len(v), bool)
        occd[inside] = occ[v[inside, 0], v[inside, 1], v[inside, 2]]
        hit[idx[occd]] = 1
        alive[idx[occd | ~inside]] = False
        if not alive.any():
            break
        t[alive] += step
    return t * voxel_size, hit


def main() -> None:
    frames = int(sys.argv[1]) if len(sys.argv) > 1 else 5
    rng = np.random.default_rng(0)
    names = list(taxonomy.OCC3D_NUSCENES_NAMES)
    for voxel_size, shape in ((0.4, (200, 200, 16)), (0.2, (400, 400, 32))):
        origin = np.array([-40.0, -40.0, -1.0])
        gts = [street(shape, voxel_size, rng) for _ in range(frames)]
        preds = [np.roll(g, 1, axis=0) for g in gts]
        origins = np.column_stack([np.linspace(-10, 10, 8), np.zeros(8), np.full(8, 1.8)])
        acc = RayAccumulator(names)
        acc.update(gts[0], preds[0], origins, origin, voxel_size)  # compile
        t = time.perf_counter()
        for g, p in zip(gts, preds):
            acc.update(g, p, origins, origin, voxel_size)
        dt = (time.perf_counter() - t) / frames
        # the numpy march on 1/20 of the rays of one origin, scaled to a whole frame (2 grids x 8 origins)
        dirs = query_directions()[::20]
        occ = gts[0] != 17
        t = time.perf_counter()
        numpy_march(occ, origins[:1], dirs, origin, voxel_size)
        t_np = (time.perf_counter() - t) * 20 * 8 * 2
        d_ours, _ = first_hits(occ, origins[:1], dirs, origin, voxel_size)
        d_np, _ = numpy_march(occ, origins[:1], dirs, origin, voxel_size)
        agree = np.mean(np.abs(d_ours - d_np) < 0.15 * voxel_size + voxel_size)  # the march overshoots by < a step and a voxel
        print(f"{voxel_size:g} m {shape}: RayIoU update {1 / dt:6.2f} frames/s ({dt * 1e3:.0f} ms, 2 x 8 x 14,040 rays); "
              f"numpy march (0.1-voxel steps) {1 / t_np:6.3f} frames/s: x{t_np / dt:.0f}; "
              f"first hits within a voxel of each other on {100 * agree:.1f} % of rays")


if __name__ == "__main__":
    main()
