"""Ray stepping through a voxel grid (3D DDA, Amanatides & Woo 1987), shared by the visibility
masks (:mod:`carlaocc.stages.voxelize.visibility`, Algorithms 1 and 2) and the ray metrics
(:mod:`carlaocc.stages.evaluation.rays`).

Everything is in voxel units: an axis of ``n`` voxels spans ``[0, n]``, voxel ``i`` covers
``[i, i + 1)``. A ray ``o + t d`` is clipped to the grid box by :func:`slab` (one axis at a time),
enters the voxel :func:`clamp_floor` gives, and steps one voxel at a time along the axis whose next
boundary crossing is nearest, from the per-axis state of :func:`axis_setup`. The functions are
numba-compiled and inlined into their callers' loops.
"""

from __future__ import annotations

import math

from numba import njit

__all__ = ["axis_setup", "clamp_floor", "slab"]


@njit(cache=True, nogil=True, inline="always")
def axis_setup(o, d, i, n):
    """Per-axis DDA state for origin coordinate ``o`` and direction ``d`` (voxel units) from voxel
    ``i`` of an axis of ``n`` voxels: (tMax, tDelta, step, voxels left before leaving the grid);
    a zero component gets infinite tMax/tDelta (no division by zero) and never steps."""
    if d > 0.0:
        return (i + 1.0 - o) / d, 1.0 / d, 1, n - 1 - i
    if d < 0.0:
        return (i - o) / d, -1.0 / d, -1, i
    return math.inf, math.inf, 0, n  # never steps along this axis (never the minimum)


@njit(cache=True, nogil=True, inline="always")
def slab(o, d, n, t0, t1):
    """Clip [t0, t1] to the slab [0, n] of one axis (voxel units); empty when t0 > t1 after."""
    if d != 0.0:
        inv = 1.0 / d
        ta = (0.0 - o) * inv
        tb = (n - o) * inv
        if ta > tb:
            ta, tb = tb, ta
        t0 = max(t0, ta)
        t1 = min(t1, tb)
    elif not (o >= 0.0 and o < n):
        # parallel to the slab and outside it (a ray in the plane o == n belongs to voxel n)
        t0 = 1.0
        t1 = 0.0
    return t0, t1


@njit(cache=True, nogil=True, inline="always")
def clamp_floor(x, n):
    """Voxel of coordinate x (floor), clamped to [0, n - 1]."""
    i = int(math.floor(min(max(x, -1.0), n + 1.0)))  # noqa: RUF046 (an int for numba whatever floor returns)
    if i < 0:
        return 0
    if i > n - 1:
        return n - 1
    return i
