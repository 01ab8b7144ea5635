"""Surface normals from a depth map with D2NT (Feng et al., "D2NT: A High-Performing
Depth-to-Normal Translator", the ``d2nt`` package on PyPI, MIT licence, by the paper's authors).

D2NT differentiates the depth image and maps the gradients straight to normals in the camera
frame (OpenCV: x right, y down, z forward). :func:`depth_normals` runs D2NT's algorithm as one
compiled pass per pixel (:func:`_d2nt_kernel`, the same float32 operations in the same order as
the package's ``depth2normal``, whose numpy/OpenCV version allocates some thirty full-image
temporaries); :func:`reference_normals` calls the package itself (tests and benchmarks compare the
two). Two conventions are adapted here:

* D2NT numbers pixels from 1 (``u = 1..W``); our pixel ``u`` (from 0) has its centre at
  ``u + 0.5``. Passing the principal point as ``cx + 0.5`` makes D2NT's ``u - u0`` equal
  ``(u + 0.5) - cx``.
* Pixels without a surface (depth 0) get the zero vector, and so do pixels whose 3x3
  neighbourhood reaches one (their gradient would mix a surface with the void).

Normals point towards the camera (negative z for a visible surface), as D2NT returns them.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

VERSIONS = ("d2nt_basic", "d2nt_v2", "d2nt_v3")


def _prepare(depth: np.ndarray, intrinsics, version: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    # the checks and the two conventions shared by the kernel and the reference
    if version not in VERSIONS:
        raise ValueError(f"unknown D2NT version {version!r}; one of {', '.join(VERSIONS)}")
    depth = np.asarray(depth, dtype=np.float32)
    if depth.ndim != 2:
        raise ValueError(f"depth must be (H, W), got shape {depth.shape}")
    K = np.array(intrinsics, dtype=np.float64).reshape(3, 3)
    # D2NT's 1-based pixel numbering: shift the principal point by half a pixel
    K[0, 2] += 0.5
    K[1, 2] += 0.5
    return depth, K, depth > 0


def depth_normals(depth: np.ndarray, intrinsics, version: str = "d2nt_v2") -> np.ndarray:
    """(H, W, 3) float32 unit normals of a planar depth map (float32 metres, 0 = no surface) in
    the OpenCV camera frame; ``intrinsics`` the 3x3 K of the camera (pixel centres at u + 0.5).
    D2NT's ``depth2normal`` compiled (see :func:`reference_normals` for the package's own)."""
    depth, K, valid = _prepare(depth, intrinsics, version)
    out = np.zeros((*depth.shape, 3), dtype=np.float32)
    if not valid.any():
        return out
    # 1. the void filled with the largest depth (D2NT differentiates it; masked out in 5.), padded
    z = _padded(depth, np.float32(depth.max()))
    # 2. D2NT v2/v3's soft-min powers base ** -laplacian by numpy's own float32 power, as D2NT
    #    computes them (a compiled powf differs from numpy's vectorized one by an ulp at times)
    pow_h = pow_v = np.zeros((1, 1), dtype=np.float32)
    if version != "d2nt_basic":
        lap_h, lap_v = np.empty_like(depth), np.empty_like(depth)
        _laplacians(z, lap_h, lap_v)
        pow_h, pow_v = np.power(np.e, -lap_h).astype(np.float32), np.power(np.e, -lap_v).astype(np.float32)
    # 3. gradients and normals; 4. v3's refinement; 5. the void's neighbourhood zeroed: without
    #    v3's refinement (which reads its neighbours' normals) those pixels are never computed,
    #    their zeros left as they are
    if version == "d2nt_v3":
        raw = np.empty_like(out)
        _d2nt_rows(z, pow_h, pow_v, K[0, 0], K[1, 1], K[0, 2], K[1, 2], True, np.zeros((0, 0), np.bool_), raw)
        _mrf(z, raw, out)
        _mask_void(depth, out)
    else:
        _d2nt_rows(z, pow_h, pow_v, K[0, 0], K[1, 1], K[0, 2], K[1, 2], version != "d2nt_basic",
                   _near_void(depth), out)
    return out


def reference_normals(depth: np.ndarray, intrinsics, version: str = "d2nt_v2") -> np.ndarray:
    """:func:`depth_normals` through the ``d2nt`` package's numpy/OpenCV ``depth2normal`` (the
    reference the compiled kernel is checked against)."""
    from d2nt import depth2normal  # with cv2, 0.3 s to import
    from scipy.ndimage import minimum_filter

    depth, K, valid = _prepare(depth, intrinsics, version)
    if not valid.any():
        return np.zeros((*depth.shape, 3), dtype=np.float32)
    # the void filled with a stand-in D2NT can differentiate (masked out below)
    filled = np.where(valid, depth, np.float32(depth[valid].max()))
    n = depth2normal(filled, K, version=version).astype(np.float32, copy=False)
    # zero where the 3x3 neighbourhood touches a pixel without a surface
    keep = minimum_filter(valid.view(np.uint8), size=3, mode="nearest").astype(bool)
    n[~keep] = 0.0
    return n


# -- the compiled kernel -----------------------------------------------------------------------------
# Each step below names the d2nt function it reproduces (d2nt 0.1.3: core.depth2normal,
# filters.get_filter / get_DAG_filter / soft_min / MRF_optim, utils.vector_normalization). OpenCV's
# filter2D reflects at the border without repeating the edge pixel (BORDER_REFLECT_101, numpy's
# "reflect" padding); every product and sum is float32 in D2NT's order. The loops run along image
# rows with selects instead of branches, so the compiler vectorizes them.
_E32 = np.float32(math.e)  # soft_min's base (and threshold), as numpy casts it against a float32 array
_EPS = np.float32(1e-8)
_HALF_EPS = np.float32(0.5e-8)


@njit(cache=True, nogil=True)
def _padded(depth, fill):
    # the depth D2NT differentiates (the void filled with ``fill``), padded by one pixel with
    # BORDER_REFLECT_101 (index -1 reads 1, index W reads W - 2)
    H, W = depth.shape
    z = np.empty((H + 2, W + 2), dtype=np.float32)
    for v in range(H):
        for u in range(W):
            d = depth[v, u]
            z[v + 1, u + 1] = d if d > 0 else fill
    # (an image one pixel wide or high reflects onto itself)
    left, right = (2, W - 1) if W > 1 else (1, 1)
    top, bottom = (2, H - 1) if H > 1 else (1, 1)
    for v in range(1, H + 1):
        z[v, 0] = z[v, left]
        z[v, W + 1] = z[v, right]
    for u in range(W + 2):
        z[0, u] = z[top, u]
        z[H + 1, u] = z[bottom, u]
    return z


@njit(cache=True, nogil=True)
def _laplacians(z, lap_h, lap_v):
    # get_DAG_filter's 1D-DLF laplacians |grad_l - grad_r| and |grad_u - grad_d| of every pixel
    H, W = lap_h.shape
    for v in range(H):
        for u in range(W):
            zc = z[v + 1, u + 1]
            lap_h[v, u] = abs((zc - z[v + 1, u]) - (z[v + 1, u + 2] - zc))
            lap_v[v, u] = abs((zc - z[v, u + 1]) - (z[v + 2, u + 1] - zc))


@njit(cache=True, nogil=True, inline="always")
def _dag_weights(p_prev, p_next):
    # soft_min's pair of weights, then get_DAG_filter's four thresholded assignments in order
    w1 = (p_prev + _HALF_EPS) / (_EPS + p_prev + p_next)
    w2 = (p_next + _HALF_EPS) / (_EPS + p_prev + p_next)
    w1 = np.float32(1.0) if w1 / (w2 + _EPS) > _E32 else w1
    w2 = np.float32(0.0) if w1 / (w2 + _EPS) > _E32 else w2
    w1 = np.float32(0.0) if w2 / (w1 + _EPS) > _E32 else w1
    w2 = np.float32(1.0) if w2 / (w1 + _EPS) > _E32 else w2
    return w1, w2


@njit(cache=True, nogil=True)
def _d2nt_rows(z, pow_h, pow_v, fx, fy, u0, v0, dag, skip, out):
    # core.depth2normal, one row at a time: the gradients Gu, Gv (get_filter or get_DAG_filter),
    # the translation to a normal, vector_normalization; pixels ``skip`` marks (an (H, W) bool,
    # or empty: none) are left as they are
    H, W = out.shape[0], out.shape[1]
    zero = np.float32(0.0)
    some = skip.size > 0
    for v in range(H):
        vm = np.float32(np.float64(np.float32(v + 1)) - v0)  # v_map: float64 difference stored float32
        for u in range(W):
            if some and skip[v, u]:
                continue
            zc = z[v + 1, u + 1]
            zl, zr, zu, zd = z[v + 1, u], z[v + 1, u + 2], z[v, u + 1], z[v + 2, u + 1]
            if dag:
                # the neighbours' laplacian powers (0 beyond the image, as soft_min pads)
                pl = pow_h[v, u - 1] if u > 0 else zero
                pr = pow_h[v, u + 1] if u < W - 1 else zero
                pu = pow_v[v - 1, u] if v > 0 else zero
                pd = pow_v[v + 1, u] if v < H - 1 else zero
                l1, l2 = _dag_weights(pl, pr)
                l3, l4 = _dag_weights(pu, pd)
                Gu = l1 * (zc - zl) + l2 * (zr - zc)
                Gv = l3 * (zc - zu) + l4 * (zd - zc)
            else:  # get_filter: the central difference, halved
                Gu = (zr - zl) / np.float32(2.0)
                Gv = (zd - zu) / np.float32(2.0)
            um = np.float32(np.float64(np.float32(u + 1)) - u0)  # u_map
            nx = np.float32(np.float64(Gu) * fx)  # float32 gradient times the float64 focal length
            ny = np.float32(np.float64(Gv) * fy)
            nz = -((zc + vm * Gv) + um * Gu)
            # vector_normalization: the float32 sum of squares' square root, plus eps
            mag = np.float32(math.sqrt((nx * nx + ny * ny) + nz * nz)) + _EPS
            out[v, u, 0] = nx / mag
            out[v, u, 1] = ny / mag
            out[v, u, 2] = nz / mag


@njit(cache=True, nogil=True)
def _mrf(z, raw, out):
    # MRF_optim (d2nt_v3): each pixel takes the normal of the neighbour (or itself) of least
    # DLF-alpha laplacian |4 z - up - left - right - down| (filter2D's order of terms), the first
    # of left, right, up, down, self on a tie (argmin); no neighbour beyond the image
    H, W = out.shape[0], out.shape[1]
    lap = np.empty((H, W), dtype=np.float32)
    for v in range(H):
        for u in range(W):
            lap[v, u] = abs(((((-z[v, u + 1]) + (-z[v + 1, u])) + np.float32(4.0) * z[v + 1, u + 1])
                             + (-z[v + 1, u + 2])) + (-z[v + 2, u + 1]))
    for v in range(H):
        for u in range(W):
            best, vv, uu = np.float32(np.inf), v, u
            if u > 0 and lap[v, u - 1] < best:
                best, vv, uu = lap[v, u - 1], v, u - 1
            if u < W - 1 and lap[v, u + 1] < best:
                best, vv, uu = lap[v, u + 1], v, u + 1
            if v > 0 and lap[v - 1, u] < best:
                best, vv, uu = lap[v - 1, u], v - 1, u
            if v < H - 1 and lap[v + 1, u] < best:
                best, vv, uu = lap[v + 1, u], v + 1, u
            if lap[v, u] < best:
                vv, uu = v, u
            for c in range(3):
                out[v, u, c] = raw[vv, uu, c]


@njit(cache=True, nogil=True)
def _near_void(depth):
    # (H, W) bool: the pixels whose 3x3 neighbourhood (clamped at the border) touches a pixel
    # without a surface (the ones :func:`_mask_void` zeroes)
    H, W = depth.shape
    near = np.zeros((H, W), dtype=np.bool_)
    for v in range(H):
        for u in range(W):
            if depth[v, u] > 0:
                continue
            for vv in range(max(v - 1, 0), min(v + 2, H)):
                for uu in range(max(u - 1, 0), min(u + 2, W)):
                    near[vv, uu] = True
    return near


@njit(cache=True, nogil=True)
def _mask_void(depth, out):
    # zero where the 3x3 neighbourhood (clamped at the border) touches a pixel without a surface
    H, W = depth.shape
    for v in range(H):
        for u in range(W):
            if depth[v, u] > 0:
                continue
            for vv in range(max(v - 1, 0), min(v + 2, H)):
                for uu in range(max(u - 1, 0), min(u + 2, W)):
                    out[vv, uu, 0] = 0.0
                    out[vv, uu, 1] = 0.0
                    out[vv, uu, 2] = 0.0


def to_float16(values: np.ndarray) -> np.ndarray:
    """``values`` (float32, any shape) rounded to float16, the same bits as numpy's
    ``values.astype(np.float16)`` (round to nearest, ties to even; overflow to signed infinity;
    subnormals and signed zeros kept; NaN stays NaN with its payload's top bits) by one compiled
    pass: numpy's conversion took 0.06-0.15 s for a frame's six normal maps (9.5 M values), this
    one 0.012 s. All 2**32 float32 bit patterns were compared with numpy 2.4 once: none differ."""
    values = np.ascontiguousarray(values, dtype=np.float32)
    out = np.empty(values.shape, dtype=np.uint16)
    _half_bits(values.reshape(-1).view(np.uint32), out.reshape(-1))
    return out.view(np.float16)


@njit(cache=True, nogil=True)
def _half_bits(f32, h16):
    # float32 bit patterns -> float16 bit patterns, numpy's npy_floatbits_to_halfbits step for step
    for i in range(len(f32)):
        f = np.uint32(f32[i])
        sign = (f & np.uint32(0x80000000)) >> np.uint32(16)
        exp = f & np.uint32(0x7F800000)
        sig = f & np.uint32(0x007FFFFF)
        if exp >= np.uint32(0x47800000):
            # 1. too large for a half: infinity; NaN keeps the top of its payload and stays NaN
            if exp == np.uint32(0x7F800000) and sig != 0:
                h = np.uint32(0x7C00) + (sig >> np.uint32(13))
                if h == np.uint32(0x7C00):
                    h += np.uint32(1)
                h16[i] = np.uint16(sign + h)
            else:
                h16[i] = np.uint16(sign + np.uint32(0x7C00))
        elif exp <= np.uint32(0x38000000):
            # 2. below the smallest normal half: a subnormal (or zero), the implicit bit made
            #    explicit and shifted by the missing exponent, then rounded ties-to-even
            if exp < np.uint32(0x33000000):
                h16[i] = np.uint16(sign)
                continue
            e = exp >> np.uint32(23)
            s = np.uint32(0x00800000) + sig
            s = s >> (np.uint32(113) - e)
            # the bits the shift dropped count for the tie test too
            if (s & np.uint32(0x3FFF)) != np.uint32(0x1000) or (f & np.uint32(0x7FF)) != 0:
                s += np.uint32(0x1000)
            h16[i] = np.uint16(sign + (s >> np.uint32(13)))
        else:
            # 3. a normal half: rebias the exponent, round the significand ties-to-even (a carry
            #    into the exponent is the right result, up to infinity)
            he = (exp - np.uint32(0x38000000)) >> np.uint32(13)
            if (sig & np.uint32(0x3FFF)) != np.uint32(0x1000):
                sig += np.uint32(0x1000)
            h16[i] = np.uint16(sign + ((sig >> np.uint32(13)) + he))
