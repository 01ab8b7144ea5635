"""Camera and LiDAR visibility masks (Occ3D semantics) by 3D DDA ray traversal.

Semantics
---------
A voxel is *observed* by a sensor when one of the sensor's rays crosses it, or ends in it, before
the first occupied voxel along that ray; the first occupied voxel a ray reaches is itself observed,
everything behind it is not. A ray also stops when it has travelled ``max_range`` metres or when it
leaves the grid. ``mask_lidar`` uses the LiDAR's beams (one ray per channel and azimuth step, up to
``LidarSpec.range_m``); ``mask_camera`` accumulates the rays through the pixel centres of every
camera of the rig (up to the grid's diagonal by default) into one mask.

Frames and units
----------------
Everything is in the grid's frame, the LiDAR frame (x forward, y left, z up, metres): ray origins
in metres, unit directions (any non-zero length is accepted and normalised), ranges in metres.
Voxel ``(i, j, k)`` covers ``[origin + (i, j, k) * vs, origin + (i + 1, j + 1, k + 1) * vs]`` and
has the C-order linear index ``(i * ny + j) * nz + k``. Camera rays are built in the OpenCV optical
frame (x right, y down, z forward) and mapped to the grid frame by ``camera_to_grid``.

Algorithm (Amanatides & Woo 1987)
---------------------------------
Each ray is traversed in *voxel units* (``(p - origin) / vs``, voxel ``(i, j, k)`` is the unit box
``[i, i+1] x [j, j+1] x [k, k+1]``), where the ray parameter ``t`` is the travelled distance in
voxels. The ray is first clipped to the grid box ``[0, n]^3`` by a slab test (``t`` from 0, or
from where it enters when the origin is outside, to where it leaves or reaches ``max_range``);
rays that miss the grid do nothing. From the voxel of the entry point the traversal steps one
voxel at a time along the axis whose next boundary crossing ``tMax`` is nearest, using integer
voxel steps and flat-index increments only. A point exactly on a voxel face belongs to the upper
voxel (``floor``). Ties (a ray through an edge or corner) step x before y before z, so such a ray
marks one of the voxels it only touches at that edge; a ray lying in a voxel face plane marks the
voxels above the plane. Zero direction components give infinite ``tMax``/``tDelta`` (no division
by zero); rays with a non-finite component or a zero direction are skipped. The traversal stops
before entering a voxel at ``t >= t_end``, so a ray ending exactly on a face does not mark the
voxel behind it.

Parallelism
-----------
Ray sets of ``PARALLEL_MIN_RAYS`` rays or more use numba's threads (``prange`` over interleaved
stripes of small ray chunks, so every thread gets near and far rays alike); smaller ones run in
the calling thread. Threads only ever store 1, so concurrent writes to one voxel are benign; a
voxel already marked is not written again (no needless cache-line traffic between cores). All
kernels release the GIL.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import njit, prange

from schemas.grid import GridSpec
from stages.scratch import scratch
from schemas.rig import CameraSpec, LidarSpec, RigConfig

__all__ = [
    "PARALLEL_MIN_RAYS",
    "camera_rays",
    "lidar_directions",
    "ray_mask",
    "sensor_to_lidar",
    "visibility_masks",
    "warmup",
]

# Below this many rays the traversal runs in the calling thread.
PARALLEL_MIN_RAYS = 4096
# Rays per chunk and interleaved stripes of chunks of the parallel loop.
_CHUNK = 256
_STRIPES = 256


# ----------------------------------------------------------------------------------------------
# working layout: 4x4x4 voxel bricks of one cache line, 16x16x16 voxel pages of 4 KiB
# ----------------------------------------------------------------------------------------------
# A ray marching along x through a C-order (X, Y, Z) uint8 volume of 1536 x 1024 x 260 voxels
# jumps 266 KB per step: every step is a cache miss and a TLB miss (~30 ns a step measured).
# The kernels therefore work on a swizzled copy: voxel (i, j, k) sits at
#     idx = TX[i] + TY[j] + TZ[k]
# with the bits of i, j, k interleaved in two levels (4x4x4 voxels = one 64-byte line, 4x4x4
# lines = one 4 KiB page, pages in C order over the padded page grid). Every term is a disjoint
# bit field or a multiple of the page size, so the index is a sum of three small per-axis tables
# (L1-resident) and a DDA step is one table load. Occupancy is stored as bits in the same order
# (word idx >> 6, bit idx & 63: one uint64 per brick, 53 MB at 0.05 m); the observed mask as
# bytes (threads only store 1, the race is benign) plus one "touched" flag per page, so the
# conversion back to C order visits only the pages some ray reached.
_PAGE = 16
_PAGE_BYTES = _PAGE**3


def _axis_tables(shape: tuple[int, int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Per-axis swizzle tables (TX, TY, TZ) and the swizzled buffer size (bytes, whole pages)."""
    px, py, pz = (-(-n // _PAGE) for n in shape)

    def table(n: int, page_stride: int, line_mul: int, voxel_mul: int) -> np.ndarray:
        a = np.arange(n, dtype=np.int64)
        return (a >> 4) * page_stride + ((a >> 2) & 3) * (64 * line_mul) + (a & 3) * voxel_mul

    tx = table(shape[0], py * pz * _PAGE_BYTES, 16, 16)
    ty = table(shape[1], pz * _PAGE_BYTES, 4, 4)
    tz = table(shape[2], _PAGE_BYTES, 1, 1)
    return tx, ty, tz, px * py * pz * _PAGE_BYTES


@njit(parallel=True, cache=True, nogil=True)
def _pack_occupancy(occ, nx, ny, nz, tx, ty, tz, words):
    """OR the bits of the nonzero voxels of flat C-order ``occ`` into swizzled ``words``.

    The 4 voxels k = 4m .. 4m + 3 of a row are 4 consecutive bits of one word: assembled without
    branches, one read-modify-write per 4 voxels. Parallel over blocks of 4 x-slabs: a word (brick)
    holds voxels of one such block only, so no two threads ever update one word."""
    nz4 = nz // 4
    for ib in prange((nx + 3) // 4):
        for i in range(4 * ib, min(4 * ib + 4, nx)):
            for j in range(ny):
                base = (i * ny + j) * nz
                pij = tx[i] + ty[j]
                for m in range(nz4):
                    q = base + 4 * m
                    nib = (
                        np.uint64(occ[q] != 0)
                        | (np.uint64(occ[q + 1] != 0) << np.uint64(1))
                        | (np.uint64(occ[q + 2] != 0) << np.uint64(2))
                        | (np.uint64(occ[q + 3] != 0) << np.uint64(3))
                    )
                    if nib:
                        idx = pij + tz[4 * m]
                        words[idx >> 6] |= nib << np.uint64(idx & 63)
                for k in range(4 * nz4, nz):
                    if occ[base + k] != 0:
                        idx = pij + tz[k]
                        words[idx >> 6] |= np.uint64(1) << np.uint64(idx & 63)


@njit(parallel=True, cache=True, nogil=True)
def _unswizzle_or(sw, sw64, pages, nx, ny, nz, tx, ty, tz, out):
    """OR the swizzled mask ``sw`` into ``out`` (flat C order), one 4x4x4 brick at a time.

    Inside a brick the 4 voxels along z of each (x, y) row are 4 consecutive bytes in both
    layouts (brick offset (x & 3) * 16 + (y & 3) * 4 + (z & 3)), so a brick is 16 runs of 4
    bytes. Bricks of unflagged pages, and bricks no ray reached (their 64 bytes, read as 8
    words, are all zero: most bricks of a LiDAR page), are skipped; the others are OR-ed
    without a branch per voxel (a per-voxel test measured 30 % slower on a camera mask, whose
    reached bricks mix observed and unobserved voxels). Parallel over x-blocks of 4 (disjoint
    rows)."""
    npy = (ny + _PAGE - 1) // _PAGE
    npz = (nz + _PAGE - 1) // _PAGE
    for i4 in prange((nx + 3) // 4):
        i0 = 4 * i4
        ni = min(4, nx - i0)
        for j4 in range((ny + 3) // 4):
            j0 = 4 * j4
            nj = min(4, ny - j0)
            prow = ((i0 >> 4) * npy + (j0 >> 4)) * npz
            sij = tx[i0] + ty[j0]
            for k4 in range((nz + 3) // 4):
                k0 = 4 * k4
                if pages[prow + (k0 >> 4)] == 0:
                    continue
                src = sij + tz[k0]  # a multiple of 64: the brick's first byte
                w = src >> 3
                if (sw64[w] | sw64[w + 1] | sw64[w + 2] | sw64[w + 3]
                        | sw64[w + 4] | sw64[w + 5] | sw64[w + 6] | sw64[w + 7]) == 0:
                    continue
                nk = min(4, nz - k0)
                for xi in range(ni):
                    for yi in range(nj):
                        base = ((i0 + xi) * ny + j0 + yi) * nz + k0
                        s0 = src + xi * 16 + yi * 4
                        for zi in range(nk):
                            out[base + zi] |= sw[s0 + zi]


# ----------------------------------------------------------------------------------------------
# ray traversal kernels
# ----------------------------------------------------------------------------------------------


@njit(cache=True, nogil=True, inline="always")
def _axis_setup(o, d, i, n):
    """Per-axis DDA state for origin coordinate ``o`` and direction ``d`` (voxel units) from voxel
    ``i`` of an axis of ``n`` voxels: (tMax, tDelta, step, voxels left before leaving the grid);
    a zero component gets infinite tMax/tDelta (no division by zero) and never steps."""
    if d > 0.0:
        return (i + 1.0 - o) / d, 1.0 / d, 1, n - 1 - i
    if d < 0.0:
        return (i - o) / d, -1.0 / d, -1, i
    return math.inf, math.inf, 0, n  # never steps along this axis (never the minimum)


@njit(cache=True, nogil=True, inline="always")
def _slab(o, d, n, t0, t1):
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
def _clamp_floor(x, n):
    """Voxel of coordinate x (floor), clamped to [0, n - 1]."""
    i = int(math.floor(x))  # noqa: RUF046 (an int for numba whatever floor returns)
    if i < 0:
        return 0
    if i > n - 1:
        return n - 1
    return i


@njit(cache=True, nogil=True)
def _trace(words, sw, pages, nx, ny, nz, tx, ty, tz, ox, oy, oz, dx, dy, dz, t_range):
    """Traverse one ray (origin o, direction d, both in voxel units; t_range voxels) through the
    swizzled occupancy bits ``words`` and mark the voxels it visits in the swizzled ``sw``."""
    # 0. reject non-finite rays and normalise the direction (t then counts voxels travelled)
    norm = math.sqrt(dx * dx + dy * dy + dz * dz)
    if not (norm > 0.0 and math.isfinite(norm) and math.isfinite(ox + oy + oz) and t_range >= 0.0):
        return
    dx /= norm
    dy /= norm
    dz /= norm
    # 1. clip the ray [0, t_range] to the grid box [0, n]^3 (slab test); a miss does nothing
    t0, t1 = _slab(ox, dx, nx, 0.0, t_range)
    t0, t1 = _slab(oy, dy, ny, t0, t1)
    t0, t1 = _slab(oz, dz, nz, t0, t1)
    if not (t0 <= t1):
        return
    # 2. entry voxel: the one containing the entry point (clamped against rounding at the faces)
    i = _clamp_floor(ox + t0 * dx, nx)
    j = _clamp_floor(oy + t0 * dy, ny)
    k = _clamp_floor(oz + t0 * dz, nz)
    # 3. per axis: t of the next boundary crossing, t between crossings, step, voxels left
    tmx, tdx, sx, lx = _axis_setup(ox, dx, i, nx)
    tmy, tdy, sy, ly = _axis_setup(oy, dy, j, ny)
    tmz, tdz, sz, lz = _axis_setup(oz, dz, k, nz)
    px = tx[i]
    py = ty[j]
    pz = tz[k]
    # 4. march: mark the voxel, stop on the first occupied one, else step to the nearest crossing
    #    (ties: x, then y, then z); stop before a crossing at t >= t1 or when leaving the grid.
    #    (A branch-free axis choice measured slower: its loop-carried dependency chain is as long
    #    as the mispredictions it saves.)
    while True:
        idx = px + py + pz
        if sw[idx] == 0:
            sw[idx] = 1
            pages[idx >> 12] = 1
        if (words[idx >> 6] >> np.uint64(idx & 63)) & np.uint64(1):
            return
        if tmx <= tmy and tmx <= tmz:
            if tmx >= t1 or lx == 0:
                return
            lx -= 1
            tmx += tdx
            i += sx
            px = tx[i]
        elif tmy <= tmz:
            if tmy >= t1 or ly == 0:
                return
            ly -= 1
            tmy += tdy
            j += sy
            py = ty[j]
        else:
            if tmz >= t1 or lz == 0:
                return
            lz -= 1
            tmz += tdz
            k += sz
            pz = tz[k]


@njit(cache=True, nogil=True)
def _rays_serial(words, sw, pages, nx, ny, nz, tx, ty, tz, O, D, t_range):
    """All rays in the calling thread; O is (1, 3) (shared origin) or (N, 3), voxel units."""
    shared = O.shape[0] == 1
    for r in range(D.shape[0]):
        q = 0 if shared else r
        _trace(words, sw, pages, nx, ny, nz, tx, ty, tz,
               O[q, 0], O[q, 1], O[q, 2], D[r, 0], D[r, 1], D[r, 2], t_range)


@njit(parallel=True, cache=True, nogil=True)
def _rays_parallel(words, sw, pages, nx, ny, nz, tx, ty, tz, O, D, t_range):
    """:func:`_rays_serial` over numba's threads: stripe s takes ray chunks s, s + _STRIPES, ...
    (so every thread gets short and long rays alike whatever the threading layer's schedule)."""
    n = D.shape[0]
    shared = O.shape[0] == 1
    nchunks = (n + _CHUNK - 1) // _CHUNK
    for s in prange(_STRIPES):
        for ch in range(s, nchunks, _STRIPES):
            for r in range(ch * _CHUNK, min((ch + 1) * _CHUNK, n)):
                q = 0 if shared else r
                _trace(words, sw, pages, nx, ny, nz, tx, ty, tz,
                       O[q, 0], O[q, 1], O[q, 2], D[r, 0], D[r, 1], D[r, 2], t_range)


# ----------------------------------------------------------------------------------------------
# Python entry points
# ----------------------------------------------------------------------------------------------


def _as_flat_u8(a: np.ndarray) -> np.ndarray:
    """Flat C-order uint8 (nonzero = set) view of a bool/numeric volume; copies only when it must."""
    a = np.asarray(a)
    if a.dtype == np.bool_:
        a = np.ascontiguousarray(a).view(np.uint8)
    elif a.dtype != np.uint8:
        a = (a != 0).view(np.uint8)
    return np.ascontiguousarray(a).reshape(-1)


class _Volume:
    """An occupancy volume packed once into the working layout, tracing ray sets into swizzled
    masks (see "working layout" above)."""

    def __init__(self, occupied: np.ndarray, grid: GridSpec):
        self.grid = grid
        self.shape = tuple(int(s) for s in grid.shape)
        if np.shape(occupied) != self.shape:
            raise ValueError(f"occupied has shape {np.shape(occupied)}, the grid {self.shape}")
        self.tx, self.ty, self.tz, self.size = _axis_tables(self.shape)
        # occupancy bits in swizzled order (one pass over the volume)
        self.words = scratch("occupancy_bits", self.size // 64, np.uint64, zero=True)
        _pack_occupancy(_as_flat_u8(occupied), *self.shape, self.tx, self.ty, self.tz, self.words)

    def new_mask(self) -> tuple[np.ndarray, np.ndarray]:
        """An empty swizzled mask and its page flags: a per-thread scratch buffer, zeroed, whose
        pages stay mapped between frames (see :mod:`stages.scratch`)."""
        return (scratch("swizzled_mask", self.size, np.uint8, zero=True),
                scratch("swizzled_pages", self.size // _PAGE_BYTES, np.uint8, zero=True))

    def trace(self, mask: tuple[np.ndarray, np.ndarray], origins, directions, max_range: float) -> None:
        """Mark the voxels the rays visit (metres, grid frame) in the swizzled ``mask``."""
        D = np.ascontiguousarray(directions, dtype=np.float64).reshape(-1, 3)
        if len(D) == 0:
            return
        O = np.ascontiguousarray(origins, dtype=np.float64).reshape(-1, 3)
        if len(O) not in (1, len(D)):
            raise ValueError(f"origins must be (3,) or ({len(D)}, 3), got {np.shape(origins)}")
        t_range = float(max_range) / self.grid.voxel_size
        if math.isnan(t_range):
            raise ValueError(f"max_range must be a number, got {max_range!r}")
        # metres -> voxel units: origins shifted and scaled; unit directions are unchanged, so the
        # ray parameter counts voxels and the range is max_range / vs voxels
        O = (O - np.asarray(self.grid.origin, dtype=np.float64)) / self.grid.voxel_size
        parallel = len(D) >= PARALLEL_MIN_RAYS and numba.get_num_threads() > 1
        kernel = _rays_parallel if parallel else _rays_serial
        kernel(self.words, mask[0], mask[1], *self.shape, self.tx, self.ty, self.tz, O, D, t_range)

    def or_into(self, mask: tuple[np.ndarray, np.ndarray], out: np.ndarray) -> np.ndarray:
        """OR the swizzled ``mask`` into the C-order uint8 volume ``out`` (returned)."""
        _unswizzle_or(mask[0], mask[0].view(np.uint64), mask[1], *self.shape, self.tx, self.ty, self.tz,
                      out.reshape(-1))
        return out


def _checked_out(out: np.ndarray | None, shape) -> np.ndarray:
    if out is None:
        return np.zeros(shape, dtype=np.uint8)
    if out.shape != tuple(shape) or out.dtype != np.uint8 or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous uint8 array of shape {tuple(shape)}")
    return out


def ray_mask(
    occupied: np.ndarray,
    grid: GridSpec,
    origins: np.ndarray,
    directions: np.ndarray,
    max_range: float,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """uint8 (X, Y, Z) mask (1 = observed) of the voxels the rays visit before/at the first
    occupied voxel (see the module docstring for the exact rules).

    ``occupied`` (X, Y, Z) of ``grid.shape``, bool or numeric (nonzero = occupied); ``origins``
    (3,) shared or (N, 3) per ray and ``directions`` (N, 3) in the grid frame (metres; directions
    are normalised here); ``max_range`` metres travelled from the origin. ``out`` (uint8,
    C-contiguous, same shape) is OR-ed into and returned when given.
    """
    shape = tuple(int(s) for s in grid.shape)
    out = _checked_out(out, shape)
    # 1. pack the occupancy, 2. trace into a swizzled mask, 3. OR it into out in C order
    vol = _Volume(occupied, grid)
    mask = vol.new_mask()
    vol.trace(mask, origins, directions, max_range)
    return vol.or_into(mask, out)


def lidar_directions(lidar: LidarSpec) -> np.ndarray:
    """(channels * steps, 3) unit beam directions in the LiDAR frame (x fwd, y left, z up).

    ``steps = points_per_frame // channels`` azimuths evenly over 360 degrees, starting at 0
    (forward, +x) and turning counter-clockwise (towards +y); channel-major order: row
    ``c * steps + a`` is channel ``c`` (``beam_elevations_deg[c]``) at azimuth step ``a``.
    """
    steps = max(lidar.points_per_frame // lidar.channels, 1)
    elev = np.radians(np.asarray(lidar.beam_elevations_deg, dtype=np.float64))[:, None]
    azim = (2.0 * np.pi / steps) * np.arange(steps, dtype=np.float64)[None, :]
    # spherical -> cartesian, (channels, steps) then flattened channel-major
    d = np.stack(
        np.broadcast_arrays(np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim), np.sin(elev)), axis=-1
    )
    return np.ascontiguousarray(d.reshape(-1, 3))


def camera_rays(camera: CameraSpec, camera_to_grid: np.ndarray, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Rays through the pixel centres of every ``stride``-th row and column of a camera.

    ``camera_to_grid`` is the 4x4 pose of the OpenCV optical frame (x right, y down, z forward)
    in the grid frame. Returns the camera centre (3,) and unit directions (N, 3) in the grid
    frame, row-major over the sampled pixels (row v outer, column u inner).
    """
    if stride < 1:
        raise ValueError(f"stride must be >= 1, got {stride}")
    K = np.asarray(camera.intrinsics, dtype=np.float64)
    T = np.asarray(camera_to_grid, dtype=np.float64)
    # 1. pixel centres (u + 0.5, v + 0.5) -> optical-frame rays ((u - cx) / fx, (v - cy) / fy, 1)
    u = np.arange(0, camera.width, stride, dtype=np.float64) + 0.5
    v = np.arange(0, camera.height, stride, dtype=np.float64) + 0.5
    x = (u - K[0, 2]) / K[0, 0]
    y = (v - K[1, 2]) / K[1, 1]
    d = np.empty((len(v), len(u), 3), dtype=np.float64)
    d[..., 0] = x[None, :]
    d[..., 1] = y[:, None]
    d[..., 2] = 1.0
    d = d.reshape(-1, 3)
    # 2. normalise, then rotate into the grid frame; the origin is the pose's translation
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d = d @ T[:3, :3].T
    return T[:3, 3].copy(), np.ascontiguousarray(d)


def sensor_to_lidar(rig: RigConfig) -> dict[str, np.ndarray]:
    """4x4 poses in the LiDAR frame, by sensor name: each camera's OpenCV optical frame
    (``inv(lidar.sensor_to_ego()) @ camera.camera_to_ego()``) and the LiDAR itself (identity)."""
    ego_to_lidar = np.linalg.inv(np.asarray(rig.lidar.sensor_to_ego(), dtype=np.float64))
    out = {cam.name: ego_to_lidar @ np.asarray(cam.camera_to_ego(), dtype=np.float64) for cam in rig.cameras}
    out[rig.lidar.name] = ego_to_lidar @ np.asarray(rig.lidar.sensor_to_ego(), dtype=np.float64)
    return out


def auto_camera_stride(rig: RigConfig, voxel_size: float, distance: float = 25.0) -> int:
    """The camera ray stride (pixels) whose neighbouring rays are at most one voxel apart at
    ``distance`` metres, ``floor(voxel_size * focal_px / distance)``, but at least 2 (reference
    rig: 2 at 0.05 and 0.1 m, 4 at 0.2 m, 8 at 0.4 m). Beyond that distance rays may pass between
    voxels (at 0.05 m from about 14 m); the cost of the camera mask falls with the square of the
    stride (stride 1 at 0.05 m roughly doubles a frame's time)."""
    focal = min((c.focal_px for c in rig.cameras), default=1.0)
    return max(2, int(voxel_size * focal / distance))


def pack_occupancy(occupied: np.ndarray, grid: GridSpec) -> _Volume:
    """The occupancy packed once (bits, brick order) for any number of ray sets."""
    return _Volume(occupied, grid)


def lidar_visibility(packed: _Volume, rig: RigConfig, out: np.ndarray | None = None) -> np.ndarray:
    """mask_lidar: the rig's beams (:func:`lidar_directions`) from the LiDAR origin up to
    ``rig.lidar.range_m``, OR-ed into ``out`` (zeroed uint8 grid volume) or a new volume."""
    out = _checked_out(out, packed.shape)
    mask = packed.new_mask()
    packed.trace(mask, np.zeros(3), lidar_directions(rig.lidar), rig.lidar.range_m)
    return packed.or_into(mask, out)


def camera_visibility(packed: _Volume, rig: RigConfig, camera_stride: int = 1, max_range: float | None = None,
                      out: np.ndarray | None = None) -> np.ndarray:
    """mask_camera: every camera's pixel rays (every ``camera_stride``-th row/column, from the
    camera centre, up to ``max_range`` m; default the grid's diagonal) into one mask."""
    out = _checked_out(out, packed.shape)
    if max_range is None:
        max_range = float(np.linalg.norm(np.asarray(packed.shape, dtype=np.float64) * packed.grid.voxel_size))
    poses = sensor_to_lidar(rig)
    mask = packed.new_mask()
    for cam in rig.cameras:  # one camera's rays at a time into one swizzled mask
        origin, dirs = camera_rays(cam, poses[cam.name], camera_stride)
        packed.trace(mask, origin, dirs, max_range)
    return packed.or_into(mask, out)


def visibility_masks(
    occupied: np.ndarray,
    grid: GridSpec,
    rig: RigConfig,
    camera_stride: int = 1,
    max_range: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(mask_camera, mask_lidar): uint8 (X, Y, Z) Occ3D visibility masks of a frame's occupancy.

    ``occupied`` (X, Y, Z) on ``grid`` (LiDAR frame), nonzero = occupied. The LiDAR mask traces
    :func:`lidar_directions` from the LiDAR origin up to ``rig.lidar.range_m``; the camera mask
    accumulates :func:`camera_rays` (every ``camera_stride``-th pixel row/column) of every camera,
    up to ``max_range`` metres (default: the grid's diagonal, i.e. unlimited within the grid).
    """
    # pack the occupancy once for both ray sets
    packed = pack_occupancy(occupied, grid)
    mask_lidar = lidar_visibility(packed, rig)
    return camera_visibility(packed, rig, camera_stride, max_range), mask_lidar


def warmup() -> None:
    """Compile (or load from numba's cache) every kernel, serial and parallel, on a tiny grid."""
    grid = GridSpec(region_min=(0.0, 0.0, 0.0), region_max=(2.0, 2.0, 2.0), voxel_size=1.0)
    occ = np.zeros(grid.shape, dtype=np.uint8)
    occ[1, 1, 1] = 1
    vol = _Volume(occ, grid)
    mask = vol.new_mask()
    O = np.full((1, 3), 0.5)
    D = np.array([[1.0, 0.5, 0.25]])
    _rays_serial(vol.words, mask[0], mask[1], *vol.shape, vol.tx, vol.ty, vol.tz, O, D, 10.0)
    _rays_parallel(vol.words, mask[0], mask[1], *vol.shape, vol.tx, vol.ty, vol.tz, O, D, 10.0)
    vol.or_into(mask, np.zeros(grid.shape, dtype=np.uint8))
