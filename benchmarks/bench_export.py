"""Release export speed on one synthetic 0.1 m frame (768 x 512 x 130, ~5 % occupied, things
with instance ids), the two costs of ``carlaocc export carlaocc-release`` per frame:

1. the release's coarse grids (0.2 m forward view, 0.4 m surround view) by class priority:
   ours (:func:`pool_window`: block reductions over the dense frame) against the way the release
   resamples (every occupied voxel's centre binned into the target grid, ``np.lexsort`` by
   (voxel, priority), the last per voxel kept), written here from that description; both must
   give the same classes;
2. writing the sparse ``.npz``: ``np.savez_compressed`` (zlib level 6) against our deflate at
   level 1 (:func:`npz_bytes`), with the file sizes.

No thresholds: it prints timings and ratios. Usage: ``python -m benchmarks.bench_export [repeats]``.
"""

from __future__ import annotations

import io
import sys
import time

import numpy as np

from carlaocc.catalog.formats import carlaocc_release as rel
from carlaocc.catalog.formats.carlaocc_npz import npz_bytes, pack_ids
from carlaocc.pipeline.commands.export.release import release_grid_spec
from carlaocc.schemas.grid import GridSpec
from carlaocc.stages.voxelize.pooling import pool_window


def _frame(rng) -> tuple[np.ndarray, np.ndarray]:
    """Ground layers, boxes of classes (buildings, cars, poles...), instance ids on the things."""
    shape = (768, 512, 130)
    sem = np.zeros(shape, np.uint8)
    sem[:, :, 10:12] = 1  # road under the LiDAR
    sem[:, :40, 10:13] = 2
    inst = np.zeros(shape, np.uint32)
    classes = [3, 14, 6, 9, 20, 12]
    for k in range(400):
        c = classes[k % len(classes)]
        sx, sy, sz = (int(v) for v in rng.integers(4, (30, 24, 50)))
        x, y, z = int(rng.integers(0, 768 - sx)), int(rng.integers(0, 512 - sy)), int(rng.integers(12, 130 - sz))
        sem[x:x + sx, y:y + sy, z:z + sz] = c
        inst[x:x + sx, y:y + sy, z:z + sz] = k + 1 if c in (14, 6, 12) else 0
    return sem, inst


def _centre_binning(sem, inst, fine: GridSpec, g: rel.ReleaseGrid, rank: np.ndarray):
    """The release's way: occupied voxel centres into the target grid, highest priority kept."""
    idx = np.flatnonzero(sem.reshape(-1))
    xyz = np.stack(np.unravel_index(idx, sem.shape), axis=1)
    pts = (xyz + 0.5) * fine.voxel_size + np.asarray(fine.origin) - np.asarray(g.voxel_origin)
    tgt = np.floor(pts / g.voxel_size).astype(np.int64)
    ok = np.all((tgt >= 0) & (tgt < np.asarray(g.volume_size)), axis=1)
    tgt, s, i = tgt[ok], sem.reshape(-1)[idx[ok]], inst.reshape(-1)[idx[ok]]
    X, Y, Z = g.volume_size
    lin = (tgt[:, 0] * Y + tgt[:, 1]) * Z + tgt[:, 2]
    order = np.lexsort((rank[s], lin))
    keep = np.ones(len(order), bool)
    keep[:-1] = lin[order][1:] != lin[order][:-1]
    out_s = np.zeros(g.volume_size, np.uint8)
    out_i = np.zeros(g.volume_size, np.uint32)
    out_s.reshape(-1)[lin[order][keep]] = s[order][keep]
    out_i.reshape(-1)[lin[order][keep]] = i[order][keep]
    return out_s, out_i


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    repeats = int(argv[0]) if argv else 3
    rng = np.random.default_rng(0)
    sem, inst = _frame(rng)
    fine = GridSpec(voxel_size=0.1)
    print(f"frame 768 x 512 x 130 at 0.1 m, {np.count_nonzero(sem) / sem.size:.1%} occupied")
    rank = np.zeros(256, np.int64)
    rank[list(rel.RELEASE_PRIORITY)] = np.arange(len(rel.RELEASE_PRIORITY), 0, -1)
    for g in rel.RELEASE_GRIDS[1:]:
        spec = release_grid_spec(g)
        ours, base = [], []
        for _ in range(repeats):
            t0 = time.perf_counter()
            s1, _ = pool_window(sem, inst, fine, spec, rel.RELEASE_PRIORITY)
            ours.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            s2, _ = _centre_binning(sem, inst, fine, g, rank)
            base.append(time.perf_counter() - t0)
        agree = float(np.mean(s1 == s2))
        print(f"{g.name:<22} pool_window {min(ours):.3f} s   centre binning + lexsort {min(base):.3f} s   "
              f"ratio {min(base) / min(ours):.1f}x   classes agree on {agree:.4%} of voxels")
    # writing one frame's sparse rows
    flat = np.flatnonzero(sem.reshape(-1))
    rows = np.concatenate([np.stack(np.unravel_index(flat, sem.shape), axis=1).astype(np.uint16),
                           pack_ids(sem.reshape(-1)[flat], np.minimum(inst.reshape(-1)[flat], 2047))[:, None]], axis=1)
    arrays = {"occupancy": rows, "voxel_size": np.float64(0.1), "voxel_origin": np.zeros(3, np.float32),
              "volume_size": np.array([768, 512, 130], np.int32)}
    t_np, t_ours = [], []
    for _ in range(repeats):
        buf = io.BytesIO()
        t0 = time.perf_counter()
        np.savez_compressed(buf, **arrays)
        t_np.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        data = npz_bytes(arrays)
        t_ours.append(time.perf_counter() - t0)
    print(f"write {len(rows):,} rows: np.savez_compressed {min(t_np):.3f} s ({len(buf.getvalue()) / 1e6:.1f} MB)   "
          f"npz_bytes level 1 {min(t_ours):.3f} s ({len(data) / 1e6:.1f} MB)   ratio {min(t_np) / min(t_ours):.1f}x")


if __name__ == "__main__":
    main()
