"""Generalized winding numbers: the solid fill of meshes that are not watertight.

Why
---
Column parity (:mod:`carlaocc.stages.voxelize.kernels`) is exact for closed meshes and wrong for
open ones: a building without a floor, a car with open wheel arches, a scan open at its base
have unpaired crossings, and their interiors come out hollow. The generalized winding number
(Jacobson, Kavan and Sorkine-Hornung 2013)

    w(q) = (1 / 4 pi) * sum over triangles t of Omega_t(q),

the signed solid angles of the triangles seen from ``q``, is 1 inside and 0 outside a closed,
outward-oriented mesh, and degrades gracefully where the mesh has holes: across a hole it
changes smoothly, ~0.5 on the hole itself. A point is *inside* when ``w > 0.5``. Faces must be
consistently oriented (outward); ingest's repair orients them.

Fast evaluation
---------------
As in Barill, Dickson, Schmidt, Levin and Jacobson (2018, "Fast winding numbers for soups and
clouds"): a bounding-volume tree over the triangles, each node holding the area-weighted centroid
``c`` of its triangles, their summed area vector ``A = sum of area_t * n_t`` (outward) and the
radius ``r`` of the ball around ``c`` holding all their vertices. Seen from ``q`` with
``|c - q| > beta * r`` a node contributes its dipole term ``A . (c - q) / |c - q|^3`` (the
first-order far-field expansion of the solid angle); nearer nodes are opened, and leaves are
summed exactly (Van Oosterom and Strackee's formula). ``beta`` = :data:`BETA` bounds the
far-field error of a node to about ``(1 / beta)^2`` of its contribution.

Solid fill of a grid
--------------------
:func:`winding_interior` / :func:`paint_winding_interior` classify voxel centres without asking
for every one. In the window of voxels whose centre lies in the mesh's bounding box (nothing
outside it is filled: an open cup fills at most up to its rim, a flat sheet not at all), the
mesh's surface voxels cut the free voxels into 6-connected components that no triangle crosses,
over each of which ``w`` is continuous:

1. a component enclosed by surface voxels (an interior, a closed pocket of outside) gets
   :data:`_SAMPLES` winding numbers evenly spread over it; when they agree they decide it whole
   -- the interior of a closed or cracked mesh costs a handful of evaluations;
2. a component reaching a face of the window (open to the outside through a hole, as a building
   without a floor or a car through its wheel arches; or cut by the grid or a tile), or whose
   samples disagree, is evaluated coarse to fine: winding numbers on a lattice of every
   :data:`LATTICE`-th voxel, then level by level (step 8, 4, 2) a voxel whose lattice cell has
   corners in its component that agree takes their answer, and only cells whose corners disagree
   -- where ``w`` crosses 0.5 -- get the points of the next finer lattice evaluated.

The surface voxels themselves are the surface kernel's: the solid is ``surface_voxels`` plus
these.

Frames and units: as :mod:`carlaocc.stages.voxelize.kernels` (grid frame, voxel units
``p = (v - origin) / voxel_size``, linear index ``(i * ny + j) * nz + k``); the winding number
itself is invariant under any rigid motion and uniform scale.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from numba import njit, prange

from carlaocc.stages.voxelize.kernels import check_mesh, paint_surface, shape3, to_voxel_units

__all__ = ["WindingTree", "winding_tree", "winding_numbers", "winding_interior", "paint_winding_interior",
           "BETA", "LEAF_SIZE", "INSIDE"]

BETA: float = 3.0
"""Opening criterion: a node is approximated when its centre is farther than ``BETA`` radii."""
LEAF_SIZE: int = 8
"""Triangles per leaf of the tree."""
INSIDE: float = 0.5
"""A point is inside when its winding number exceeds this."""
_QUERY_CHUNK = 256  # queries per parallel work item (one traversal stack each)
_PARALLEL_MIN_QUERIES = 4096


@dataclass(frozen=True)
class WindingTree:
    """A mesh ready for fast winding numbers (arrays in the mesh's own units and frame).

    ``order`` lists triangle ids leaf by leaf; node ``n`` owns ``order[start[n]:end[n]]`` and has
    children ``left[n]``, ``left[n] + 1`` (``left[n] == -1`` for a leaf); node 0 is the root.
    """

    vertices: np.ndarray  # (N, 3) float64
    faces: np.ndarray  # (M, 3) int64 (finite triangles only)
    order: np.ndarray  # (M,) int64
    start: np.ndarray  # (K,) int64
    end: np.ndarray  # (K,) int64
    left: np.ndarray  # (K,) int64
    centre: np.ndarray  # (K, 3) float64, area-weighted centroid of the node's triangles
    area: np.ndarray  # (K, 3) float64, summed area vectors (area * outward unit normal)
    radius: np.ndarray  # (K,) float64, ball around centre holding the node's vertices


# ----------------------------------------------------------------------------------------------
# tree
# ----------------------------------------------------------------------------------------------


@njit(cache=True, nogil=True)
def _build(P, F, leaf_size):
    """Median-split tree over the triangle centroids (longest axis of the centroids' box)."""
    nt = F.shape[0]
    cen = np.empty((nt, 3))
    avec = np.empty((nt, 3))
    amag = np.empty(nt)
    for t in range(nt):
        a, b, c = F[t, 0], F[t, 1], F[t, 2]
        ux, uy, uz = P[b, 0] - P[a, 0], P[b, 1] - P[a, 1], P[b, 2] - P[a, 2]
        vx, vy, vz = P[c, 0] - P[a, 0], P[c, 1] - P[a, 1], P[c, 2] - P[a, 2]
        # area vector = half the cross product (outward for counter-clockwise faces)
        avec[t, 0] = 0.5 * (uy * vz - uz * vy)
        avec[t, 1] = 0.5 * (uz * vx - ux * vz)
        avec[t, 2] = 0.5 * (ux * vy - uy * vx)
        amag[t] = math.sqrt(avec[t, 0] ** 2 + avec[t, 1] ** 2 + avec[t, 2] ** 2)
        for d in range(3):
            cen[t, d] = (P[a, d] + P[b, d] + P[c, d]) / 3.0
    cap = max(2 * nt, 1)
    start = np.zeros(cap, dtype=np.int64)
    end = np.zeros(cap, dtype=np.int64)
    left = np.full(cap, -1, dtype=np.int64)
    order = np.arange(nt)
    start[0], end[0] = 0, nt
    count = 1
    stack = np.empty(cap, dtype=np.int64)
    sp = 0
    stack[sp] = 0
    sp += 1
    # 1. split top-down (children are numbered after their parent)
    while sp > 0:
        sp -= 1
        n = stack[sp]
        s, e = start[n], end[n]
        if e - s <= leaf_size:
            continue
        lo = np.full(3, np.inf)
        hi = np.full(3, -np.inf)
        for x in range(s, e):
            for d in range(3):
                v = cen[order[x], d]
                lo[d] = min(lo[d], v)
                hi[d] = max(hi[d], v)
        axis = int(np.argmax(hi - lo))
        sub = order[s:e].copy()
        keys = np.empty(e - s)
        for x in range(e - s):
            keys[x] = cen[sub[x], axis]
        idx = np.argsort(keys, kind="mergesort")  # stable: the tree does not depend on the sort
        for x in range(e - s):
            order[s + x] = sub[idx[x]]
        mid = (s + e) // 2
        left[n] = count
        start[count], end[count] = s, mid
        start[count + 1], end[count + 1] = mid, e
        stack[sp] = count
        stack[sp + 1] = count + 1
        sp += 2
        count += 2
    # 2. aggregate bottom-up (reverse numbering visits children before parents)
    centre = np.zeros((count, 3))
    area = np.zeros((count, 3))
    weight = np.zeros(count)
    radius = np.zeros(count)
    for n in range(count - 1, -1, -1):
        if left[n] < 0:
            s, e = start[n], end[n]
            for x in range(s, e):
                t = order[x]
                weight[n] += amag[t]
                for d in range(3):
                    area[n, d] += avec[t, d]
            for x in range(s, e):
                t = order[x]
                wt = amag[t] / weight[n] if weight[n] > 0.0 else 1.0 / (e - s)
                for d in range(3):
                    centre[n, d] += wt * cen[t, d]
        else:
            l, q = left[n], left[n] + 1
            weight[n] = weight[l] + weight[q]
            wl = weight[l] / weight[n] if weight[n] > 0.0 else 0.5
            for d in range(3):
                area[n, d] = area[l, d] + area[q, d]
                centre[n, d] = wl * centre[l, d] + (1.0 - wl) * centre[q, d]
    # 3. radii: the exact ball around each node's centre holding its triangles' vertices (a
    #    bound from the children's balls grows with depth and opens far more nodes)
    for n in range(count):
        r = 0.0
        for x in range(start[n], end[n]):
            t = order[x]
            for m in range(3):
                v = F[t, m]
                dd = 0.0
                for d in range(3):
                    dd += (P[v, d] - centre[n, d]) ** 2
                r = max(r, dd)
        radius[n] = math.sqrt(r)
    return order, start[:count].copy(), end[:count].copy(), left[:count].copy(), centre, area, radius


def winding_tree(vertices, faces) -> WindingTree:
    """The tree of a triangle mesh (any units and frame; triangles with a non-finite corner are
    left out). An empty mesh gives a tree whose winding number is 0 everywhere."""
    V, F = check_mesh(vertices, faces)
    if len(F):
        F = F[np.isfinite(V[F].reshape(len(F), -1)).all(axis=1)]
    F = np.ascontiguousarray(F)
    order, start, end, left, centre, area, radius = _build(V, F, LEAF_SIZE)
    return WindingTree(V, F, order, start, end, left, centre, area, radius)


# ----------------------------------------------------------------------------------------------
# evaluation
# ----------------------------------------------------------------------------------------------


@njit(cache=True, nogil=True)
def _solid_angle(P, F, t, qx, qy, qz):
    """Signed solid angle of triangle t seen from q (Van Oosterom and Strackee 1983): positive
    when q is behind the face (on the side its counter-clockwise normal points away from)."""
    a, b, c = F[t, 0], F[t, 1], F[t, 2]
    ax, ay, az = P[a, 0] - qx, P[a, 1] - qy, P[a, 2] - qz
    bx, by, bz = P[b, 0] - qx, P[b, 1] - qy, P[b, 2] - qz
    cx, cy, cz = P[c, 0] - qx, P[c, 1] - qy, P[c, 2] - qz
    la = math.sqrt(ax * ax + ay * ay + az * az)
    lb = math.sqrt(bx * bx + by * by + bz * bz)
    lc = math.sqrt(cx * cx + cy * cy + cz * cz)
    det = ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx)
    den = la * lb * lc + (ax * bx + ay * by + az * bz) * lc + (bx * cx + by * cy + bz * cz) * la \
        + (cx * ax + cy * ay + cz * az) * lb
    return 2.0 * math.atan2(det, den)


@njit(cache=True, nogil=True)
def _winding_one(P, F, order, start, end, left, centre, area, radius, beta, qx, qy, qz, stack):
    """Winding number at q: far nodes by their dipole, near leaves exactly."""
    total = 0.0
    sp = 0
    stack[0] = 0
    sp = 1
    while sp > 0:
        sp -= 1
        n = stack[sp]
        dx, dy, dz = centre[n, 0] - qx, centre[n, 1] - qy, centre[n, 2] - qz
        d2 = dx * dx + dy * dy + dz * dz
        rb = beta * radius[n]
        if d2 > rb * rb:
            # far: dipole term of the node's summed area vector
            total += (area[n, 0] * dx + area[n, 1] * dy + area[n, 2] * dz) / (d2 * math.sqrt(d2))
        elif left[n] < 0:
            # near leaf: exact solid angles
            for x in range(start[n], end[n]):
                total += _solid_angle(P, F, order[x], qx, qy, qz)
        else:
            if sp + 2 > stack.shape[0]:
                # a degenerate (very deep) tree: fall back to the exact sum of the node
                for x in range(start[n], end[n]):
                    total += _solid_angle(P, F, order[x], qx, qy, qz)
                continue
            stack[sp] = left[n]
            stack[sp + 1] = left[n] + 1
            sp += 2
    return total / (4.0 * math.pi)


@njit(cache=True, nogil=True)
def _winding_chunk(P, F, order, start, end, left, centre, area, radius, beta, Q, shift, out, c0, c1):
    stack = np.empty(256, dtype=np.int64)
    for m in range(c0, c1):
        out[m] = _winding_one(P, F, order, start, end, left, centre, area, radius, beta,
                              Q[m, 0] + shift[0], Q[m, 1] + shift[1], Q[m, 2] + shift[2], stack)


@njit(cache=True, nogil=True)
def _winding_serial(P, F, order, start, end, left, centre, area, radius, beta, Q, shift, out):
    _winding_chunk(P, F, order, start, end, left, centre, area, radius, beta, Q, shift, out, 0, Q.shape[0])


@njit(cache=True, nogil=True, parallel=True)
def _winding_parallel(P, F, order, start, end, left, centre, area, radius, beta, Q, shift, out):
    nq = Q.shape[0]
    nchunks = (nq + _QUERY_CHUNK - 1) // _QUERY_CHUNK
    for ch in prange(nchunks):
        _winding_chunk(P, F, order, start, end, left, centre, area, radius, beta, Q, shift, out,
                       ch * _QUERY_CHUNK, min((ch + 1) * _QUERY_CHUNK, nq))


def winding_numbers(tree: WindingTree, points, shift=(0.0, 0.0, 0.0), beta: float = BETA) -> np.ndarray:
    """Winding numbers of the tree's mesh at ``points + shift`` ((Q, 3), the mesh's units and
    frame): float64 (Q,), 1 inside and 0 outside a closed outward mesh.

    ``beta`` (default :data:`BETA`): larger is more exact and slower; ``inf`` sums every triangle
    exactly. Queries beyond a few thousand use numba's threads.
    """
    Q = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.zeros(len(Q))
    if len(Q) == 0 or len(tree.faces) == 0:
        return out
    s = np.asarray(shift, dtype=np.float64).reshape(3)
    args = (tree.vertices, tree.faces, tree.order, tree.start, tree.end, tree.left, tree.centre, tree.area,
            tree.radius, float(beta), Q, s, out)
    if len(Q) >= _PARALLEL_MIN_QUERIES and numba.get_num_threads() > 1:
        _winding_parallel(*args)
    else:
        _winding_serial(*args)
    return out


# ----------------------------------------------------------------------------------------------
# solid fill of a grid
# ----------------------------------------------------------------------------------------------


@njit(cache=True, nogil=True)
def _component_samples(labels, n_labels, k):
    """Up to ``k`` flat indices per component of ``labels`` (1..n_labels; 0 = surface), evenly
    spread over the component's voxels in C order (its first and last among them): (n + 1, k)
    int64, -1 where a component has fewer voxels."""
    counts = np.zeros(n_labels + 1, dtype=np.int64)
    for x in range(labels.shape[0]):
        counts[labels[x]] += 1
    out = np.full((n_labels + 1, k), -1, dtype=np.int64)
    seen = np.zeros(n_labels + 1, dtype=np.int64)
    nxt = np.zeros(n_labels + 1, dtype=np.int64)  # next sample slot per component
    for x in range(labels.shape[0]):
        c = labels[x]
        if c == 0:
            continue
        s = nxt[c]
        if s < k:
            n = counts[c]
            # rank of sample s: s * (n - 1) / (k - 1), or every voxel of a small component
            want = s if n <= k else (s * (n - 1)) // (k - 1)
            if seen[c] == want:
                out[c, s] = x
                nxt[c] = s + 1
        seen[c] += 1
    return out


@njit(cache=True, nogil=True)
def _touches_window(labels, n_labels, ni, nj, nk):
    """Per component: does it reach a face of the (ni, nj, nk) window? uint8, index = label."""
    out = np.zeros(n_labels + 1, dtype=np.uint8)
    for i in range(ni):
        for j in range(nj):
            base = (i * nj + j) * nk
            if i == 0 or i == ni - 1 or j == 0 or j == nj - 1:
                for k in range(nk):
                    out[labels[base + k]] = 1
            else:
                out[labels[base]] = 1
                out[labels[base + nk - 1]] = 1
    return out


def _lattice_points(labels, state, ni, nj, nk, step) -> np.ndarray:
    """Flat indices of the lattice voxels (every ``step``-th along each axis, and the last) that
    belong to components to be evaluated (``state`` 2), in C order."""
    axes = [np.unique(np.r_[0:n:step, n - 1]) for n in (ni, nj, nk)]
    flat = ((axes[0][:, None, None] * nj + axes[1][None, :, None]) * nk + axes[2][None, None, :]).ravel()
    return flat[state[labels[flat]] == 2]


@njit(cache=True, nogil=True)
def _cell_corners(c, n, step):
    """The two lattice coordinates bracketing voxel coordinate c (equal on a lattice plane)."""
    lo = (c // step) * step
    if lo == c:
        return c, c
    hi = min(lo + step, n - 1)
    return lo, hi


@njit(cache=True, nogil=True)
def _refine_level(labels, state, val, ni, nj, nk, step, todo):
    """One level of the coarse-to-fine evaluation of the components to evaluate (``state`` 2):
    each voxel still unknown (``val`` -1) whose cell of the ``step`` lattice has corners in its
    component that all agree takes their answer (``val`` 1 inside, 0 outside); the others lying on
    the lattice of half that step are listed in ``todo`` (returned: their count) to be evaluated.
    At step 2 every voxel is on the finer lattice, so nothing stays unknown after it."""
    half = max(step // 2, 1)
    nt = 0
    for i in range(ni):
        ia, ib = _cell_corners(i, ni, step)
        on_i = i % half == 0 or i == ni - 1
        for j in range(nj):
            ja, jb = _cell_corners(j, nj, step)
            on_ij = on_i and (j % half == 0 or j == nj - 1)
            for k in range(nk):
                x = (i * nj + j) * nk + k
                c = labels[x]
                if state[c] != 2 or val[x] >= 0:
                    continue
                ka, kb = _cell_corners(k, nk, step)
                n_in = 0
                n_out = 0
                for ci in (ia, ib):
                    for cj in (ja, jb):
                        for ck in (ka, kb):
                            y = (ci * nj + cj) * nk + ck
                            if labels[y] == c:
                                if val[y] == 1:
                                    n_in += 1
                                elif val[y] == 0:
                                    n_out += 1
                if n_in > 0 and n_out == 0:
                    val[x] = 1
                elif n_out > 0 and n_in == 0:
                    val[x] = 0
                elif on_ij and (k % half == 0 or k == nk - 1):
                    todo[nt] = x
                    nt += 1
    return nt


@njit(cache=True, nogil=True)
def _window_indices(labels, state, mask, nj, nk, i0, j0, k0, ny, nz):
    """Sorted grid linear indices of the window's inside voxels: components decided inside
    (``state`` 1) and evaluated voxels marked in ``mask``."""
    n = labels.shape[0]
    cnt = 0
    for x in range(n):
        if state[labels[x]] == 1 or mask[x] == 1:
            cnt += 1
    out = np.empty(cnt, dtype=np.int64)
    w = 0
    for x in range(n):
        if state[labels[x]] == 1 or mask[x] == 1:
            i = i0 + x // (nj * nk)
            j = j0 + (x // nk) % nj
            k = k0 + x % nk
            out[w] = (i * ny + j) * nz + k
            w += 1
    return out


@njit(cache=True, nogil=True)
def _centres(flat, nj, nk, i0, j0, k0):
    """Voxel-unit centres of flat window indices (window origin at voxel (i0, j0, k0))."""
    Q = np.empty((flat.shape[0], 3))
    for m in range(flat.shape[0]):
        x = flat[m]
        Q[m, 0] = i0 + x // (nj * nk) + 0.5
        Q[m, 1] = j0 + (x // nk) % nj + 0.5
        Q[m, 2] = k0 + x % nk + 0.5
    return Q


_SAMPLES = 8  # winding numbers asked per free-space component
LATTICE: int = 8
"""Stride (voxels) of the coarse lattice on which components open to the window are evaluated."""


def _window_range(lo: float, hi: float, n: int) -> tuple[int, int]:
    """Voxel indices [c0, c1] of the centres c + 0.5 in [lo, hi] (voxel units), clipped to [0, n)."""
    lo, hi = min(max(lo, -2.0), n + 2.0), min(max(hi, -2.0), n + 2.0)
    return max(math.ceil(lo - 0.5), 0), min(math.floor(hi - 0.5), n - 1)


def _classify(P: np.ndarray, F: np.ndarray, shape, tree: WindingTree | None, shift) -> np.ndarray:
    """Sorted C-order linear indices of the grid voxels (voxel units ``P``; ``shape``) whose centre
    has a winding number above :data:`INSIDE`. ``tree`` (built on ``P + shift``) and ``shift``
    let a caller build the tree once and classify tile after tile."""
    nx, ny, nz = shape3(shape)
    fin = P[np.isfinite(P).all(axis=1)]
    if len(fin) == 0:
        return np.zeros(0, dtype=np.int64)
    lo, hi = fin.min(axis=0), fin.max(axis=0)
    # 1. the window: voxels whose centre lies in the mesh's bounding box (nothing outside fills)
    (i0, i1), (j0, j1), (k0, k1) = (_window_range(lo[a], hi[a], n) for a, n in enumerate((nx, ny, nz)))
    if i0 > i1 or j0 > j1 or k0 > k1:
        return np.zeros(0, dtype=np.int64)
    ni, nj, nk = i1 - i0 + 1, j1 - j0 + 1, k1 - k0 + 1
    if tree is None:
        tree = winding_tree(P, F)
        shift = (0.0, 0.0, 0.0)
    # 2. the mesh's surface voxels in the window; the free voxels' 6-connected components, which
    #    no triangle crosses: the winding number is continuous over each
    surface = np.zeros(ni * nj * nk, dtype=np.uint8)
    paint_surface(P - np.array([i0, j0, k0], dtype=np.float64), F, (ni, nj, nk), surface, None, 1, 0)
    from scipy import ndimage  # imported here: a run that fills no open mesh does not need scipy

    labels, n_labels = ndimage.label(surface.reshape(ni, nj, nk) == 0)
    labels = labels.reshape(-1)
    # 3. a few winding numbers per component, evenly spread over it: agreeing samples decide the
    #    component whole (an interior, a closed pocket of outside); disagreeing ones mark it for
    #    evaluation
    samples = _component_samples(labels, n_labels, _SAMPLES)
    used = samples >= 0
    w = np.zeros(samples.shape)
    w[used] = winding_numbers(tree, _centres(samples[used], nj, nk, i0, j0, k0), shift)
    above = (w > INSIDE) & used
    state = np.where(above.sum(axis=1) == used.sum(axis=1), 1, np.where(above.any(axis=1), 2, 0)).astype(np.int8)
    # so are the components reaching a face of the window: open to the outside through a hole
    # there (a building without a floor), or cut by the grid or a tile (whose other part may be)
    state[(_touches_window(labels, n_labels, ni, nj, nk) == 1) & (state != 2)] = 2
    state[0] = 0  # the surface itself is painted by the surface kernel
    # 4. evaluated components, coarse to fine: winding numbers on a lattice of every LATTICE-th
    #    voxel; level by level (step 8, 4, 2), a voxel whose lattice cell has corners in its
    #    component that agree takes their answer, and the cells whose corners disagree (where w
    #    crosses 0.5) get the points of the lattice of half the step evaluated
    val = np.full(len(labels), -1, dtype=np.int8)
    if (state == 2).any():
        pts = _lattice_points(labels, state, ni, nj, nk, LATTICE)
        val[pts] = winding_numbers(tree, _centres(pts, nj, nk, i0, j0, k0), shift) > INSIDE
        todo = np.empty(len(labels), dtype=np.int64)
        step = LATTICE
        while step >= 2:
            nt = _refine_level(labels, state, val, ni, nj, nk, step, todo)
            val[todo[:nt]] = winding_numbers(tree, _centres(todo[:nt], nj, nk, i0, j0, k0), shift) > INSIDE
            step //= 2
    mask = (val == 1).view(np.uint8)
    return _window_indices(labels, state, mask, nj, nk, i0, j0, k0, ny, nz)


def winding_interior(vertices, faces, origin, voxel_size: float, shape) -> np.ndarray:
    """Sorted C-order linear indices of the voxels not touched by the mesh's surface (not in
    :func:`~carlaocc.stages.voxelize.kernels.surface_voxels`) whose centre has a generalized winding
    number above :data:`INSIDE` (0.5), within the mesh's bounding box (nothing outside it is filled).

    The solid a voxelizer writes is ``surface_voxels`` united with these. For a watertight mesh,
    ``surface_voxels | winding_interior == surface_voxels | fill_interior`` (column parity,
    :func:`~carlaocc.stages.voxelize.kernels.fill_interior`).

    ``vertices`` (N, 3) metres in the grid frame, ``faces`` (M, 3) consistently oriented (outward);
    ``origin`` (3,) metres, ``voxel_size`` metres and ``shape`` (3,) voxels the grid, as in
    ``fill_interior``. The winding numbers are asked component by component of the free voxels
    (6-connected, cut by the surface voxels): a component enclosed by surface voxels is decided by
    8 evenly spread samples (so its voxels are all inside or all outside); one reaching a
    window face (the bounding box's, or where the grid or a tile cuts the mesh), or whose samples
    disagree, is evaluated on a lattice of every :data:`LATTICE`-th voxel, cells whose corners (in
    the same component) disagree being evaluated down to voxel by voxel.
    """
    V, F = check_mesh(vertices, faces)
    if len(F) == 0:
        return np.zeros(0, dtype=np.int64)
    P = to_voxel_units(V, origin, voxel_size)
    return _classify(P, F, shape, None, None)


def paint_winding_interior(P, faces, shape, out_a, out_b, val_a, val_b, tree: WindingTree | None = None,
                           shift=(0.0, 0.0, 0.0)) -> None:
    """Write ``val_a``/``val_b`` into flat ``out_a``/``out_b`` at the voxels whose centre has a
    winding number above 0.5, for the mesh in voxel units ``P``. ``tree`` may be the tree of
    ``P + shift`` (a tile's voxel units plus the tile's offset), built once per mesh."""
    P, F = check_mesh(P, faces)
    if len(F) == 0:
        return
    idx = _classify(P, F, shape, tree, shift)
    out_a[idx] = val_a
    out_b[idx] = val_b


def warmup() -> None:
    """Compile (or load from numba's cache) the tree, the evaluators and the fill on a small
    open box."""
    V = np.array([[0, 0, 0], [2, 0, 0], [2, 2, 0], [0, 2, 0], [0, 0, 2], [2, 0, 2], [2, 2, 2], [0, 2, 2]], float)
    F = np.array([[4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6],
                  [3, 0, 4], [3, 4, 7]], dtype=np.int64)
    winding_interior(V, F, (0.0, 0.0, 0.0), 0.5, (4, 4, 4))
    tree = winding_tree(V, F)
    for kernel in (_winding_serial, _winding_parallel):
        kernel(tree.vertices, tree.faces, tree.order, tree.start, tree.end, tree.left, tree.centre, tree.area,
               tree.radius, BETA, np.zeros((1, 3)), np.zeros(3), np.zeros(1))
