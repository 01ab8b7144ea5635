"""Headless pictures of panoptic occupancy grids: bird's-eye height maps and 3D voxel views.

Inputs are the dense grid arrays indexed ``[x, y, z]`` in the LiDAR frame (x forward, y left,
z up, metres): ``semantic`` (uint8; 0 = free, class ids 1..29) and ``instance`` (uint32; 0 = stuff
or free, ``None`` for none), on a :class:`GridSpec`. Outputs are ``(H, W, 3)`` uint8 RGB images
(write them with ``carlaocc.catalog.images.save_png``), coloured by ``mode`` as in
:mod:`carlaocc.stages.render.colours`. Everything is numpy + numba (no plotting library) and
deterministic: the same inputs give identical bytes.

Bird's-eye view (:func:`bev_height_map`): one pixel per (x, y) column, image up = +x (forward),
image left = +y (left), so the ego's forward points up and its left is on the left. Each column
shows its top-most occupied voxel (a numba scan down every column, stopping at the first occupied
voxel), shaded by height: brightness ``0.6 + 0.4 sqrt(t)`` with ``t`` the top's height normalised over
the occupied tops of the image (or ``z_range``), brighter = higher; with ``relief`` a column lower
than its upper-left neighbour (the light comes from the image's upper left) is darkened by up to
30% (a drop shadow over 0.5 m of step), so edges of objects read even in one colour. Free columns
are dark grey. ``max_pixels`` downsamples big grids by an integer factor, keeping the top-most
voxel of every block of columns.

3D view (:func:`perspective_view`): a perspective (or, with ``fov_deg=0``, orthographic) camera at
``azimuth_deg`` / ``elevation_deg`` around the scene, by default a chase camera behind (-x) and
above the ego, framing the occupied voxels (or ``bounds``). Only surface voxels are drawn (occupied
with a free 6-neighbour; outside the grid counts as free), and of them only the exposed faces
turned towards the camera, as two triangles each through the shared rasterizer
(:func:`carlaocc.stages.render.raster.fill_triangle`), flat Lambert shaded per face direction with the key
light and the ambient/diffuse split of the asset previews. With ``outline`` a face of at least a
few pixels gets a thin darker border, so voxel size stays visible on flat areas. **Pooling:** when
the grid (after cropping to ``bounds``) has more than ``max_voxels`` voxels it is pooled by the
smallest power of two ``f`` that brings it under the budget: each ``f x f x f`` block is occupied
when any of its voxels is and takes the class and instance of its top-most occupied voxel
(:func:`pool_occupancy`). The default budget (64 M) pools a 0.05 m default-size frame (409 M
voxels) by 2, to 0.1 m voxels (about a pixel at 960 px wide).

The figures built from these views are in :mod:`carlaocc.stages.render.figures`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from carlaocc.schemas.grid import GridSpec
from carlaocc.stages.render.colours import check_mode, voxel_colours
from carlaocc.stages.render.raster import AMBIENT, DIFFUSE, camera_axes, fill_triangle, image_size, key_light

__all__ = [
    "DEFAULT_MAX_VOXELS",
    "FREE_RGB",
    "bev_height_map",
    "classes_present",
    "orthographic_extent",
    "perspective_view",
    "pool_occupancy",
    "surface_voxels",
    "top_surface",
]

FREE_RGB = (40, 40, 40)  # BEV colour of a free column (and of window pixels outside the grid)
DEFAULT_MAX_VOXELS = 64_000_000  # pooling budget of the 3D view (voxels of the cropped grid)
SHADE_MIN = 0.6  # BEV brightness of the lowest top (the highest gets 1.0)
RELIEF_DARKEN = 0.30  # BEV drop shadow: at most this share darker ...
RELIEF_STEP_M = 0.5  # ... reached for a step of this height (metres)
OUTLINE_DARKEN = 0.72  # 3D view: face borders are multiplied by this


# --------------------------------------------------------------------------------------------
# numba kernels
# --------------------------------------------------------------------------------------------


_CHUNK = 32  # column scans test this many voxels at once (a vectorized OR) to skip free space


@njit(cache=True, nogil=True)
def _top_kernel(sem, inst, has_inst, ktop, stop, itop):  # pragma: no cover - numba
    """Per (x, y) column: index of the top-most occupied voxel (-1 when free), its class and
    instance."""
    X, Y, Z = sem.shape
    for i in range(X):
        for j in range(Y):
            ktop[i, j] = -1
            stop[i, j] = 0
            itop[i, j] = 0
            hi = Z
            while hi > 0:
                lo = max(0, hi - _CHUNK)
                acc = 0
                for k in range(lo, hi):
                    acc |= sem[i, j, k]
                if acc != 0:
                    for k in range(hi - 1, lo - 1, -1):
                        c = sem[i, j, k]
                        if c != 0:
                            ktop[i, j] = k
                            stop[i, j] = c
                            if has_inst:
                                itop[i, j] = inst[i, j, k]
                            break
                    break
                hi = lo


@njit(cache=True, nogil=True)
def _pool_kernel(sem, inst, has_inst, f, psem, pinst, pk):  # pragma: no cover - numba
    """Pool by ``f``: a block keeps its top-most occupied voxel's class and instance (``pk`` holds
    that voxel's fine z index, -1 initially; ties in z go to the first voxel in x, y order)."""
    X, Y, Z = sem.shape
    for i in range(X):
        bi = i // f
        for j in range(Y):
            bj = j // f
            k = Z - 1
            while k >= 0:
                lo = max(0, k - _CHUNK + 1)
                acc = 0
                for kk in range(lo, k + 1):
                    acc |= sem[i, j, kk]
                if acc == 0:  # a free run: skip it
                    k = lo - 1
                    continue
                while k >= lo:
                    c = sem[i, j, k]
                    if c != 0:
                        bk = k // f
                        if k > pk[bi, bj, bk]:
                            pk[bi, bj, bk] = k
                            psem[bi, bj, bk] = c
                            if has_inst:
                                pinst[bi, bj, bk] = inst[i, j, k]
                        k = bk * f - 1  # the rest of this block's column cannot be higher
                    else:
                        k -= 1


@njit(cache=True, nogil=True)
def _surface_kernel(sem, fill, idx, mask):  # pragma: no cover - numba
    """Count (``fill`` False) or list the surface voxels: occupied with at least one free
    6-neighbour (outside the grid is free). ``mask`` bit d is set when the face in direction d
    (0: -x, 1: +x, 2: -y, 3: +y, 4: -z, 5: +z) is exposed."""
    X, Y, Z = sem.shape
    n = 0
    for i in range(X):
        for j in range(Y):
            for k in range(Z):
                if sem[i, j, k] == 0:
                    continue
                m = 0
                if i == 0 or sem[i - 1, j, k] == 0:
                    m |= 1
                if i == X - 1 or sem[i + 1, j, k] == 0:
                    m |= 2
                if j == 0 or sem[i, j - 1, k] == 0:
                    m |= 4
                if j == Y - 1 or sem[i, j + 1, k] == 0:
                    m |= 8
                if k == 0 or sem[i, j, k - 1] == 0:
                    m |= 16
                if k == Z - 1 or sem[i, j, k + 1] == 0:
                    m |= 32
                if m == 0:
                    continue
                if fill:
                    idx[n, 0] = i
                    idx[n, 1] = j
                    idx[n, 2] = k
                    mask[n] = m
                n += 1
    return n


@njit(cache=True, nogil=True)
def _seen_kernel(flat, seen):  # pragma: no cover - numba
    for v in range(flat.shape[0]):
        seen[flat[v]] = 1



@njit(cache=True, nogil=True)
def _draw_faces(idx, mask, cols, shade, origin, voxel_size, cam, basis, persp, scale, offx, offy, edge, dark,
                zbuf, img):  # pragma: no cover - numba  # fmt: skip
    """Draw the exposed, camera-facing faces of voxels ``idx`` (N, 3) with face masks ``mask``
    (bits as in :func:`_surface_kernel`), base colours ``cols`` (N, 3) and per-direction shade
    ``shade`` (6,). Camera at ``cam``; ``basis`` rows are right, up, forward; screen x =
    ``offx + scale * u``, y = ``offy - scale * v`` with (u, v) the view coordinates, divided by the
    depth when ``persp``. Faces of at least ``3 * edge`` pixels a side get a ``dark`` border."""
    p = np.empty(3)
    sx = np.empty(4)
    sy = np.empty(4)
    sz = np.empty(4)
    qs = (0.0, 1.0, 1.0, 0.0)
    qt = (0.0, 0.0, 1.0, 1.0)
    for n in range(idx.shape[0]):
        m = mask[n]
        if m == 0:
            continue
        bx = origin[0] + idx[n, 0] * voxel_size
        by = origin[1] + idx[n, 1] * voxel_size
        bz = origin[2] + idx[n, 2] * voxel_size
        for d in range(6):
            if (m >> d) & 1 == 0:
                continue
            a = d // 2
            pos = d & 1
            sgn = 1.0 if pos else -1.0
            if persp:
                face = (bx, by, bz)[a] + (voxel_size if pos else 0.0)
                if sgn * (cam[a] - face) <= 0.0:
                    continue
            elif sgn * basis[2, a] >= 0.0:
                continue
            b_ = (a + 1) % 3
            c_ = (a + 2) % 3
            ok = True
            for q in range(4):
                p[0] = bx
                p[1] = by
                p[2] = bz
                if pos:
                    p[a] += voxel_size
                p[b_] += qs[q] * voxel_size
                p[c_] += qt[q] * voxel_size
                dx = p[0] - cam[0]
                dy = p[1] - cam[1]
                dz = p[2] - cam[2]
                u = dx * basis[0, 0] + dy * basis[0, 1] + dz * basis[0, 2]
                v = dx * basis[1, 0] + dy * basis[1, 1] + dz * basis[1, 2]
                w = dx * basis[2, 0] + dy * basis[2, 1] + dz * basis[2, 2]
                if w <= 1e-9:
                    ok = False
                    break
                if persp:
                    u /= w
                    v /= w
                sx[q] = offx + scale * u
                sy[q] = offy - scale * v
                sz[q] = w
            if not ok:
                continue
            ls = math.hypot(sx[1] - sx[0], sy[1] - sy[0])
            lt = math.hypot(sx[3] - sx[0], sy[3] - sy[0])
            e = edge if min(ls, lt) >= 3.0 * edge else 0.0
            k = shade[d]
            r, g, bb = cols[n, 0] * k, cols[n, 1] * k, cols[n, 2] * k
            fill_triangle(sx[0], sy[0], sz[0], 0.0, 0.0, sx[1], sy[1], sz[1], 1.0, 0.0, sx[2], sy[2], sz[2], 1.0, 1.0,
                          r, g, bb, 1.0, False, ls, lt, e, dark, zbuf, img)  # fmt: skip
            fill_triangle(sx[0], sy[0], sz[0], 0.0, 0.0, sx[2], sy[2], sz[2], 1.0, 1.0, sx[3], sy[3], sz[3], 0.0, 1.0,
                          r, g, bb, 1.0, False, ls, lt, e, dark, zbuf, img)  # fmt: skip


# --------------------------------------------------------------------------------------------
# arrays: checks, top surface, pooling, surface voxels, classes
# --------------------------------------------------------------------------------------------


def grid_arrays(semantic, instance, grid: GridSpec | None = None) -> tuple[np.ndarray, np.ndarray, bool]:
    """C-contiguous uint8 semantic and uint32 instance (a 1-voxel dummy when ``None``), checked."""
    sem = np.asarray(semantic)
    if sem.ndim != 3:
        raise ValueError(f"semantic must be a 3D [x, y, z] array, got shape {sem.shape}")
    if grid is not None and tuple(sem.shape) != tuple(grid.shape):
        raise ValueError(f"semantic shape {sem.shape} does not match the grid shape {grid.shape}")
    sem = np.ascontiguousarray(sem.astype(np.uint8, copy=False))
    if instance is None:
        return sem, np.zeros((1, 1, 1), np.uint32), False
    inst = np.asarray(instance)
    if inst.shape != sem.shape:
        raise ValueError(f"instance shape {inst.shape} does not match semantic shape {sem.shape}")
    return sem, np.ascontiguousarray(inst.astype(np.uint32, copy=False)), True



def top_surface(semantic, instance=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Top-most occupied voxel of every (x, y) column: ``(k, semantic, instance)`` arrays of shape
    (X, Y), ``k`` the z index (int32, -1 for a free column, whose class and instance are 0)."""
    sem, inst, has = grid_arrays(semantic, instance)
    X, Y, _ = sem.shape
    ktop = np.empty((X, Y), np.int32)
    stop = np.empty((X, Y), np.uint8)
    itop = np.empty((X, Y), np.uint32)
    _top_kernel(sem, inst, has, ktop, stop, itop)
    return ktop, stop, itop


def block_top(ktop, stop, itop, f: int):
    """Downsample top maps by ``f`` per axis, keeping the top-most voxel of each f x f block (the
    first in x, y order on ties); partial blocks at the far edges are padded with free columns."""
    X, Y = ktop.shape
    Xb, Yb = -(-X // f), -(-Y // f)

    def blocks(a, fill):
        out = np.full((Xb * f, Yb * f), fill, dtype=a.dtype)
        out[:X, :Y] = a
        return out.reshape(Xb, f, Yb, f).transpose(0, 2, 1, 3).reshape(Xb, Yb, f * f)

    kb = blocks(ktop, -1)
    best = np.argmax(kb, axis=2)[..., None]
    take = lambda a: np.take_along_axis(a, best, axis=2)[..., 0]
    return take(kb), take(blocks(stop, 0)), take(blocks(itop, 0))


def pool_occupancy(semantic, instance=None, factor: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Pool a grid by ``factor`` per axis (shape rounded up): a block is occupied when any of its
    voxels is, with the class and instance of its top-most occupied voxel (ties in z: the first
    voxel in x, y order). Returns ``(semantic uint8, instance uint32)``; one streaming pass."""
    f = int(factor)
    if f < 1:
        raise ValueError(f"factor must be >= 1, got {factor}")
    sem, inst, has = grid_arrays(semantic, instance)
    if f == 1:
        return sem, (inst if has else np.zeros(sem.shape, np.uint32))
    shape = tuple(-(-n // f) for n in sem.shape)
    psem = np.zeros(shape, np.uint8)
    pinst = np.zeros(shape, np.uint32)
    pk = np.full(shape, -1, np.int32)
    _pool_kernel(sem, inst, has, f, psem, pinst, pk)
    return psem, pinst


def surface_voxels(semantic) -> tuple[np.ndarray, np.ndarray]:
    """Surface voxels (occupied, with a free 6-neighbour; outside the grid is free) in C order:
    ``(idx (N, 3) int32, mask (N,) uint8)``, mask bit d set when the face in direction d
    (0: -x, 1: +x, 2: -y, 3: +y, 4: -z, 5: +z) is exposed."""
    sem = np.ascontiguousarray(np.asarray(semantic).astype(np.uint8, copy=False))
    dummy_i, dummy_m = np.empty((1, 3), np.int32), np.empty(1, np.uint8)
    n = _surface_kernel(sem, False, dummy_i, dummy_m)
    idx, mask = np.empty((n, 3), np.int32), np.empty(n, np.uint8)
    _surface_kernel(sem, True, idx, mask)
    return idx, mask


def classes_present(semantic) -> np.ndarray:
    """Sorted nonzero class ids occurring in the grid (int64), in one pass without a copy."""
    sem = np.ascontiguousarray(np.asarray(semantic).astype(np.uint8, copy=False))
    seen = np.zeros(256, np.uint8)
    _seen_kernel(sem.reshape(-1), seen)
    seen[0] = 0
    return np.flatnonzero(seen)


# --------------------------------------------------------------------------------------------
# bird's-eye view
# --------------------------------------------------------------------------------------------


def bev_colours(ktop, stop, itop, z0: float, voxel_size: float, mode: str, z_range, relief: bool, free_color) -> np.ndarray:
    """Float32 (X, Y, 3) colours of top maps in grid order (not yet flipped to the image)."""
    occ = ktop >= 0
    z = z0 + (ktop.astype(np.float64) + 0.5) * voxel_size
    out = np.empty(ktop.shape + (3,), np.float32)
    out[:] = np.asarray(free_color, np.float32)
    if not occ.any():
        return out
    if z_range is None:
        z_range = (float(z[occ].min()), float(z[occ].max()))
    lo, hi = float(z_range[0]), float(z_range[1])
    col = voxel_colours(stop[occ], itop[occ], z[occ], mode, (lo, hi))
    if mode != "height":
        t = np.clip((z[occ] - lo) / (hi - lo), 0.0, 1.0) if hi > lo else np.ones(int(occ.sum()))
        col *= (SHADE_MIN + (1.0 - SHADE_MIN) * np.sqrt(t)).astype(np.float32)[:, None]
    out[occ] = col
    if relief:
        # the light comes from the image's upper left = grid (+x, +y): darken a column lower than
        # its (+1, +1) neighbour, by the step height
        step = np.zeros(ktop.shape)
        both = occ[1:, 1:] & occ[:-1, :-1]
        step[:-1, :-1] = np.where(both, z[1:, 1:] - z[:-1, :-1], 0.0)
        factor = 1.0 - RELIEF_DARKEN * np.clip(step / RELIEF_STEP_M, 0.0, 1.0)
        out *= factor.astype(np.float32)[..., None]
    return out


def bev_image(colours: np.ndarray) -> np.ndarray:
    """Grid-order (X, Y, 3) colours to the BEV image: rows from +x down, columns from +y right."""
    return np.ascontiguousarray(np.clip(np.round(colours[::-1, ::-1]), 0, 255).astype(np.uint8))


def draw_ego(img: np.ndarray, x_top: float, y_left: float, cell: float, length: float = 4.6,
             width: float = 1.9) -> None:  # fmt: skip
    """Draw the ego as a white arrow-head triangle (``length`` x ``width`` metres, tip forward)
    centred on the LiDAR origin into a BEV image whose top edge is at x = ``x_top``, left edge at
    y = ``y_left``, ``cell`` metres per pixel. Clipped to the image."""
    H, W = img.shape[:2]
    r0 = max(0, int(math.floor((x_top - length / 2) / cell)) - 1)
    r1 = min(H, int(math.ceil((x_top + length / 2) / cell)) + 1)
    c0 = max(0, int(math.floor((y_left - width / 2) / cell)) - 1)
    c1 = min(W, int(math.ceil((y_left + width / 2) / cell)) + 1)
    if r1 <= r0 or c1 <= c0:
        return
    x = x_top - (np.arange(r0, r1) + 0.5)[:, None] * cell  # metres forward of the ego
    y = y_left - (np.arange(c0, c1) + 0.5)[None, :] * cell  # metres left of the ego
    # tip at x = +length/2 on the axis; base from (-length/2, -width/2) to (-length/2, +width/2)
    inside = (x >= -length / 2) & (np.abs(y) <= (width / 2) * (length / 2 - x) / length)
    img[r0:r1, c0:c1][inside] = (255, 255, 255)


def bev_height_map(
    semantic,
    instance,
    grid: GridSpec,
    mode: str = "instance",
    *,
    max_pixels: int | None = None,
    z_range: tuple[float, float] | None = None,
    relief: bool = True,
    mark_ego: bool = False,
    free_color=FREE_RGB,
) -> np.ndarray:
    """Bird's-eye view of a grid: ``(X // f, Y // f, 3)`` uint8 (rounded up), one pixel per (x, y)
    column (``f`` = 1) or per ``f x f`` block when ``max_pixels`` is given and exceeded (``f`` the
    smallest integer that fits; each block shows its top-most voxel). Image up = +x (forward),
    left = +y (left). Colours as in the module docstring (``mode``), shaded by the top's height
    (normalised over the occupied tops, or over ``z_range`` in metres), with the ``relief`` drop
    shadow; free columns ``free_color``; ``mark_ego`` draws the ego (white triangle pointing
    forward) at the LiDAR origin."""
    check_mode(mode)
    sem, inst, has = grid_arrays(semantic, instance, grid)
    ktop, stop, itop = top_surface(sem, inst if has else None)
    X, Y = ktop.shape
    f = 1
    if max_pixels is not None and X * Y > int(max_pixels):
        if max_pixels < 1:
            raise ValueError(f"max_pixels must be >= 1, got {max_pixels}")
        f = max(1, int(math.ceil(math.sqrt(X * Y / max_pixels))))
        while (-(-X // f)) * (-(-Y // f)) > max_pixels:
            f += 1
        ktop, stop, itop = block_top(ktop, stop, itop, f)
    voxel_size = grid.voxel_size
    img = bev_image(bev_colours(ktop, stop, itop, grid.origin[2], voxel_size, mode, z_range, relief, free_color))
    if mark_ego:
        cell = voxel_size * f
        Xb, Yb = ktop.shape
        draw_ego(img, grid.origin[0] + Xb * cell, grid.origin[1] + Yb * cell, cell)
    return img


# --------------------------------------------------------------------------------------------
# 3D view
# --------------------------------------------------------------------------------------------


def crop_indices(origin, voxel_size: float, shape, bounds, centres: bool = True) -> tuple[slice, slice, slice]:
    """Voxel index slices of the voxels (grid ``origin``, ``voxel_size``, ``shape``) whose centres lie in
    the metric ``bounds`` ((xmin, xmax), (ymin, ymax)[, (zmin, zmax)]), or with ``centres`` False
    that overlap them; axes without bounds are whole."""
    out = []
    for a, n in enumerate(shape):
        if bounds is None or a >= len(bounds) or bounds[a] is None:
            out.append(slice(0, n))
            continue
        lo, hi = ((bounds[a][0] - origin[a]) / voxel_size, (bounds[a][1] - origin[a]) / voxel_size)
        if centres:
            i0, i1 = math.ceil(lo - 0.5 - 1e-9), math.floor(hi - 0.5 + 1e-9) + 1
        else:
            i0, i1 = math.floor(lo + 1e-9), math.ceil(hi - 1e-9)
        i0, i1 = max(0, i0), min(n, i1)
        out.append(slice(i0, max(i0, i1)))
    return out[0], out[1], out[2]


def _frame_camera(lo, hi, el: float, az: float, H: int, W: int, fov_deg: float, margin: float):
    """Camera position, basis (rows right, up, forward), projection scale and offsets framing the
    box [lo, hi] into an H x W image with ``margin`` on each side."""
    right, up, fwd = camera_axes(el, az)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    c = (lo + hi) / 2
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]) - c
    u, v, wr = corners @ right, corners @ up, corners @ fwd
    usable = 1.0 - 2.0 * min(max(margin, 0.0), 0.45)
    size = float(np.linalg.norm(hi - lo)) + 1e-6
    persp = fov_deg > 0
    if persp:
        tv = math.tan(math.radians(min(fov_deg, 170.0)) / 2)
        th = tv * W / H
        d = max(float(np.max(np.abs(u) / (th * usable) - wr)), float(np.max(np.abs(v) / (tv * usable) - wr)),
                float(np.max(-wr)) + 0.05 * size)  # fmt: skip
        w = d + wr
        su, sv = u / w, v / w
    else:
        d = 2.0 * size
        su, sv = u, v
    cam = c - fwd * d
    span_u, span_v = max(float(np.ptp(su)), 1e-12), max(float(np.ptp(sv)), 1e-12)
    scale = min(W * usable / span_u, H * usable / span_v)
    offx = W / 2 - (su.max() + su.min()) / 2 * scale
    offy = H / 2 + (sv.max() + sv.min()) / 2 * scale
    basis = np.ascontiguousarray(np.stack([right, up, fwd]))
    light = key_light(right, up, fwd)
    return cam, basis, persp, float(scale), float(offx), float(offy), light


def orthographic_extent(bounds, size, elevation_deg: float, azimuth_deg: float,
                        margin: float = 0.03) -> tuple[float, float, float, float]:
    """(left, right, bottom, top) of an orthographic :func:`perspective_view` (``fov_deg=0``)
    framing the metric ``bounds`` ((xmin, xmax), (ymin, ymax), (zmin, zmax)) into ``size``
    pixels: the image edges in metres along the view's screen axes (``right`` and ``up`` of
    :func:`carlaocc.stages.render.raster.camera_axes`), measured from the centre of ``bounds``.
    A point p lands at pixel column ``(u - left) / (right - left) * W`` and row
    ``(top - v) / (top - bottom) * H`` with (u, v) = ((p - centre) . right, (p - centre) . up).
    At ``elevation_deg`` 0, ``up`` is +z: bottom and top are heights above the centre."""
    H, W = image_size(size)
    lo = np.array([b[0] for b in bounds], float)
    hi = np.array([b[1] for b in bounds], float)
    # the same framing the view computes (the supersampling scales pixels and offsets alike)
    _, _, _, scale, offx, offy, _ = _frame_camera(lo, hi, elevation_deg, azimuth_deg, H, W, 0.0, margin)
    # screen x = offx + scale u, y = offy - scale v, inverted at the image edges
    return (-offx / scale, (W - offx) / scale, (offy - H) / scale, offy / scale)


def voxel_view(sem, inst, has, grid_origin, voxel_size, size, elevation_deg, azimuth_deg, mode, fov_deg, bounds,
               max_voxels, background, antialias, margin, outline, z_range=None) -> tuple[np.ndarray, int]:  # fmt: skip
    """:func:`perspective_view` on checked arrays (see :func:`grid_arrays`) with voxel (0, 0, 0) at
    ``grid_origin``; returns the image and the pooling factor. ``z_range`` (m), when given, is
    the height mode's ramp range (else the bounds' z range, else the drawn voxels')."""
    check_mode(mode)
    H, W = image_size(size)
    ss = max(1, int(antialias))
    bg = np.asarray(background, np.float32).reshape(3)
    blank = np.ascontiguousarray(np.broadcast_to(np.round(bg).astype(np.uint8), (H, W, 3)))
    voxel_size = float(voxel_size)
    full_lo = np.asarray(grid_origin, float)
    full_hi = full_lo + np.array(sem.shape) * voxel_size
    sx, sy, sz = crop_indices(grid_origin, voxel_size, sem.shape, bounds)
    origin = np.asarray(grid_origin, float) + np.array([sx.start, sy.start, sz.start]) * voxel_size
    if (sx.start, sy.start, sz.start, sx.stop, sy.stop, sz.stop) != (0, 0, 0) + sem.shape:
        sem = np.ascontiguousarray(sem[sx, sy, sz])
        inst = np.ascontiguousarray(inst[sx, sy, sz]) if has else inst
    f = 1
    if sem.size == 0:
        return blank, f
    while math.prod(-(-n // f) for n in sem.shape) > max(int(max_voxels), 1):
        f *= 2
    psem, pinst = pool_occupancy(sem, inst if has else None, f)
    pooled_voxel_size = voxel_size * f
    idx, mask = surface_voxels(psem)
    if len(idx) == 0:
        return blank, f
    i, j, k = idx[:, 0], idx[:, 1], idx[:, 2]
    z = origin[2] + (k + 0.5) * pooled_voxel_size
    if z_range is not None:
        z_range = (float(z_range[0]), float(z_range[1]))
    elif bounds is not None and len(bounds) > 2 and bounds[2] is not None:
        z_range = (float(bounds[2][0]), float(bounds[2][1]))
    else:
        z_range = (float(z.min()), float(z.max()))
    cols = np.ascontiguousarray(voxel_colours(psem[i, j, k], pinst[i, j, k], z, mode, z_range).astype(np.float64))
    # framing: the bounds (clipped to the grid) or the occupied voxels
    if bounds is not None:
        lo, hi = full_lo.copy(), full_hi.copy()
        for a in range(min(len(bounds), 3)):
            if bounds[a] is not None:
                lo[a], hi[a] = max(lo[a], bounds[a][0]), min(hi[a], bounds[a][1])
    else:
        lo, hi = origin + idx.min(axis=0) * pooled_voxel_size, origin + (idx.max(axis=0) + 1) * pooled_voxel_size
    Hs, Ws = H * ss, W * ss
    cam, basis, persp, scale, offx, offy, light = _frame_camera(
        lo, hi, elevation_deg, azimuth_deg, Hs, Ws, fov_deg, margin
    )
    normals = np.array([[-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0], [0, 0, -1], [0, 0, 1]], float)
    shade = AMBIENT + DIFFUSE * np.clip(normals @ light, 0.0, 1.0)
    img = np.empty((Hs, Ws, 3), np.float32)
    img[:] = bg
    zbuf = np.full((Hs, Ws), np.inf)
    edge = 0.75 * ss if outline else 0.0
    _draw_faces(idx, mask, cols, shade, origin, float(pooled_voxel_size), cam, basis, persp, scale, offx, offy, edge, OUTLINE_DARKEN,
                zbuf, img)  # fmt: skip
    if ss > 1:
        img = img.reshape(H, ss, W, ss, 3).mean(axis=(1, 3))
    return np.ascontiguousarray(np.clip(np.round(img), 0, 255).astype(np.uint8)), f


def perspective_view(
    semantic,
    instance,
    grid: GridSpec,
    size=(540, 960),
    elevation_deg: float = 35.0,
    azimuth_deg: float = 180.0,
    *,
    mode: str = "instance",
    fov_deg: float = 40.0,
    bounds=None,
    max_voxels: int = DEFAULT_MAX_VOXELS,
    background=(255, 255, 255),
    antialias: int = 2,
    margin: float = 0.03,
    outline: bool = True,
) -> np.ndarray:
    """3D view of the occupied voxels as shaded cubes: ``size`` = ``(height, width)`` (as
    for every picture of :mod:`carlaocc.stages.render`) uint8 RGB.

    The camera looks from ``azimuth_deg`` (about +z, from +x towards +y; 180 = from behind the ego)
    and ``elevation_deg`` (above the horizon) with a vertical field of view ``fov_deg`` (0 for an
    orthographic view), framing the occupied voxels, or the metric ``bounds`` ((xmin, xmax),
    (ymin, ymax)[, (zmin, zmax)]) to which the grid is then also cropped (the voxels whose centre
    is inside). Grids of more than ``max_voxels`` voxels are pooled first (see the module
    docstring). Only exposed faces are drawn, Lambert shaded per face direction, with thin darker
    borders when ``outline``; ``antialias`` supersamples. An empty grid gives the ``background``."""
    sem, inst, has = grid_arrays(semantic, instance, grid)
    img, _ = voxel_view(sem, inst, has, grid.origin, grid.voxel_size, size, elevation_deg, azimuth_deg, mode,
                        fov_deg, bounds, max_voxels, background, antialias, margin, outline)  # fmt: skip
    return img
