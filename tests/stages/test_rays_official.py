"""RayIoU against a transcription of SparseOcc's protocol, written here from the rules of its code
(MCG-NJU/SparseOcc ``loaders/ray_metrics.py``: ``generate_lidar_rays``, ``process_one_sample``,
``calc_rayiou``; ``lib/dvr/dvr.cu``: ``render_forward_cuda_kernel``), independent of
``stages/evaluation/rays.py``: plain numpy, all rays stepped together.

The rules transcribed:

* rays: float32 unit vectors (pitches ``-(pi/2 - atan(k + 1))``, k < 10, then the gap of the last
  two added until the pitch reaches 0.21 rad; azimuths 0..359 whole degrees);
* end points ``rays + origin`` (float64: float32 rays plus float64 origins), then origin and end
  points to voxel units ``((p - pc_min) / voxel)`` in float64 with the float32 ``pc_min`` and
  ``0.4``, then ``.float()``;
* the caster, in double from those float32 values: the direction ``(e - o) / |e - o|``; the start
  voxel ``int(o)``; ``step = d >= 0 ? 1 : -1``; ``tMax = (v + (step > 0) - o) / d``,
  ``tDelta = step / d`` (DBL_MAX where ``d == 0``); each step takes x when ``tMaxX < tMaxY`` and
  ``tMaxX < tMaxZ``, else y when ``tMaxY < tMaxZ``, else z (ties: z, then y, then x); the
  distance recorded for a voxel inside the grid is the tMax it steps on (where the ray leaves
  it); it stops on leaving the grid after being in it (or after 1000 steps);
* the depth is the first occupied voxel's distance, else the last in-grid voxel's, written to a
  float32 tensor and multiplied by 0.4 in float32; the label is the grid at that voxel;
* RayIoU: the rays whose ground truth is not free; per threshold (1, 2, 4 m) and class,
  ``TP / (GT + P - TP)`` with TP = same class and float32 ``|d_pred - d_gt| < t``; the free class
  dropped; the nanmean over thresholds and classes.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from shared_data import needs, shared_path

from carlaocc.schemas import taxonomy
from carlaocc.stages.evaluation.rays import RayAccumulator, first_hits

SAMPLE = shared_path("occupancy/occ3d-nuscenes/labels.npz")
pytestmark = needs(SAMPLE)

NAMES = list(taxonomy.OCC3D_NUSCENES_NAMES)  # 18, free 17
FREE = 17
PC_MIN = np.array([-40.0, -40.0, -1.0])
VOXEL = 0.4
NUSCENES_LIDAR2EGO = (0.985793, 0.0, 1.84019)  # nuScenes LIDAR_TOP calibrated_sensor translation
FACES = (0.0, 0.0, 1.8402)  # x, y on voxel faces: the azimuth-90/270 rays run along a face


def official_rays() -> np.ndarray:
    pitches = [-(math.pi / 2 - math.atan(k + 1)) for k in range(10)]
    while pitches[-1] < 0.21:
        pitches.append(pitches[-1] + (pitches[-1] - pitches[-2]))
    out = []
    for p in pitches:
        for a in np.arange(0, 360, 1):
            a = np.deg2rad(a)
            out.append((np.cos(p) * np.cos(a), np.cos(p) * np.sin(a), np.sin(p)))
    return np.array(out, dtype=np.float32)


def official_cast(sem: np.ndarray, origin) -> tuple[np.ndarray, np.ndarray]:
    """(float32 depth m, label) of every official ray from one origin through ``sem`` (X, Y, Z)."""
    rays = official_rays()
    o = np.asarray(origin, np.float64)
    off = PC_MIN.astype(np.float32).astype(np.float64)
    scale = np.float64(np.float32(VOXEL))
    O = ((o - off) / scale).astype(np.float32).astype(np.float64)
    E = ((rays.astype(np.float64) + o - off) / scale).astype(np.float32).astype(np.float64)
    r = E - O
    d = r / np.sqrt((r * r).sum(axis=1))[:, None]
    n = len(d)
    size = np.array(sem.shape)
    occ = sem != FREE
    step = np.where(d >= 0, 1, -1)
    v = np.tile(np.trunc(O).astype(np.int64), (n, 1))
    big = np.finfo(np.float64).max
    with np.errstate(divide="ignore", invalid="ignore"):
        tmax = np.where(d != 0, (v + (step > 0) - O) / d, big)
        tdelta = np.where(d != 0, step / d, big)
    hit_d, hit_v = np.full(n, -1.0), np.zeros((n, 3), np.int64)
    last_d, last_v = np.full(n, -1.0), np.zeros((n, 3), np.int64)
    found = np.zeros(n, bool)
    was_inside = np.zeros(n, bool)
    live = np.arange(n)
    rows = np.arange(n)
    for _ in range(1001):
        if not len(live):
            break
        vv = v[live]
        inside = np.all((vv >= 0) & (vv < size), axis=1)
        go = ~(was_inside[live] & ~inside)  # a ray that was inside and left stops
        live, vv, inside = live[go], vv[go], inside[go]
        was_inside[live] |= inside
        tm = tmax[live]
        ax = np.where(tm[:, 0] < tm[:, 1], np.where(tm[:, 0] < tm[:, 2], 0, 2), np.where(tm[:, 1] < tm[:, 2], 1, 2))
        k = rows[: len(live)]
        dist = tm[k, ax]
        v[live, ax] += step[live, ax]
        tmax[live, ax] += tdelta[live, ax]
        rec = live[inside]
        rv, rd = vv[inside], dist[inside]
        last_d[rec], last_v[rec] = rd, rv
        new = ~found[rec] & occ[rv[:, 0], rv[:, 1], rv[:, 2]]
        hit_d[rec[new]], hit_v[rec[new]] = rd[new], rv[new]
        found[rec[new]] = True
        live = live[~found[live]]  # a hit ends the search (the first occupied voxel of the path)
    dist = np.where(found, hit_d, last_d).astype(np.float32) * np.float32(VOXEL)
    vox = np.where(found[:, None], hit_v, last_v)
    return dist, sem[vox[:, 0], vox[:, 1], vox[:, 2]].astype(np.int64)


def official_rayiou(gt: np.ndarray, pred: np.ndarray, origin) -> float:
    gd, gl = official_cast(gt, origin)
    pd, pl = official_cast(pred, origin)
    keep = gl != FREE
    gd, gl, pd, pl = gd[keep], gl[keep], pd[keep], pl[keep]
    err = np.abs(pd - gd)  # float32
    ious = []
    for t in (1, 2, 4):
        row = []
        for c in range(len(NAMES)):
            g, p = (gl == c).sum(), (pl == c).sum()
            tp = ((gl == c) & (pl == c) & (err < t)).sum()
            row.append(tp / (g + p - tp) if g + p - tp else np.nan)
        ious.append(row[:-1])
    return float(np.nanmean(ious))


def ours(gt: np.ndarray, pred: np.ndarray, origin) -> float:
    acc = RayAccumulator(NAMES)
    acc.update(gt, pred, np.asarray(origin, float)[None], PC_MIN, VOXEL)
    return acc.ray_iou().ray_iou


@pytest.fixture(scope="module")
def grids():
    gt = np.load(SAMPLE)["semantics"].astype(np.int64)
    shifted = np.full_like(gt, FREE)
    shifted[1:] = gt[:-1]  # the whole sample one voxel along +x
    return gt, shifted


@pytest.mark.parametrize(("origin", "expected"), [(NUSCENES_LIDAR2EGO, 0.761857), (FACES, 0.815866)])
def test_rayiou_matches_the_official_casters_reading(grids, origin, expected):
    gt, shifted = grids
    official = official_rayiou(gt, shifted, origin)
    assert official == pytest.approx(expected, abs=5e-7)
    assert ours(gt, shifted, origin) == pytest.approx(official, abs=1e-6)


@pytest.mark.parametrize("origin", [NUSCENES_LIDAR2EGO, FACES])
def test_every_ray_matches_the_transcription(grids, origin):
    """Ray by ray: the same voxel's label and the same float32 depth (on the face origin the
    azimuth-270 rays, with a -1.8e-16 x component in float64, stay in their column)."""
    for sem in grids:
        od, ol = official_cast(sem, origin)
        depth, lin = first_hits(sem != FREE, np.asarray(origin, float)[None], official_rays(), PC_MIN, VOXEL)
        assert np.all(lin >= 0)
        np.testing.assert_array_equal(sem.reshape(-1)[lin], ol)
        np.testing.assert_array_equal(depth.astype(np.float32), od)
