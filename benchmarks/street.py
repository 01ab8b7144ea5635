"""A synthetic street at any voxel size, built directly in voxel space, for the quality and report
benchmarks: a 2-voxel ground slab at z = -1.73 m, solid buildings along both sides, cars, poles
and trees (blobs with holes, so some voxels are isolated); and the pose of a second frame seen
from a sensor moved 0.37 m forward, 0.11 m left, yawed 0.6 degrees and pitched 0.1 degrees
(nearest-voxel resampling, so the aliasing along the moved boundaries is what keeps s_tc below 1).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from carlaocc.schemas.grid import GridSpec

ROAD, SIDEWALK, BUILDING, POLE, VEGETATION, CAR = 1, 2, 3, 6, 9, 14
GROUND_Z = -1.73


def street(grid: GridSpec, seed: int = 0) -> np.ndarray:
    """Dense uint8 semantic grid of a synthetic street (see the module docstring)."""
    rng = np.random.default_rng(seed)
    X, Y, Z = grid.shape
    voxel_size, (ox, oy, oz) = grid.voxel_size, grid.origin
    sem = np.zeros((X, Y, Z), np.uint8)

    def ix(x):
        return int(np.clip(round((x - ox) / voxel_size), 0, X))

    def iy(y):
        return int(np.clip(round((y - oy) / voxel_size), 0, Y))

    def iz(z):
        return int(np.clip(round((z - oz) / voxel_size), 0, Z))

    g = iz(GROUND_Z)
    sem[:, :, g - 2:g] = ROAD
    sem[:, : iy(-6.0), g - 2:g] = SIDEWALK
    sem[:, iy(6.0):, g - 2:g] = SIDEWALK
    # buildings: solid blocks along both sides
    x = -25.0
    while x < 50.0:
        length, height = rng.uniform(6, 18), rng.uniform(5, 14)
        for y0, y1 in ((-25.6, -10.0 + rng.uniform(-1, 1)), (10.0 + rng.uniform(-1, 1), 25.6)):
            sem[ix(x):ix(x + length), iy(y0):iy(y1), g:iz(GROUND_Z + height)] = BUILDING
        x += length + rng.uniform(1, 4)
    # cars on the road
    for _ in range(14):
        cx, cy = rng.uniform(-24, 50), rng.choice([-3.5, -1.5, 1.5, 3.5])
        sem[ix(cx - 2.3):ix(cx + 2.3), iy(cy - 0.9):iy(cy + 0.9), g:iz(GROUND_Z + 1.5)] = CAR
    # poles and trees on the sidewalks
    for px in np.arange(-24.0, 50.0, 8.0):
        for py in (-7.0, 7.0):
            sem[ix(px):ix(px + 0.2), iy(py):iy(py + 0.2), g:iz(GROUND_Z + 7.0)] = POLE
            cx, cy, cz, r = px + 4.0, py, GROUND_Z + 5.0, rng.uniform(1.5, 2.5)
            xs, ys, zs = np.ogrid[ix(cx - r):ix(cx + r), iy(cy - r):iy(cy + r), iz(cz - r):iz(cz + r)]
            d = ((ox + (xs + 0.5) * voxel_size - cx) ** 2 + (oy + (ys + 0.5) * voxel_size - cy) ** 2
                 + (oz + (zs + 0.5) * voxel_size - cz) ** 2)
            blob = (d < r * r) & (rng.random(d.shape) < 0.7)  # foliage with holes
            region = sem[ix(cx - r):ix(cx + r), iy(cy - r):iy(cy + r), iz(cz - r):iz(cz + r)]
            region[blob & (region == 0)] = VEGETATION
    return sem


@numba.njit(cache=True, nogil=True, parallel=True)
def resample_nearest(sem, A, c):  # pragma: no cover - numba
    """Grid t+1: label of the grid-t voxel containing each grid-(t+1) centre (q = A v + c)."""
    X, Y, Z = sem.shape
    out = np.zeros_like(sem)
    for i in numba.prange(X):
        for j in range(Y):
            for k in range(Z):
                qx = A[0, 0] * i + A[0, 1] * j + A[0, 2] * k + c[0]
                qy = A[1, 0] * i + A[1, 1] * j + A[1, 2] * k + c[1]
                qz = A[2, 0] * i + A[2, 1] * j + A[2, 2] * k + c[2]
                if qx < 0 or qy < 0 or qz < 0 or qx >= X or qy >= Y or qz >= Z:
                    continue
                out[i, j, k] = sem[int(qx), int(qy), int(qz)]
    return out


def moved_pose() -> np.ndarray:
    yaw, pitch = math.radians(0.6), math.radians(0.1)
    cz, sz, cy, sy = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    p = np.eye(4)
    p[:3, :3], p[:3, 3] = rz @ ry, (0.37, 0.11, 0.0)
    return p
