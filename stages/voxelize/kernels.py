"""Numba kernels of the voxelizer: exact triangle/box surface voxels and column-parity solid fill.

Frames and units
----------------
Inputs are a triangle mesh in the grid's frame (LiDAR frame, metres) and a grid given by its
``origin`` (minimum corner of voxel (0, 0, 0), metres), cubic ``voxel_size`` (metres) and
``shape = (nx, ny, nz)``. Voxel ``(i, j, k)`` covers the closed box
``[origin + (i, j, k) * voxel_size, origin + (i + 1, j + 1, k + 1) * voxel_size]`` and has the
C-order linear index ``(i * ny + j) * nz + k`` (z fastest).

Every kernel first maps the vertices to *voxel units*, ``p = (v - origin) / voxel_size``, in which
voxel ``(i, j, k)`` is the unit box ``[i, i+1] x [j, j+1] x [k, k+1]`` and its centre is
``(i, j, k) + 0.5``. The tests below are exact in that frame up to the float64 rounding of the
products they form (no rounding at all for dyadic coordinates, which the tests exploit).

Surface algorithm
-----------------
Per triangle: clip its voxel bounding range to the grid (cull when empty); pick the sweep frame
(u, v, w) whose w is the dominant axis of the normal; for each (u, v) column of the range, reject
the column by the five axes that ignore w, then test only the few voxels along w that the
triangle's plane reaches over the column's cross-section (|slope| <= 1 per axis, so 1-4 of them)
with the remaining eight axes. The per-column halves of the projections are hoisted without
changing any rounding, so the result is bit-identical to the plain per-voxel test
:func:`tri_box_overlap`. Work is proportional to the triangle's area in voxels, not to its
bounding box.

Conventions (each is tested)
----------------------------
* Surface: a voxel is marked when its **closed** box intersects a triangle (separating-axis test of
  Akenine-Moeller: 3 box axes, the triangle normal, 9 edge x axis cross products). A triangle lying
  exactly on a voxel face therefore marks the voxels on both sides of it.
* Degenerate triangles are **kept**: a zero-area triangle (a segment or a point) marks exactly the
  voxels its segment / point touches (the same 13 axes contain the segment/box separating axes).
* Triangles with a non-finite coordinate are dropped (so are those beyond ~1e150 voxels, whose
  cross products overflow).
* Fill: a voxel is inside when its **centre** is inside the closed mesh, decided by the parity of
  the crossings of the vertical line through the centre. A centre exactly on an xy edge of a
  triangle's projection is resolved by symbolic perturbation of the column to
  ``(x - eps^2, y + eps)``, computed per undirected edge in one canonical vertex order, so the
  two triangles that share an edge always agree and a crossing is counted once. Along z, a centre
  is inside the crossing pair ``(z0, z1)`` when ``z0 <= zc < z1``. An unpaired last crossing
  (an open mesh) is ignored.

Parallelism
-----------
Only the surface sweep (meshes of ``PARALLEL_MIN_TRIANGLES`` triangles or more) and the mask
extraction of big grids use numba's threads (``prange``; ``numba.set_num_threads`` per calling
thread, e.g. 1 inside Dask workers that already fill the cores). The triangles are dealt out in
interleaved stripes of small chunks, so each thread samples the whole mesh whatever the threading
layer's schedule. Concurrent writes of two threads to one voxel store the same value, so the race
is benign. Everything else runs in the calling thread; all kernels release the GIL (``nogil``).
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import njit, prange

__all__ = [
    "surface_voxels",
    "tri_box_overlap",
    "fill_interior",
    "to_voxel_units",
    "paint_surface",
    "paint_interior",
    "shape3",
    "check_mesh",
]

# Slack (voxel units) widening every candidate range (bounding ranges, per-column plane ranges,
# column-centre ranges) before the exact tests, so float rounding of a range can only add
# candidates, never lose one.
_RANGE_SLACK = 1e-6
# Triangles per chunk, and interleaved stripes of chunks, of the parallel surface loop.
_CHUNK = 64
_STRIPES = 64
# uint64 words per block of the mask extraction (64 KiB).
_BLOCK_WORDS = 8192
# Below these sizes the kernels run in the calling thread (see _use_threads).
PARALLEL_MIN_TRIANGLES = 20_000
PARALLEL_MIN_VOXELS = 16_000_000


# ----------------------------------------------------------------------------------------------
# small helpers
# ----------------------------------------------------------------------------------------------


@njit(cache=True, nogil=True)
def _min3(a, b, c):
    return min(a, min(b, c))


@njit(cache=True, nogil=True)
def _max3(a, b, c):
    return max(a, max(b, c))


@njit(cache=True, nogil=True)
def _separated(p0, p1, p2, r):
    """True when the projections p0..p2 of the triangle miss the box's projection [-r, r]."""
    return _min3(p0, p1, p2) > r or _max3(p0, p1, p2) < -r


@njit(cache=True, nogil=True)
def _touch_range(lo, hi, n):
    """Indices k in [0, n) of the closed unit intervals [k, k+1] touching [lo, hi] (voxel units).

    Returns (k0, k1), empty when k0 > k1. Clamps in float first so huge or infinite bounds do not
    overflow the integer conversion.
    """
    # [k, k+1] touches [lo, hi]  <=>  k >= lo - 1 and k <= hi; widened by the slack so the range
    # is a superset of what the exact test (which rounds centre-relative coordinates) accepts
    lo = min(max(lo - _RANGE_SLACK, -2.0), n + 2.0)
    hi = min(max(hi + _RANGE_SLACK, -2.0), n + 2.0)
    k0 = max(int(math.ceil(lo)) - 1, 0)
    k1 = min(int(math.floor(hi)), n - 1)
    return k0, k1


# --- the separating-axis test in a triangle's sweep frame ------------------------------------
# Every triangle is tested in the cyclic axis order (u, v, w) whose last axis w is the dominant
# axis of its normal (x wins ties, then y): (y, z, x), (z, x, y) or (x, y, z). Cyclic relabelling
# keeps every cross product, so this is the plain 13-axis test; fixing the frame (and the order
# of every sum in it) is what lets the sweep below hoist the per-column parts of each projection
# and still produce bit-for-bit the result of the per-voxel test (and of the numpy reference).


@njit(cache=True, nogil=True)
def _sweep_axis(nx, ny, nz):
    """Dominant axis of the normal: 0 (x), 1 (y) or 2 (z); x wins ties, then y."""
    ax_, ay_, az_ = abs(nx), abs(ny), abs(nz)
    if ax_ >= ay_ and ax_ >= az_:
        return 0
    if ay_ >= az_:
        return 1
    return 2


@njit(cache=True, nogil=True)
def _to_uvw(d, x, y, z):
    """(x, y, z) -> (u, v, w), w along axis d, cyclic order."""
    if d == 0:
        return y, z, x
    if d == 1:
        return z, x, y
    return x, y, z


@njit(cache=True, nogil=True)
def _from_uvw(d, u, v, w):
    """(u, v, w) -> (x, y, z), inverse of :func:`_to_uvw`."""
    if d == 0:
        return w, u, v
    if d == 1:
        return v, w, u
    return u, v, w


@njit(cache=True, nogil=True)
def tri_box_overlap(ax, ay, az, bx, by, bz, cx, cy, cz, i, j, k):
    """Closed-box/triangle separating-axis test (Akenine-Moeller 2001), voxel units.

    Triangle (a, b, c) against the unit box of voxel (i, j, k): centre (i, j, k) + 0.5,
    half-extent 0.5. True when no axis separates them (touching counts as overlap). 13 axes: the 3
    box face normals, the triangle normal, the 9 cross products edge x box axis.

    Robustness: edges and normal come from the absolute vertices (the same for every voxel,
    hence translation-consistent), and every vertex is projected on every axis: disjoint
    projections on *any* axis prove separation, so a noisy normal (a near-collinear sliver) can
    never reject a box the triangle touches; a zero-area triangle (zero normal) reduces to the
    exact segment/point-box test.
    """
    # edges and normal from the absolute vertices; the sweep frame
    nx = (by - ay) * (cz - bz) - (bz - az) * (cy - by)
    ny = (bz - az) * (cx - bx) - (bx - ax) * (cz - bz)
    nz = (bx - ax) * (cy - by) - (by - ay) * (cx - bx)
    d = _sweep_axis(nx, ny, nz)
    au, av, aw = _to_uvw(d, ax, ay, az)
    bu, bv, bw = _to_uvw(d, bx, by, bz)
    cu, cv, cw = _to_uvw(d, cx, cy, cz)
    iu, iv, iw = _to_uvw(d, i, j, k)
    return _sat_uvw(au, av, aw, bu, bv, bw, cu, cv, cw, iu, iv, iw)


@njit(cache=True, nogil=True)
def _sat_uvw(au, av, aw, bu, bv, bw, cu, cv, cw, iu, iv, iw):
    """The 13-axis test in the sweep frame (same arithmetic as the hoisted sweep)."""
    # edges e0 = b - a, e1 = c - b, e2 = a - c and the normal e0 x e1
    eu0, ev0, ew0 = bu - au, bv - av, bw - aw
    eu1, ev1, ew1 = cu - bu, cv - bv, cw - bw
    eu2, ev2, ew2 = au - cu, av - cv, aw - cw
    nu = ev0 * ew1 - ew0 * ev1
    nv = ew0 * eu1 - eu0 * ew1
    nw = eu0 * ev1 - ev0 * eu1
    # vertices relative to the box centre
    ou, ov, ow = iu + 0.5, iv + 0.5, iw + 0.5
    u0, v0, w0 = au - ou, av - ov, aw - ow
    u1, v1, w1 = bu - ou, bv - ov, bw - ow
    u2, v2, w2 = cu - ou, cv - ov, cw - ow
    # box axes
    if _separated(u0, u1, u2, 0.5) or _separated(v0, v1, v2, 0.5) or _separated(w0, w1, w2, 0.5):
        return False
    # triangle normal
    if _separated(nu * u0 + nv * v0 + nw * w0, nu * u1 + nv * v1 + nw * w1, nu * u2 + nv * v2 + nw * w2,
                  0.5 * (abs(nu) + abs(nv) + abs(nw))):
        return False
    for m in range(3):
        if m == 0:
            eu, ev, ew = eu0, ev0, ew0
        elif m == 1:
            eu, ev, ew = eu1, ev1, ew1
        else:
            eu, ev, ew = eu2, ev2, ew2
        # W x e = (-ev, eu, 0)
        if _separated(-ev * u0 + eu * v0, -ev * u1 + eu * v1, -ev * u2 + eu * v2, 0.5 * (abs(ev) + abs(eu))):
            return False
        # U x e = (0, -ew, ev)
        if _separated(-ew * v0 + ev * w0, -ew * v1 + ev * w1, -ew * v2 + ev * w2, 0.5 * (abs(ew) + abs(ev))):
            return False
        # V x e = (ew, 0, -eu)
        if _separated(ew * u0 - eu * w0, ew * u1 - eu * w1, ew * u2 - eu * w2, 0.5 * (abs(ew) + abs(eu))):
            return False
    return True


# ----------------------------------------------------------------------------------------------
# surface
# ----------------------------------------------------------------------------------------------


@njit(cache=True, nogil=True)
def _surface_triangle(P, faces, t, nx, ny, nz, out_a, out_b, val_a, val_b, write_b, x0):
    """Write (val_a, val_b) into every voxel the closed box of which meets triangle t, its
    vertices ``P`` shifted by ``-x0`` along x (the same subtraction as shifting ``P`` first)."""
    a = faces[t, 0]
    b = faces[t, 1]
    c = faces[t, 2]
    ax, ay, az = P[a, 0] - x0, P[a, 1], P[a, 2]
    bx, by, bz = P[b, 0] - x0, P[b, 1], P[b, 2]
    cx, cy, cz = P[c, 0] - x0, P[c, 1], P[c, 2]
    # drop triangles with a NaN/inf coordinate
    if not math.isfinite(ax + ay + az + bx + by + bz + cx + cy + cz):
        return
    # clipped voxel bounding range of the triangle; culled when it misses the grid
    i0, i1 = _touch_range(_min3(ax, bx, cx), _max3(ax, bx, cx), nx)
    j0, j1 = _touch_range(_min3(ay, by, cy), _max3(ay, by, cy), ny)
    k0, k1 = _touch_range(_min3(az, bz, cz), _max3(az, bz, cz), nz)
    if i0 > i1 or j0 > j1 or k0 > k1:
        return
    # sweep frame (u, v, w): w along the dominant normal axis (see tri_box_overlap)
    nrx = (by - ay) * (cz - bz) - (bz - az) * (cy - by)
    nry = (bz - az) * (cx - bx) - (bx - ax) * (cz - bz)
    nrz = (bx - ax) * (cy - by) - (by - ay) * (cx - bx)
    if not math.isfinite(nrx + nry + nrz):
        return  # products overflow: coordinates beyond ~1e150 voxels are not supported
    d = _sweep_axis(nrx, nry, nrz)
    au, av, aw = _to_uvw(d, ax, ay, az)
    bu, bv, bw = _to_uvw(d, bx, by, bz)
    cu, cv, cw = _to_uvw(d, cx, cy, cz)
    ru0, rv0, rw0 = _to_uvw(d, i0, j0, k0)
    ru1, rv1, rw1 = _to_uvw(d, i1, j1, k1)
    # per-triangle constants of the test: edges, normal, radii
    eu0, ev0, ew0 = bu - au, bv - av, bw - aw
    eu1, ev1, ew1 = cu - bu, cv - bv, cw - bw
    eu2, ev2, ew2 = au - cu, av - cv, aw - cw
    nu = ev0 * ew1 - ew0 * ev1
    nv = ew0 * eu1 - eu0 * ew1
    nw = eu0 * ev1 - ev0 * eu1
    rn = 0.5 * (abs(nu) + abs(nv) + abs(nw))
    rw0_, rw1_, rw2_ = 0.5 * (abs(ev0) + abs(eu0)), 0.5 * (abs(ev1) + abs(eu1)), 0.5 * (abs(ev2) + abs(eu2))
    ru0_, ru1_, ru2_ = 0.5 * (abs(ew0) + abs(ev0)), 0.5 * (abs(ew1) + abs(ev1)), 0.5 * (abs(ew2) + abs(ev2))
    rv0_, rv1_, rv2_ = 0.5 * (abs(ew0) + abs(eu0)), 0.5 * (abs(ew1) + abs(eu1)), 0.5 * (abs(ew2) + abs(eu2))
    degenerate = nu == 0.0 and nv == 0.0 and nw == 0.0
    if not degenerate:
        # plane through a: w = aw + g (u - au) + q (v - av). The test accepts boxes meeting the slab
        # between the planes through the lowest and highest vertex projections on n (one plane
        # up to rounding, except for slivers), so widen by that slab: [t_lo, t_hi]
        g = -nu / nw
        q = -nv / nw
        g_lo, g_hi = min(g, 0.0), max(g, 0.0)
        q_lo, q_hi = min(q, 0.0), max(q, 0.0)
        sa = nu * au + nv * av + nw * aw
        sb = nu * bu + nv * bv + nw * bw
        sc = nu * cu + nv * cv + nw * cw
        t_lo = (_min3(sa, sb, sc) - sa) / nw
        t_hi = (_max3(sa, sb, sc) - sa) / nw
        if t_lo > t_hi:
            t_lo, t_hi = t_hi, t_lo
    for iu in range(ru0, ru1 + 1):
        ou = iu + 0.5
        u0, u1, u2 = au - ou, bu - ou, cu - ou
        # 1. box axis u
        if _separated(u0, u1, u2, 0.5):
            continue
        for iv in range(rv0, rv1 + 1):
            ov = iv + 0.5
            v0, v1, v2 = av - ov, bv - ov, cv - ov
            # 2. the column's axes: box axis v and the three W x e (they ignore w)
            if _separated(v0, v1, v2, 0.5):
                continue
            if _separated(-ev0 * u0 + eu0 * v0, -ev0 * u1 + eu0 * v1, -ev0 * u2 + eu0 * v2, rw0_):
                continue
            if _separated(-ev1 * u0 + eu1 * v0, -ev1 * u1 + eu1 * v1, -ev1 * u2 + eu1 * v2, rw1_):
                continue
            if _separated(-ev2 * u0 + eu2 * v0, -ev2 * u1 + eu2 * v1, -ev2 * u2 + eu2 * v2, rw2_):
                continue
            # 3. the voxels along w the plane reaches over the column's cross-section
            if degenerate:
                kw0, kw1 = rw0, rw1
            else:
                base = aw + g * (iu - au) + q * (iv - av)
                kw0, kw1 = _touch_range(base + g_lo + q_lo + t_lo, base + g_hi + q_hi + t_hi, 1 << 40)
                kw0 = max(kw0, rw0)
                kw1 = min(kw1, rw1)
            if kw0 > kw1:
                continue
            # the w-independent halves of the remaining projections (same operation order as
            # the full test: hoisting a term does not change any rounding)
            pn0, pn1, pn2 = nu * u0 + nv * v0, nu * u1 + nv * v1, nu * u2 + nv * v2
            pu00, pu01, pu02 = -ew0 * v0, -ew0 * v1, -ew0 * v2
            pu10, pu11, pu12 = -ew1 * v0, -ew1 * v1, -ew1 * v2
            pu20, pu21, pu22 = -ew2 * v0, -ew2 * v1, -ew2 * v2
            pv00, pv01, pv02 = ew0 * u0, ew0 * u1, ew0 * u2
            pv10, pv11, pv12 = ew1 * u0, ew1 * u1, ew1 * u2
            pv20, pv21, pv22 = ew2 * u0, ew2 * u1, ew2 * u2
            for iw in range(kw0, kw1 + 1):
                ow = iw + 0.5
                w0, w1, w2 = aw - ow, bw - ow, cw - ow
                # 4. box axis w, the normal, U x e and V x e for this voxel
                if _separated(w0, w1, w2, 0.5):
                    continue
                if _separated(pn0 + nw * w0, pn1 + nw * w1, pn2 + nw * w2, rn):
                    continue
                if _separated(pu00 + ev0 * w0, pu01 + ev0 * w1, pu02 + ev0 * w2, ru0_):
                    continue
                if _separated(pu10 + ev1 * w0, pu11 + ev1 * w1, pu12 + ev1 * w2, ru1_):
                    continue
                if _separated(pu20 + ev2 * w0, pu21 + ev2 * w1, pu22 + ev2 * w2, ru2_):
                    continue
                if _separated(pv00 - eu0 * w0, pv01 - eu0 * w1, pv02 - eu0 * w2, rv0_):
                    continue
                if _separated(pv10 - eu1 * w0, pv11 - eu1 * w1, pv12 - eu1 * w2, rv1_):
                    continue
                if _separated(pv20 - eu2 * w0, pv21 - eu2 * w1, pv22 - eu2 * w2, rv2_):
                    continue
                i, j, k = _from_uvw(d, iu, iv, iw)
                lin = (i * ny + j) * nz + k
                out_a[lin] = val_a
                if write_b:
                    out_b[lin] = val_b


@njit(cache=True, nogil=True)
def _surface_paint_serial(P, faces, nx, ny, nz, out_a, out_b, val_a, val_b, write_b, x0):
    """Paint every surface voxel of every triangle, in the calling thread."""
    for t in range(faces.shape[0]):
        _surface_triangle(P, faces, t, nx, ny, nz, out_a, out_b, val_a, val_b, write_b, x0)


@njit(parallel=True, cache=True, nogil=True)
def _surface_paint_parallel(P, faces, nx, ny, nz, out_a, out_b, val_a, val_b, write_b, x0):
    """Paint every surface voxel of every triangle, triangles spread over numba's threads."""
    nt = faces.shape[0]
    nchunks = (nt + _CHUNK - 1) // _CHUNK
    # load balance whatever the threading layer's schedule: the parallel loop runs over _STRIPES
    # stripes, stripe s taking the chunks s, s + _STRIPES, ... of _CHUNK consecutive triangles,
    # so every thread's share samples the whole mesh (big and small triangles alike)
    for s in prange(_STRIPES):
        for ch in range(s, nchunks, _STRIPES):
            for t in range(ch * _CHUNK, min((ch + 1) * _CHUNK, nt)):
                _surface_triangle(P, faces, t, nx, ny, nz, out_a, out_b, val_a, val_b, write_b, x0)


@njit(cache=True, nogil=True)
def _touched_blocks(P, faces, nx, slab_len, block_bytes):
    """Flags of the mask blocks (block_bytes each) that some triangle's clipped x range reaches."""
    nt = faces.shape[0]
    nblocks = (nx * slab_len + block_bytes - 1) // block_bytes
    flags = np.zeros(nblocks, dtype=np.uint8)
    for t in range(nt):
        a = faces[t, 0]
        b = faces[t, 1]
        c = faces[t, 2]
        xa, xb, xc = P[a, 0], P[b, 0], P[c, 0]
        if not math.isfinite(xa + xb + xc):
            continue
        i0, i1 = _touch_range(_min3(xa, xb, xc), _max3(xa, xb, xc), nx)
        if i0 > i1:
            continue
        # x slabs [i0, i1] are bytes [i0 * slab_len, (i1 + 1) * slab_len)
        for blk in range((i0 * slab_len) // block_bytes, ((i1 + 1) * slab_len - 1) // block_bytes + 1):
            flags[blk] = 1
    return flags


@njit(cache=True, nogil=True)
def _block_count(words, blk, block_words):
    """Non-zero bytes of mask block blk (bytes are 0/1, so a word's byte sum is its count)."""
    c = 0
    for w in range(blk * block_words, min((blk + 1) * block_words, words.shape[0])):
        x = words[w]
        if x != 0:
            c += np.int64((x * np.uint64(0x0101010101010101)) >> np.uint64(56))
    return c


@njit(cache=True, nogil=True)
def _block_write(mask, words, blk, block_words, out, o):
    """Write the byte indices of the non-zero bytes of block blk into out[o:], ascending."""
    for w in range(blk * block_words, min((blk + 1) * block_words, words.shape[0])):
        if words[w] != 0:
            for byte in range(8 * w, 8 * w + 8):
                if mask[byte] != 0:
                    out[o] = byte
                    o += 1


@njit(cache=True, nogil=True)
def _mask_to_indices_serial(mask, words, flags, block_words):
    """Sorted linear indices of the non-zero bytes of ``mask`` (0/1 bytes), scanning 8 bytes at a
    time (``words`` is the uint64 view of the zero-padded mask) and only the flagged blocks."""
    nb = flags.shape[0]
    # pass 1: count per block, prefix sum -> output offsets
    counts = np.zeros(nb + 1, dtype=np.int64)
    for blk in range(nb):
        counts[blk + 1] = counts[blk] + (_block_count(words, blk, block_words) if flags[blk] else 0)
    out = np.empty(counts[nb], dtype=np.int64)
    # pass 2: each block's indices at its offset (blocks ascend -> sorted output)
    for blk in range(nb):
        if flags[blk]:
            _block_write(mask, words, blk, block_words, out, counts[blk])
    return out


@njit(parallel=True, cache=True, nogil=True)
def _mask_to_indices_parallel(mask, words, flags, block_words):
    """:func:`_mask_to_indices_serial` with the blocks spread over numba's threads."""
    nb = flags.shape[0]
    counts = np.zeros(nb + 1, dtype=np.int64)
    for blk in prange(nb):
        if flags[blk]:
            counts[blk + 1] = _block_count(words, blk, block_words)
    for blk in range(nb):
        counts[blk + 1] += counts[blk]
    out = np.empty(counts[nb], dtype=np.int64)
    for blk in prange(nb):
        if flags[blk]:
            _block_write(mask, words, blk, block_words, out, counts[blk])
    return out


# ----------------------------------------------------------------------------------------------
# solid fill (column parity)
# ----------------------------------------------------------------------------------------------


@njit(cache=True, nogil=True)
def _edge_side(px, py, qx, qy, x, y):
    """Side of the column (x, y) w.r.t. the directed xy edge p -> q, with its edge function.

    Returns (s, e): e = cross(q - p, (x, y) - p) evaluated in one canonical order of the
    endpoints (lexicographically smaller first, then negated if p -> q runs the other way), so the
    two triangles sharing an edge get exactly opposite values; s = sign(e), or for e == 0 the
    sign at the perturbed column (x - eps^2, y + eps): sign(dx), else sign(dy); 0 for a
    zero-length edge.
    """
    if px < qx or (px == qx and py < qy):
        e = (qx - px) * (y - py) - (qy - py) * (x - px)
    else:
        e = -((px - qx) * (y - qy) - (py - qy) * (x - qx))
    if e > 0.0:
        return 1, e
    if e < 0.0:
        return -1, e
    dx = qx - px
    dy = qy - py
    if dx > 0.0:
        return 1, e
    if dx < 0.0:
        return -1, e
    if dy > 0.0:
        return 1, e
    if dy < 0.0:
        return -1, e
    return 0, e


@njit(cache=True, nogil=True)
def _column_crossing(ax, ay, az, bx, by, bz, cx, cy, cz, x, y):
    """(hit, z): does the vertical line through (x, y) cross triangle abc, and at which z."""
    sa, wa = _edge_side(bx, by, cx, cy, x, y)  # edge opposite a
    sb, wb = _edge_side(cx, cy, ax, ay, x, y)  # edge opposite b
    sc, wc = _edge_side(ax, ay, bx, by, x, y)  # edge opposite c
    # inside (either winding) iff the three sides agree and none is degenerate
    if sa == 0 or sa != sb or sa != sc:
        return False, 0.0
    # barycentric height: weights are the edge functions, all of one sign
    wsum = wa + wb + wc
    if wsum == 0.0:
        return True, (az + bz + cz) / 3.0
    return True, (wa * az + wb * bz + wc * cz) / wsum


@njit(cache=True, nogil=True)
def _centre_range(lo, hi, n):
    """Column indices c in [0, n) with centre c + 0.5 in [lo, hi] (voxel units), widened by the
    slack: a superset, the edge functions decide (so both triangles of an edge see the column)."""
    lo = min(max(lo - _RANGE_SLACK, -2.0), n + 2.0)
    hi = min(max(hi + _RANGE_SLACK, -2.0), n + 2.0)
    c0 = max(int(math.ceil(lo - 0.5)), 0)
    c1 = min(int(math.floor(hi - 0.5)), n - 1)
    return c0, c1


@njit(cache=True, nogil=True)
def _triangle_columns(P, faces, t, i0, i1, j0, j1):
    """Window columns [ci0, ci1] x [cj0, cj1] whose centres the xy bounding box of triangle t
    may contain (a superset; empty when ci0 > ci1 or cj0 > cj1, or for a non-finite triangle)."""
    a = faces[t, 0]
    b = faces[t, 1]
    c = faces[t, 2]
    ax, ay = P[a, 0], P[a, 1]
    bx, by = P[b, 0], P[b, 1]
    cx, cy = P[c, 0], P[c, 1]
    if not math.isfinite(ax + ay + bx + by + cx + cy + P[a, 2] + P[b, 2] + P[c, 2]):
        return 0, -1, 0, -1
    ci0, ci1 = _centre_range(_min3(ax, bx, cx), _max3(ax, bx, cx), i1 + 1)
    cj0, cj1 = _centre_range(_min3(ay, by, cy), _max3(ay, by, cy), j1 + 1)
    return max(ci0, i0), ci1, max(cj0, j0), cj1


@njit(cache=True, nogil=True)
def _triangle_crossings(P, faces, t, i0, j0, nj, ci0, ci1, cj0, cj1, col, zs, w):
    """Store from offset w, one slot per column of [ci0, ci1] x [cj0, cj1], the crossing of
    triangle t with that column's centre line: (window column index, z), or column -1 (none)."""
    a = faces[t, 0]
    b = faces[t, 1]
    c = faces[t, 2]
    ax, ay, az = P[a, 0], P[a, 1], P[a, 2]
    bx, by, bz = P[b, 0], P[b, 1], P[b, 2]
    cx, cy, cz = P[c, 0], P[c, 1], P[c, 2]
    n = w
    for i in range(ci0, ci1 + 1):
        for j in range(cj0, cj1 + 1):
            hit, z = _column_crossing(ax, ay, az, bx, by, bz, cx, cy, cz, i + 0.5, j + 0.5)
            col[n] = (i - i0) * nj + (j - j0) if hit else -1
            zs[n] = z
            n += 1


@njit(cache=True, nogil=True)
def _column_crossings(P, faces, i0, i1, j0, j1):
    """Crossings of every column of the window [i0, i1] x [j0, j1], grouped by column and sorted
    in z: returns (ptr, z) with column m = (i - i0) * nj + (j - j0) owning z[ptr[m]:ptr[m+1]]."""
    nt = faces.shape[0]
    nj = j1 - j0 + 1
    ncol = (i1 - i0 + 1) * nj
    # pass 1: slots per triangle = the columns of its clipped xy bounding box (cheap bound)
    cnt = np.zeros(nt + 1, dtype=np.int64)
    for t in range(nt):
        ci0, ci1, cj0, cj1 = _triangle_columns(P, faces, t, i0, i1, j0, j1)
        if ci0 <= ci1 and cj0 <= cj1:
            cnt[t + 1] = (ci1 - ci0 + 1) * (cj1 - cj0 + 1)
    for t in range(nt):
        cnt[t + 1] += cnt[t]
    total = cnt[nt]
    # pass 2: the crossing (window column, z) of every slot, -1 where the column misses
    col = np.empty(total, dtype=np.int64)
    zt = np.empty(total, dtype=np.float64)
    for t in range(nt):
        ci0, ci1, cj0, cj1 = _triangle_columns(P, faces, t, i0, i1, j0, j1)
        if ci0 <= ci1 and cj0 <= cj1:
            _triangle_crossings(P, faces, t, i0, j0, nj, ci0, ci1, cj0, cj1, col, zt, cnt[t])
    # counting sort of the crossings by column
    ptr = np.zeros(ncol + 1, dtype=np.int64)
    for m in range(total):
        if col[m] >= 0:
            ptr[col[m] + 1] += 1
    for m in range(ncol):
        ptr[m + 1] += ptr[m]
    cur = ptr[:-1].copy()
    zs = np.empty(ptr[ncol], dtype=np.float64)
    for m in range(total):
        cm = col[m]
        if cm >= 0:
            zs[cur[cm]] = zt[m]
            cur[cm] += 1
    # sort each column's crossings in z (few per column: insertion sort)
    for m in range(ncol):
        for x in range(ptr[m] + 1, ptr[m + 1]):
            v = zs[x]
            y = x - 1
            while y >= ptr[m] and zs[y] > v:
                zs[y + 1] = zs[y]
                y -= 1
            zs[y + 1] = v
    return ptr, zs


@njit(cache=True, nogil=True)
def _column_span(zs, p, nz):
    """Voxel range [k0, k1] of the crossing pair (zs[p], zs[p+1]): centres k + 0.5 in [z0, z1)."""
    z0 = min(max(zs[p], -2.0), nz + 2.0)
    z1 = min(max(zs[p + 1], -2.0), nz + 2.0)
    k0 = max(int(math.ceil(z0 - 0.5)), 0)
    k1 = min(int(math.ceil(z1 - 0.5)) - 1, nz - 1)
    return k0, k1


@njit(cache=True, nogil=True)
def _interior_indices(ptr, zs, i0, j0, nj, ny, nz):
    """Sorted linear indices of the voxel centres between crossing pairs of every column."""
    ncol = ptr.shape[0] - 1
    # pass 1: inside voxels per column
    cnt = np.zeros(ncol + 1, dtype=np.int64)
    for m in range(ncol):
        c = 0
        for p in range(ptr[m], ptr[m + 1] - 1, 2):
            k0, k1 = _column_span(zs, p, nz)
            if k1 >= k0:
                c += k1 - k0 + 1
        cnt[m + 1] = c
    for m in range(ncol):
        cnt[m + 1] += cnt[m]
    out = np.empty(cnt[ncol], dtype=np.int64)
    # pass 2: write them; window columns are in (i, j) order, pairs ascend -> sorted, unique
    for m in range(ncol):
        i = i0 + m // nj
        j = j0 + m % nj
        base = (i * ny + j) * nz
        w = cnt[m]
        for p in range(ptr[m], ptr[m + 1] - 1, 2):
            k0, k1 = _column_span(zs, p, nz)
            for k in range(k0, k1 + 1):
                out[w] = base + k
                w += 1
    return out


@njit(cache=True, nogil=True)
def _interior_paint(ptr, zs, i0, j0, nj, ny, nz, out_a, out_b, val_a, val_b):
    """Write (val_a, val_b) into the voxels whose centres lie between crossing pairs."""
    ncol = ptr.shape[0] - 1
    for m in range(ncol):
        i = i0 + m // nj
        j = j0 + m % nj
        base = (i * ny + j) * nz
        for p in range(ptr[m], ptr[m + 1] - 1, 2):
            k0, k1 = _column_span(zs, p, nz)
            for k in range(k0, k1 + 1):
                out_a[base + k] = val_a
                out_b[base + k] = val_b


# ----------------------------------------------------------------------------------------------
# Python entry points
# ----------------------------------------------------------------------------------------------


def shape3(shape) -> tuple[int, int, int]:
    """``shape`` as three positive ints (ValueError otherwise)."""
    nx, ny, nz = (int(s) for s in shape)
    if nx <= 0 or ny <= 0 or nz <= 0:
        raise ValueError(f"grid shape must be positive, got {shape!r}")
    return nx, ny, nz


def check_mesh(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    """``(V, F)``: contiguous float64 ``(n, 3)`` vertices and int64 ``(m, 3)`` faces, every index checked."""
    V = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
    F = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(F) and (F.min() < 0 or F.max() >= len(V)):
        raise ValueError(f"face indices must lie in [0, {len(V)}), got [{F.min()}, {F.max()}]")
    return V, F


def to_voxel_units(vertices: np.ndarray, origin, voxel_size: float) -> np.ndarray:
    """(N, 3) metres in the grid frame -> voxel units ``(v - origin) / voxel_size`` (float64)."""
    if not (voxel_size > 0 and math.isfinite(voxel_size)):
        raise ValueError(f"voxel size must be positive and finite, got {voxel_size!r}")
    V = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    return np.ascontiguousarray((V - np.asarray(origin, dtype=np.float64)) / float(voxel_size))


def _use_threads(work: int, threshold: int) -> bool:
    """Parallel kernels only pay off for big inputs (a thread-pool launch costs ~0.1 ms idle and
    milliseconds when the cores are busy with other work, e.g. other Dask tasks)."""
    return work >= threshold and numba.get_num_threads() > 1


def paint_surface(P, faces, shape, out_a, out_b, val_a, val_b, shift_x: float = 0.0) -> None:
    """Write ``val_a`` into flat ``out_a`` (and ``val_b`` into flat ``out_b`` unless it is None)
    at every surface voxel of the mesh given in voxel units ``P`` (see :func:`to_voxel_units`),
    moved by ``-shift_x`` along x first (a tile's first index: the same result as painting
    ``P - (shift_x, 0, 0)``, without the shifted copy).

    Meshes of at least ``PARALLEL_MIN_TRIANGLES`` triangles use numba's threads
    (``numba.set_num_threads``, per calling thread); smaller ones run in the calling thread.
    """
    nx, ny, nz = shape3(shape)
    P, F = check_mesh(P, faces)
    if len(F) == 0:
        return
    write_b = out_b is not None
    if out_b is None:
        out_b = np.zeros(1, dtype=np.uint32)
    kernel = _surface_paint_parallel if _use_threads(len(F), PARALLEL_MIN_TRIANGLES) else _surface_paint_serial
    kernel(P, F, nx, ny, nz, out_a, out_b, out_a.dtype.type(val_a), out_b.dtype.type(val_b), write_b, float(shift_x))


def surface_voxels(vertices, faces, origin, voxel_size: float, shape) -> np.ndarray:
    """Sorted unique C-order linear indices of the voxels whose closed box meets a triangle.

    ``vertices`` (N, 3) metres in the grid frame, ``faces`` (M, 3) vertex indices, ``origin``
    the grid's minimum corner (metres), ``voxel_size`` metres, ``shape`` (nx, ny, nz). Triangles
    outside the grid are culled, those crossing its border are clipped; zero-area triangles mark
    the voxels their segment/point touches; triangles with a non-finite coordinate are dropped.
    Uses one uint8 scratch mask of the grid's size (409 MB at 0.05 m on the default region; pages
    never touched are never allocated).
    """
    nx, ny, nz = shape3(shape)
    V, F = check_mesh(vertices, faces)
    if len(F) == 0:
        return np.zeros(0, dtype=np.int64)
    P = to_voxel_units(V, origin, voxel_size)
    # 1. mark every surface voxel in a byte mask (same-value writes: race-free in effect), padded
    #    to whole 8-byte words for the extraction
    n = nx * ny * nz
    words = np.zeros((n + 7) // 8, dtype=np.uint64)
    mask = words.view(np.uint8)
    paint_surface(P, F, (nx, ny, nz), mask, None, 1, 0)
    # 2. extract the marked indices, 8 bytes at a time, only in the blocks some triangle reaches
    flags = _touched_blocks(P, F, nx, ny * nz, 8 * _BLOCK_WORDS)
    if _use_threads(n, PARALLEL_MIN_VOXELS):
        return _mask_to_indices_parallel(mask, words, flags, _BLOCK_WORDS)
    return _mask_to_indices_serial(mask, words, flags, _BLOCK_WORDS)


def _fill_window(P: np.ndarray, F: np.ndarray, nx: int, ny: int):
    """Column window [i0, i1] x [j0, j1] of the mesh's xy bounding box (finite vertices), with
    one column of margin, clipped to the grid (None when it misses the grid)."""
    fin = P if np.isfinite(P).all() else P[np.isfinite(P).all(axis=1)]
    if len(fin) == 0:
        return None
    lo = fin.min(axis=0)
    hi = fin.max(axis=0)
    # a superset: the edge functions decide
    i0 = max(int(math.ceil(min(max(lo[0], -2.0), nx + 2.0) - 0.5)) - 1, 0)
    i1 = min(int(math.floor(min(max(hi[0], -2.0), nx + 2.0) - 0.5)) + 1, nx - 1)
    j0 = max(int(math.ceil(min(max(lo[1], -2.0), ny + 2.0) - 0.5)) - 1, 0)
    j1 = min(int(math.floor(min(max(hi[1], -2.0), ny + 2.0) - 0.5)) + 1, ny - 1)
    if i0 > i1 or j0 > j1:
        return None
    return i0, i1, j0, j1


def fill_interior(vertices, faces, origin, voxel_size: float, shape) -> np.ndarray:
    """Sorted C-order linear indices of the voxels whose centre is inside a closed mesh.

    Column parity: each triangle records, for every voxel-centre column (x, y) inside its xy
    projection (edge functions with a per-edge canonical tie rule: shared edges count once), the
    z of the crossing; crossings are sorted per column and the centres between pairs
    (z0 <= zc < z1) are inside. Meaningful for closed (watertight) meshes; the mesh may extend
    beyond the grid (crossings outside still count for the parity).
    """
    nx, ny, nz = shape3(shape)
    V, F = check_mesh(vertices, faces)
    if len(F) == 0:
        return np.zeros(0, dtype=np.int64)
    P = to_voxel_units(V, origin, voxel_size)
    win = _fill_window(P, F, nx, ny)
    if win is None:
        return np.zeros(0, dtype=np.int64)
    i0, i1, j0, j1 = win
    # 1. crossings per column, sorted in z
    ptr, zs = _column_crossings(P, F, i0, i1, j0, j1)
    # 2. centres between crossing pairs
    return _interior_indices(ptr, zs, i0, j0, j1 - j0 + 1, ny, nz)


def paint_interior(P, faces, shape, out_a, out_b, val_a, val_b) -> None:
    """Write ``val_a``/``val_b`` into flat ``out_a``/``out_b`` at the voxels whose centre is inside
    the closed mesh given in voxel units ``P``."""
    nx, ny, nz = shape3(shape)
    P, F = check_mesh(P, faces)
    if len(F) == 0:
        return
    win = _fill_window(P, F, nx, ny)
    if win is None:
        return
    i0, i1, j0, j1 = win
    ptr, zs = _column_crossings(P, F, i0, i1, j0, j1)
    _interior_paint(
        ptr, zs, i0, j0, j1 - j0 + 1, ny, nz, out_a, out_b,
        out_a.dtype.type(val_a), out_b.dtype.type(val_b),
    )


def warmup() -> None:
    """Compile (or load from numba's on-disk cache) every kernel, serial and parallel, on a
    tetrahedron, so that no later call pays for the JIT."""
    tet_v = np.array([[0.1, 0.1, 0.1], [1.9, 0.2, 0.1], [0.2, 1.8, 0.3], [0.4, 0.5, 1.7]])
    tet_f = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]], dtype=np.int64)
    shape = (4, 4, 4)
    surface_voxels(tet_v, tet_f, (0.0, 0.0, 0.0), 0.5, shape)
    fill_interior(tet_v, tet_f, (0.0, 0.0, 0.0), 0.5, shape)
    P = to_voxel_units(tet_v, (0.0, 0.0, 0.0), 0.5)
    for dtype_b in (np.uint32,):
        sem = np.zeros(64, dtype=np.uint8)
        inst = np.zeros(64, dtype=dtype_b)
        paint_surface(P, tet_f, shape, sem, inst, 1, 1)
        paint_interior(P, tet_f, shape, sem, inst, 1, 1)
        _surface_paint_parallel(P, tet_f, 4, 4, 4, sem, inst, np.uint8(1), dtype_b(1), True, 0.0)
    words = np.zeros(8, dtype=np.uint64)
    mask = words.view(np.uint8)
    _surface_paint_parallel(P, tet_f, 4, 4, 4, mask, np.zeros(1, np.uint32), np.uint8(1), np.uint32(0), False, 0.0)
    _mask_to_indices_parallel(mask, words, np.ones(1, dtype=np.uint8), _BLOCK_WORDS)
