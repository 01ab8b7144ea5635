"""Evaluation kit speed: the SSC confusion matrix over 100 Occ3D-size frames (200 x 200 x 16) and
over one CarlaOcc 0.05 m grid (1536 x 1024 x 260 = 409 M voxels), against a chunked
``np.bincount`` baseline, and panoptic quality on one 0.2 m frame (384 x 256 x 65) with a road,
buildings and 150 cars. Synthetic grids, ~3 % occupied (the measured share at 0.05 m is 2.6 %).
JIT warm-up is not timed. No thresholds: it prints timings.

Usage: ``python -m benchmarks.bench_eval``.
"""

from __future__ import annotations

import time

import numpy as np

from carlaocc.stages.evaluation import PanopticAccumulator, SSCAccumulator, label_map
from carlaocc.stages.evaluation.ssc import confusion_matrix


def _bincount_cm(pred: np.ndarray, gt: np.ndarray, n: int, chunk: int = 1 << 23) -> np.ndarray:
    """Baseline: gt * n + pred in uint16, np.bincount per chunk (ignore 255 -> a spare bin)."""
    lut = np.full(256, n * n, np.uint16)
    lut[:n] = np.arange(n, dtype=np.uint16) * n
    g, p = gt.reshape(-1), pred.reshape(-1)
    cm = np.zeros(n * n + n + 1, np.int64)
    for s in range(0, g.size, chunk):
        comb = lut[g[s : s + chunk]]
        comb += p[s : s + chunk]
        cm += np.bincount(comb, minlength=cm.size)
    return cm[: n * n].reshape(n, n)


def _grid(shape, free, n_classes, rng, occupied=0.03):
    """A uint8 grid, ``free`` everywhere but a ground layer and random boxes of classes."""
    g = np.full(shape, free, np.uint8)
    g[:, :, 1] = 1 % n_classes
    X, Y, Z = shape
    target = occupied * g.size  # boxes, on top of the ground layer
    placed = 0
    while placed < target:
        sx, sy, sz = (int(rng.integers(2, max(3, d // 12))) for d in shape)
        x, y, z = int(rng.integers(0, X - sx)), int(rng.integers(0, Y - sy)), int(rng.integers(2, Z - sz))
        g[x : x + sx, y : y + sy, z : z + sz] = rng.integers(0, n_classes - 1)
        placed += sx * sy * sz
    return g


def _noisy(gt, n, rng, rate=0.05):
    """A prediction: ``gt`` shifted by one voxel in x, with ``rate`` of the occupied voxels relabelled."""
    pred = np.roll(gt, 1, axis=0)
    occ = np.flatnonzero(pred.reshape(-1) != gt.reshape(-1)[0])
    pick = rng.choice(occ, size=int(rate * occ.size), replace=False) if occ.size else occ
    pred.reshape(-1)[pick] = rng.integers(0, n, pick.size)
    return pred


def bench_occ3d(frames: int = 100) -> None:
    rng = np.random.default_rng(0)
    lm = label_map("occ3d")
    gts = [_grid((200, 200, 16), 17, 18, rng) for _ in range(4)]
    preds = [_noisy(g, 18, rng) for g in gts]
    masks = [rng.random(g.shape) < 0.6 for g in gts]
    SSCAccumulator(lm).update(preds[0], gts[0], masks[0])  # JIT
    for use_mask in (False, True):
        acc = SSCAccumulator(lm)
        t0 = time.perf_counter()
        for i in range(frames):
            acc.update(preds[i % 4], gts[i % 4], masks[i % 4] if use_mask else None)
        r = acc.result()
        dt = time.perf_counter() - t0
        print(f"ssc 200x200x16 x {frames} frames{' + camera mask' if use_mask else ''}: {dt:.3f} s "
              f"({dt / frames * 1e3:.2f} ms/frame), mIoU {r.miou:.3f}")
    t0 = time.perf_counter()
    for i in range(frames):
        _bincount_cm(preds[i % 4], gts[i % 4], 18)
    dt = time.perf_counter() - t0
    print(f"  baseline chunked np.bincount: {dt:.3f} s ({dt / frames * 1e3:.2f} ms/frame)")


def bench_fine() -> None:
    rng = np.random.default_rng(1)
    shape = (1536, 1024, 260)
    gt = _grid(shape, 0, 30, rng, occupied=0.026)
    pred = _noisy(gt, 30, rng)
    t0 = time.perf_counter()
    cm, _ = confusion_matrix(pred, gt, 30)
    dt = time.perf_counter() - t0
    t0 = time.perf_counter()
    ref = _bincount_cm(pred, gt, 30)
    db = time.perf_counter() - t0
    assert (ref == cm).all()
    print(f"ssc one 0.05 m grid {'x'.join(map(str, shape))} ({gt.size / 1e6:.0f} M voxels): {dt:.2f} s "
          f"({gt.size / dt / 1e6:.0f} M voxels/s); chunked np.bincount {db:.2f} s")


def bench_panoptic() -> None:
    rng = np.random.default_rng(2)
    lm = label_map("carlaocc")
    shape = (384, 256, 65)
    sem = np.zeros(shape, np.uint8)
    inst = np.zeros(shape, np.uint32)
    sem[:, :, 14] = 1  # road at z = 0 m
    nid = 1
    for cls, n, (sx, sy, sz) in ((3, 40, (40, 30, 40)), (14, 150, (22, 10, 8))):  # buildings, cars
        for _ in range(n):
            x, y = int(rng.integers(0, shape[0] - sx)), int(rng.integers(0, shape[1] - sy))
            sem[x : x + sx, y : y + sy, 15 : 15 + sz] = cls
            inst[x : x + sx, y : y + sy, 15 : 15 + sz] = nid
            nid += 1
    p_sem, p_inst = np.roll(sem, 1, axis=0), np.roll(inst, 1, axis=0)
    perm = rng.permutation(nid).astype(np.uint32)
    p_inst = np.where(p_inst > 0, perm[p_inst] + 1, 0).astype(np.uint32)
    acc = PanopticAccumulator(lm, min_size=10)
    t0 = time.perf_counter()
    acc.update(p_sem, p_inst, sem, inst)
    r = acc.result()
    dt = time.perf_counter() - t0
    occ = int((sem > 0).sum())
    print(f"panoptic one 0.2 m frame {'x'.join(map(str, shape))} ({occ / 1e6:.2f} M occupied voxels, "
          f"{nid - 1} instances): {dt:.3f} s, PQ {r.means['pq']:.3f}")


def main() -> None:
    bench_occ3d()
    bench_fine()
    bench_panoptic()


if __name__ == "__main__":
    main()
