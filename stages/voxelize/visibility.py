"""Camera and LiDAR visibility masks (Occ3D semantics) by DDA ray traversal.

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
Voxel ``(i, j, k)`` covers ``[origin + (i, j, k) * voxel_size, origin + (i + 1, j + 1, k + 1) * voxel_size]`` and
has the C-order linear index ``(i * ny + j) * nz + k``. Camera rays are built in the OpenCV optical
frame (x right, y down, z forward) and mapped to the grid frame by ``camera_to_grid``. The kernels
work in *voxel units* (``(p - origin) / voxel_size``: voxel ``(i, j, k)`` is the unit box
``[i, i+1] x [j, j+1] x [k, k+1]``).

Working layout: column bits
---------------------------
Occupancy and masks are bits, one ``uint64`` word per 64 voxels of a vertical ``(i, j)`` column:
word ``(i * ny + j) * W + k // 64``, bit ``k % 64``, ``W = ceil(nz / 64)`` words a column (63 MB
at 0.05 m, against 409 MB for a byte a voxel). A ray's voxels in one column are a run of bits of
one or two words, so marking them is a few word operations whatever their number, and the
occupancy of a column is read once for every ray of a fan that crosses it. Masks are converted
back to C-order bytes once, after every ray set: whole (:func:`_unpack_or`) or a block of columns
at a time (:func:`_block_stream`, a chunk of the store). Both conversions go through a flat
bit stream in C order (numpy's ``packbits`` one way, one multiply per eight voxels the other), so
they run at memory speed.

Algorithm 1: 3D DDA (any rays; Amanatides & Woo 1987)
-----------------------------------------------------
Each ray is traversed in voxel units, where the ray parameter ``t`` is the travelled distance in
voxels. The ray is first clipped to the grid box ``[0, n]^3`` by a slab test (``t`` from 0, or
from where it enters when the origin is outside, to where it leaves or reaches ``max_range``);
rays that miss the grid do nothing (:mod:`carlaocc.stages.voxelize.dda` holds the clipping and stepping
shared with the ray metrics). From the voxel of the entry point the traversal steps one
voxel at a time along the axis whose next boundary crossing ``tMax`` is nearest. A point exactly
on a voxel face belongs to the upper voxel (``floor``). Ties (a ray through an edge or corner)
step x before y before z, so such a ray marks one of the voxels it only touches at that edge; a
ray lying in a voxel face plane marks the voxels above the plane. Zero direction components give
infinite ``tMax``/``tDelta`` (no division by zero); rays with a non-finite component or a zero
direction are skipped. The traversal stops before entering a voxel at ``t >= t_end``, so a ray
ending exactly on a face does not mark the voxel behind it.

Algorithm 2: vertical fans (the rig's cameras and LiDAR)
--------------------------------------------------------
The cameras of the rig are level in the LiDAR frame (they turn only about its z,
``carlaocc.schemas.rig``; an ego pitched or rolled on a slope tilts the LiDAR, the cameras and the
grid together), so the rays of one image column
lie in one vertical plane through the camera centre: they share the origin and the horizontal
direction ``h`` and differ only in their slope ``m`` (rise per unit of horizontal distance ``r``).
The LiDAR's channels at one azimuth form the same kind of fan. All rays of a fan cross the same
sequence of ``(i, j)`` columns, so one 2D DDA along ``h`` serves the whole fan; in a column
crossed over ``[r_in, r_out]``, ray ``m`` visits the voxels whose z-interval meets
``(oz + m r_in, oz + m r_out)`` -- exactly the voxels its own 3D DDA visits in that column, up
to the tie rule -- in order of increasing ``r``, and stops at the first occupied one. Each column
then costs a few word operations instead of a step per ray and voxel:

1. Rays are kept sorted by slope; in a column both ends of a ray's voxel range grow with ``m``,
   so the rays still alive form a few runs of consecutive indices and everything below is a
   search on monotone sequences.
2. Rays that end in the column (``max_range``) are at the ends of a run (the range limit in ``r``,
   ``max_range / sqrt(1 + m^2)``, falls with ``|m|``) and are traced one by one; rays that left
   the grid through its top or bottom are a prefix and a suffix and are dropped.
3. The occupied runs of the column inside the run's voxel range are found with bit scans. For
   each occupied run ``[p, q]``, the rays whose range lies wholly below ``p`` are free; the rays
   whose range reaches into ``[p, q]`` (a binary search each side) are traced one by one: they
   stop at their first occupied voxel and leave the fan. The common case goes first: when no
   ray of the run ends in the column (the range limit is smallest at the run's ends) and the
   run's range -- from its first ray's lowest cell to its last ray's highest -- lies in the grid
   with no occupied cell (one bit scan), the whole run is free and that range is its union.
4. Free rays mark their voxel ranges. Where neighbouring rays are less than a voxel apart over
   the whole column (``max gap between slopes * r_out < 1``: near the sensor) the union of a free
   run's ranges is one interval, marked with a few word operations.
5. Farther out (the *sparse* part of the fan, from the first column where that product reaches
   1 to the fan's end) a free ray's cells differ from column to column, but slowly: a ray of
   slope ``m`` changes cells about every ``1 / |m|`` voxels of ``r``. There each live ray keeps
   its cells ``lo..hi``, a count per cell says how many live rays cover it, and the covered
   cells are kept as column words ``U``: a column marks ``U`` (W word operations) instead of
   recomputing every ray. A ray is recomputed -- with the very floor/ceil expressions of steps
   1-3 -- only from the column where its cells may change: the distance where its lower end
   reaches the next cell face or its upper end passes it, ``(face - oz) / m``, less a margin far
   above rounding, files it in a bucket of one voxel of ``r`` (or in the next column's list when
   that distance is already reached); its counts then move by the cells that changed (usually
   one). Rays that end, hit or leave the grid are taken out of the counts. A column's near end
   is the last one's far end (the same float ``r``), so a ray's cells in the next column begin
   with the cell ``P`` of its height at this column's far end and stay ``P`` alone until the
   height reaches P's other face. When a refresh finds the ray in ``P`` and one more cell (it
   is crossing a face: a rising ray rose into ``P`` within this column, a falling one's
   near end is still in the cell above), it does not wait for the next column to drop that
   cell: the ray is kept as ``P`` from now on and the other cell goes into a list of pending
   decrements, applied first thing in the next column (its bit of ``U`` still counts here).
   That is one refresh for each face a ray crosses instead of two. The cells marked are those
   of steps 3-4 bit for bit (tested against every ray traced in every column); on the default
   rig at 0.05 m, on an empty grid, the two front cameras' far fields recompute about 32 M rays
   instead of 180 M ray-columns without the pending decrements, which spare up to half of
   those refreshes (the second one of each face crossed).

The result equals the union of the rays' 3D DDA traversals except at ties, which the two resolve
differently: a ray through a voxel edge, or a fan whose origin lies exactly on a horizontal voxel
face (the DDA starts in the voxel above, a falling fan ray in the voxel below). Both stay in the
tests' tolerance band; on a default 0.05 m frame 5e-5 of the camera mask's voxels differ. Work grows with the columns
the fans cross and the rays far from the sensor, not with the voxels every ray visits: every
pixel of the six cameras at 0.05 m (3.2 M rays) costs about what every second pixel does
(``benchmarks/bench_voxelize.py`` measures both algorithms on the same rays).

Parallelism
-----------
Ray sets of ``PARALLEL_MIN_RAYS`` rays or more (fan sets of ``PARALLEL_MIN_FANS`` fans) use
numba's threads (``prange`` over interleaved stripes, so every thread gets near and far work
alike); smaller ones run in the calling thread. Threads OR their words into the mask atomically,
and only when a word would change. All kernels release the GIL.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from numba import njit, prange, types
from numba.core import cgutils
from numba.cpython.unsafe.numbers import leading_zeros, trailing_zeros
from numba.extending import intrinsic

from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.rig import CameraSpec, LidarSpec, RigConfig
from carlaocc.stages.scratch import scratch
from carlaocc.stages.voxelize.dda import axis_setup, clamp_floor, slab

__all__ = [
    "PARALLEL_MIN_FANS",
    "PARALLEL_MIN_RAYS",
    "Fans",
    "camera_fans",
    "camera_rays",
    "fan_mask",
    "lidar_directions",
    "lidar_fans",
    "ray_mask",
    "sensor_to_lidar",
    "visibility_masks",
    "warmup",
]

# Below this many rays (fans) the traversal runs in the calling thread.
PARALLEL_MIN_RAYS = 4096
PARALLEL_MIN_FANS = 64
# Rays per chunk and interleaved stripes of chunks of the parallel loops.
_CHUNK = 256
_STRIPES = 256

_ONES = np.uint64(0xFFFFFFFFFFFFFFFF)


# ----------------------------------------------------------------------------------------------
# bits of a column
# ----------------------------------------------------------------------------------------------


@intrinsic
def _atomic_or(typingctx, arr, idx, val):
    """``arr[idx] |= val`` as one atomic read-modify-write (LLVM ``atomicrmw or``)."""
    sig = types.void(arr, idx, val)

    def codegen(context, builder, signature, args):
        aryty = signature.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, [args[1]])
        value = context.cast(builder, args[2], signature.args[2], aryty.dtype)
        builder.atomic_rmw("or", ptr, value, "monotonic")
        return context.get_dummy_value()

    return sig, codegen


@njit(cache=True, nogil=True, inline="always")
def _or_word(mask, w, bits):
    """OR ``bits`` into ``mask[w]``, atomically and only when that changes the word (most words
    a ray reaches near a sensor are already set: no needless cache-line traffic between threads)."""
    if (mask[w] & bits) != bits:
        _atomic_or(mask, w, bits)


@njit(cache=True, nogil=True)
def _range_bits(lo, hi):
    """Bits ``lo..hi`` of a word (``0 <= lo <= hi <= 63``)."""
    return (_ONES >> np.uint64(63 - (hi - lo))) << np.uint64(lo)


@njit(cache=True, nogil=True, inline="always")
def _mark_range(acc, lo, hi):
    """Set cells ``lo..hi`` (``lo <= hi``) of the column accumulator ``acc`` (W words)."""
    q0 = lo >> 6
    q1 = hi >> 6
    for q in range(q0, q1 + 1):
        a = lo - 64 * q if q == q0 else 0
        b = hi - 64 * q if q == q1 else 63
        acc[q] |= _range_bits(a, b)


@njit(cache=True, nogil=True, inline="always")
def _next_occupied(occ, cb, k, hi):
    """The lowest occupied cell in ``[k, hi]`` of the column whose words start at ``cb``, or -1."""
    if k > hi:
        return -1
    q = k >> 6
    w = occ[cb + q] & (_ONES << np.uint64(k & 63))
    while True:
        if w != 0:
            c = 64 * q + trailing_zeros(w)
            return c if c <= hi else -1
        q += 1
        if 64 * q > hi:
            return -1
        w = occ[cb + q]


@njit(cache=True, nogil=True, inline="always")
def _next_free(occ, cb, k, hi):
    """The lowest free cell in ``[k, hi]`` of the column, or ``hi + 1``."""
    q = k >> 6
    w = ~occ[cb + q] & (_ONES << np.uint64(k & 63))
    while True:
        if w != 0:
            c = 64 * q + trailing_zeros(w)
            return c if c <= hi else hi + 1
        q += 1
        if 64 * q > hi:
            return hi + 1
        w = ~occ[cb + q]


# ----------------------------------------------------------------------------------------------
# layout: C-order bytes <-> column bits
# ----------------------------------------------------------------------------------------------


@njit(parallel=True, cache=True, nogil=True)
def _columns_from_stream(stream, ncol, nz, W, words):
    """Column bits ``words`` (ncol * W) from ``stream``: the voxels' bits in flat C order (bit
    ``g % 64`` of word ``g // 64`` is voxel ``g = column * nz + k``, as ``np.packbits(...,
    bitorder="little")`` lays them out, plus one word of padding). Column c's word q is the 64
    bits from ``c * nz + 64 q``: two words of the stream shifted together, cut to the column's
    last ``nz - 64 q`` bits. Parallel over columns."""
    for c in prange(ncol):
        for q in range(W):
            s = c * nz + 64 * q
            i = s >> 6
            sh = s & 63
            w = stream[i] >> np.uint64(sh)
            if sh != 0:
                w |= stream[i + 1] << np.uint64(64 - sh)
            nb = nz - 64 * q
            if nb < 64:
                w &= (np.uint64(1) << np.uint64(nb)) - np.uint64(1)
            words[c * W + q] = w


def _bit_stream(flat_u8: np.ndarray) -> np.ndarray:
    """The bits of flat bytes (nonzero = 1) in order, little-endian within each byte, as uint64
    words with one word of padding (numpy's packbits: memory speed)."""
    packed = np.packbits(flat_u8, bitorder="little")
    n = len(packed) // 8 + 2
    stream = np.zeros(8 * n, np.uint8)
    stream[:len(packed)] = packed
    return stream.view(np.uint64)


@njit(parallel=True, cache=True, nogil=True)
def _unpack_or(mask, ncol, nz, W, out):
    """OR the column bits ``mask`` into flat C-order bytes ``out`` (ncol * nz, 1 = set): zero words
    are skipped, full ones written without a per-voxel shift. Parallel over columns."""
    for c in prange(ncol):
        base = c * nz
        for q in range(W):
            w = mask[c * W + q]
            if w == 0:
                continue
            k0 = 64 * q
            k1 = min(k0 + 64, nz)
            if w == _ONES:
                for k in range(k0, k1):
                    out[base + k] = 1
            else:
                for k in range(k0, k1):
                    out[base + k] |= np.uint8((w >> np.uint64(k - k0)) & np.uint64(1))


@njit(cache=True, nogil=True)
def _block_stream(mask, ny, i0, j0, bx, by, nz, W, stream):
    """The columns (i0 .. i0 + bx) x (j0 .. j0 + by) of the column bits ``mask`` as one flat bit
    stream in C order (bit ``g % 64`` of ``stream[g // 64]`` is voxel ``g = (xi * by + yj) * nz +
    k`` of the block), ORed into ``stream`` (zeroed, at least ``bx * by * nz / 64 + 1`` words):
    each nonzero column word lands shifted across two stream words. Returns the number of
    nonzero words read (0: the block is empty)."""
    nonzero = 0
    for xi in range(bx):
        for yj in range(by):
            src = ((i0 + xi) * ny + j0 + yj) * W
            base = (xi * by + yj) * nz
            for q in range(W):
                w = mask[src + q]
                if w == 0:
                    continue
                nb = nz - 64 * q
                if nb < 64:  # (a mask never sets bits above the grid; cut them anyway)
                    w &= (np.uint64(1) << np.uint64(nb)) - np.uint64(1)
                nonzero += 1
                s = base + 64 * q
                i = s >> 6
                sh = s & 63
                stream[i] |= w << np.uint64(sh)
                if sh != 0:
                    stream[i + 1] |= w >> np.uint64(64 - sh)
    return nonzero


# eight bits -> eight bytes: bit i of a byte to bit 0 of byte i (_stream_bytes)
_SPREAD7 = np.uint64(0x0002040810204081)  # bit i to bits i + 7 m, m = 0..7: byte m gets bit m at its bit 0
_BYTE_LOWS = np.uint64(0x0101010101010101)


@njit(cache=True, nogil=True)
def _stream_bytes(stream8, n8, out64):
    """Bytes (0/1) of the first ``8 * n8`` bits of a bit stream (``stream8``: its bytes): eight
    voxels per uint64 store, bit ``i`` of a stream byte becoming byte ``i`` of the store (little
    endian). No table lookup, so the loop vectorizes (about 5x faster than a 256-entry table)."""
    for i in range(n8):
        b = np.uint64(stream8[i])
        # bits 0-6: one multiply copies bit i to positions i + 7 m (distinct for i < 7, so no
        # carries); the byte mask keeps position 8 m, i.e. bit m in byte m. Bit 7 goes to byte 7
        # by a shift (its copies would collide with bit 0's)
        low = ((b & np.uint64(0x7F)) * _SPREAD7) & _BYTE_LOWS
        out64[i] = low | ((b >> np.uint64(7)) << np.uint64(56))


# ----------------------------------------------------------------------------------------------
# algorithm 1: 3D DDA of single rays
# ----------------------------------------------------------------------------------------------


@njit(cache=True, nogil=True)
def _trace(occ, mask, nx, ny, nz, W, ox, oy, oz, dx, dy, dz, t_range):
    """Traverse one ray (origin o, direction d, both in voxel units; t_range voxels) through the
    occupancy column bits ``occ`` and mark the voxels it visits in the column bits ``mask``."""
    # 0. reject non-finite rays and normalise the direction (t then counts voxels travelled)
    norm = math.sqrt(dx * dx + dy * dy + dz * dz)
    if not (norm > 0.0 and math.isfinite(norm) and math.isfinite(ox + oy + oz) and t_range >= 0.0):
        return
    dx /= norm
    dy /= norm
    dz /= norm
    # 1. clip the ray [0, t_range] to the grid box [0, n]^3 (slab test); a miss does nothing
    t0, t1 = slab(ox, dx, nx, 0.0, t_range)
    t0, t1 = slab(oy, dy, ny, t0, t1)
    t0, t1 = slab(oz, dz, nz, t0, t1)
    if not (t0 <= t1):
        return
    # 2. entry voxel: the one containing the entry point (clamped against rounding at the faces)
    i = clamp_floor(ox + t0 * dx, nx)
    j = clamp_floor(oy + t0 * dy, ny)
    k = clamp_floor(oz + t0 * dz, nz)
    # 3. per axis: t of the next boundary crossing, t between crossings, step, voxels left
    tmx, tdx, sx, lx = axis_setup(ox, dx, i, nx)
    tmy, tdy, sy, ly = axis_setup(oy, dy, j, ny)
    tmz, tdz, sz, lz = axis_setup(oz, dz, k, nz)
    # 4. march: mark the voxel (bits gathered per word in a register), stop on the first occupied
    #    one, else step to the nearest crossing (ties: x, then y, then z); stop before a crossing
    #    at t >= t1 or when leaving the grid
    col = i * ny + j
    w = col * W + (k >> 6)
    occw = occ[w]
    acc = np.uint64(0)
    while True:
        bit = np.uint64(1) << np.uint64(k & 63)
        acc |= bit
        if occw & bit:
            break
        if tmx <= tmy and tmx <= tmz:
            if tmx >= t1 or lx == 0:
                break
            lx -= 1
            tmx += tdx
            col += sx * ny
        elif tmy <= tmz:
            if tmy >= t1 or ly == 0:
                break
            ly -= 1
            tmy += tdy
            col += sy
        else:
            if tmz >= t1 or lz == 0:
                break
            lz -= 1
            tmz += tdz
            k += sz
        w2 = col * W + (k >> 6)
        if w2 != w:
            _or_word(mask, w, acc)
            acc = np.uint64(0)
            w = w2
            occw = occ[w]
    _or_word(mask, w, acc)


@njit(cache=True, nogil=True)
def _rays_serial(occ, mask, nx, ny, nz, W, O, D, t_range):
    """All rays in the calling thread; O is (1, 3) (shared origin) or (N, 3), voxel units."""
    shared = O.shape[0] == 1
    for r in range(D.shape[0]):
        q = 0 if shared else r
        _trace(occ, mask, nx, ny, nz, W, O[q, 0], O[q, 1], O[q, 2], D[r, 0], D[r, 1], D[r, 2], t_range)


@njit(parallel=True, cache=True, nogil=True)
def _rays_parallel(occ, mask, nx, ny, nz, W, O, D, t_range):
    """:func:`_rays_serial` over numba's threads: stripe s takes ray chunks s, s + _STRIPES, ...
    (so every thread gets short and long rays alike whatever the threading layer's schedule)."""
    n = D.shape[0]
    shared = O.shape[0] == 1
    nchunks = (n + _CHUNK - 1) // _CHUNK
    for s in prange(_STRIPES):
        for ch in range(s, nchunks, _STRIPES):
            for r in range(ch * _CHUNK, min((ch + 1) * _CHUNK, n)):
                q = 0 if shared else r
                _trace(occ, mask, nx, ny, nz, W, O[q, 0], O[q, 1], O[q, 2], D[r, 0], D[r, 1], D[r, 2], t_range)


# ----------------------------------------------------------------------------------------------
# algorithm 2: vertical fans
# ----------------------------------------------------------------------------------------------
# A fan: origin (ox, oy, oz) and unit horizontal direction (hx, hy) in voxel units, slopes M
# ascending; ray v is the line o + r * (hx, hy, M[v]) for horizontal distances r in [0, R[v]].
# In a column crossed over [r_in, r_out] ray v spans z in (oz + M[v] r_in, oz + M[v] r_out) and
# visits the cells lo..hi: lo = floor(lower end), hi = ceil(upper end) - 1 (at least lo).


# Heights (voxel units) are clamped to [-2, 2^40] before they become integer cells: far outside
# the grid either way, and no float -> int overflow for steep rays far away.
_Z_LOW = -2.0
_Z_HIGH = 1099511627776.0


@njit(cache=True, nogil=True, inline="always")
def _floor_cell(z):
    return int(math.floor(min(max(z, _Z_LOW), _Z_HIGH)))  # noqa: RUF046


@njit(cache=True, nogil=True, inline="always")
def _ceil_cell(z):
    return int(math.ceil(min(max(z, _Z_LOW), _Z_HIGH)))  # noqa: RUF046


@njit(cache=True, nogil=True, inline="always")
def _cell_lo(oz, m, r_in, r_out):
    """Lowest cell of a ray's voxel range in the column [r_in, r_out] (not clipped to the grid)."""
    return _floor_cell(min(oz + m * r_in, oz + m * r_out))


@njit(cache=True, nogil=True, inline="always")
def _cell_hi(oz, m, r_in, r_out):
    """Highest cell of a ray's voxel range in the column [r_in, r_out] (not clipped to the grid)."""
    za = oz + m * r_in
    zb = oz + m * r_out
    return max(_ceil_cell(max(za, zb)) - 1, _floor_cell(min(za, zb)))


@njit(cache=True, nogil=True, inline="always")
def _append_run(sa, sb, ns, a, b):
    """Append the run of rays [a, b] to the runs (sa, sb) of length ns, merged with the last one
    when they are adjacent; returns the new length."""
    if ns > 0 and sb[ns - 1] + 1 == a:
        sb[ns - 1] = b
        return ns
    sa[ns] = a
    sb[ns] = b
    return ns + 1


@njit(cache=True, nogil=True, inline="always")
def _below(oz, m, r_in, r_out, bound, upper):
    """The search predicate of :func:`_last_ray`: the ray's highest cell is below ``bound``
    (``upper`` False) or its lowest cell is at most ``bound`` (``upper`` True)."""
    if upper:
        return _cell_lo(oz, m, r_in, r_out) <= bound
    return _cell_hi(oz, m, r_in, r_out) < bound


@njit(cache=True, nogil=True, inline="always")
def _last_ray(oz, M, r_in, r_out, start, b, bound, upper):
    """The last ray index in ``[start, b]`` for which :func:`_below` holds, given that it holds
    for ``start`` (or ``start`` is one before the run) and is monotone (true, then false):
    galloping from ``start`` then bisecting, so a nearby answer -- the usual one -- costs a few
    evaluations."""
    step = 1
    while start + step <= b and _below(oz, M[start + step], r_in, r_out, bound, upper):
        start += step
        step *= 2
    hi_i = min(start + step - 1, b)
    while start < hi_i:
        mid = (start + hi_i + 1) >> 1
        if _below(oz, M[mid], r_in, r_out, bound, upper):
            start = mid
        else:
            hi_i = mid - 1
    return start


@njit(cache=True, nogil=True)
def _rays_column(occ, acc, cb, nz, M, R, a, b, oz, r_in, r_out, sa, sb, ns):
    """Rays a..b of a fan, one by one, in the column whose occupancy words start at ``cb``:
    mark each ray's cells up to its first occupied one (in the ray's order: upwards for a
    rising ray) into ``acc``; append the rays that go on to the runs (sa, sb); returns their
    new count. A ray leaves the fan when it hits, ends (R) or has left the grid vertically."""
    cq = -1  # the word gathered in a register (rays ascend: so do their words)
    cbits = np.uint64(0)
    ra = -1  # the survivors' current run, in registers
    rb = -2
    if ns > 0:
        ns -= 1
        ra = sa[ns]
        rb = sb[ns]
    for v in range(a, b + 1):
        m = M[v]
        r_end = r_out
        dead = False
        if R[v] <= r_out:  # the ray ends in this column
            r_end = R[v]
            dead = True
        za = oz + m * r_in
        zb = oz + m * r_end
        lo = _floor_cell(min(za, zb))
        hi = max(_ceil_cell(max(za, zb)) - 1, lo)
        if hi < 0:
            dead = dead or m <= 0.0  # below the grid and not rising
        elif lo >= nz:
            dead = dead or m >= 0.0  # above the grid and not falling
        else:
            lo = max(lo, 0)
            hi = min(hi, nz - 1)
            q0 = lo >> 6
            q1 = hi >> 6
            if q0 == q1:
                bits = _range_bits(lo & 63, hi & 63)
                o = occ[cb + q0] & bits
                if o != 0:  # hit: keep the cells up to the first occupied one in the ray's order
                    dead = True
                    if m > 0.0:
                        bits &= _ONES >> np.uint64(63 - trailing_zeros(o))
                    elif m < 0.0:
                        bits &= _ONES << np.uint64(63 - leading_zeros(o))
                if q0 != cq:
                    if cq >= 0:
                        acc[cq] |= cbits
                    cq = q0
                    cbits = bits
                else:
                    cbits |= bits
            elif m >= 0.0:  # a range over several words, walked upwards
                for q in range(q0, q1 + 1):
                    bits = _range_bits(lo - 64 * q if q == q0 else 0, hi - 64 * q if q == q1 else 63)
                    o = occ[cb + q] & bits
                    if o != 0:
                        acc[q] |= bits & (_ONES >> np.uint64(63 - trailing_zeros(o)))
                        dead = True
                        break
                    acc[q] |= bits
            else:  # ... downwards
                for q in range(q1, q0 - 1, -1):
                    bits = _range_bits(lo - 64 * q if q == q0 else 0, hi - 64 * q if q == q1 else 63)
                    o = occ[cb + q] & bits
                    if o != 0:
                        acc[q] |= bits & (_ONES << np.uint64(63 - leading_zeros(o)))
                        dead = True
                        break
                    acc[q] |= bits
        if not dead:
            if rb + 1 == v:
                rb = v
            else:
                if ra >= 0:
                    sa[ns] = ra
                    sb[ns] = rb
                    ns += 1
                ra = v
                rb = v
    if cq >= 0:
        acc[cq] |= cbits
    if ra >= 0:
        sa[ns] = ra
        sb[ns] = rb
        ns += 1
    return ns


@njit(cache=True, nogil=True, inline="always")
def _cell_bounds(oz, m, r_in, r_out):
    """A ray's z-interval ends in the column [r_in, r_out], clamped as :func:`_floor_cell` clamps:
    (lower, upper); its cells are ``floor(lower) .. max(ceil(upper) - 1, floor(lower))``."""
    za = oz + m * r_in
    zb = oz + m * r_out
    return min(max(min(za, zb), _Z_LOW), _Z_HIGH), min(max(max(za, zb), _Z_LOW), _Z_HIGH)


# Rows of the sparse part's int64 state S (one row per name, max(rays, nz, buckets) wide): per ray
# its lowest and highest cell in the current column, its successor in its bucket's list and
# whether it has left the fan; the two column lists (rays to refresh now / in the next column);
# per cell the number of live rays covering it; per bucket the first ray of its list; the cells
# whose count falls by one at the start of the next column (a ray's end carried over, step 5).
_LO, _HI, _NEXT, _DEAD, _LIST0, _LIST1, _COUNT, _HEAD, _PEND = 0, 1, 2, 3, 4, 5, 6, 7, 8
_SPARSE_ROWS = 9


@njit(cache=True, nogil=True, inline="always")
def _next_change(m, oz, lo, hu):
    """The horizontal distance (voxels) up to which a ray of slope ``m`` keeps its cells
    ``lo = floor(lower end)`` .. ``hu = ceil(upper end) - 1`` of a column, less a margin far above
    rounding (so never beyond the change): a rising ray's lower end reaches ``lo + 1`` at
    ``r_in = (lo + 1 - oz) / m`` and its upper end passes ``hu + 1`` at ``r_out = (hu + 1 - oz) /
    m``; a falling ray's lower end passes below ``lo``, its upper end reaches ``hu``. +inf for a
    level ray; NaN or less than the column's ``r_out`` for degenerate ones (checked every column)."""
    if m > 0.0:
        t = min(lo + 1.0 - oz, hu + 1.0 - oz) / m
    elif m < 0.0:
        t = max(lo - oz, hu - oz) / m
    else:
        return math.inf
    return t - 1e-9 * (abs(t) + (abs(lo) + abs(hu) + abs(oz) + 2.0) / abs(m) + 1.0)


@njit(cache=True, nogil=True)
def _move_cells(S, U, l0, h0, l1, h1, nz):
    """Move one ray's counts (row ``_COUNT`` of S) from cells ``l0..h0`` to ``l1..h1`` (either
    clipped to the grid here; an empty range counts nothing), keeping ``U`` (W words) the set of
    cells whose count is positive. Only the cells that differ change."""
    top = nz - 1
    l0 = max(l0, 0)
    h0 = min(h0, top)
    l1 = max(l1, 0)
    h1 = min(h1, top)
    if l0 > h0:
        l0 = nz
        h0 = top
    if l1 > h1:
        l1 = nz
        h1 = top
    # cells of the old range below and above the new one leave; cells of the new range below and
    # above the old one arrive (a branch-free bit update per cell)
    for part in range(4):
        if part == 0:
            c0, c1, d = l0, min(h0, l1 - 1), -1
        elif part == 1:
            c0, c1, d = max(l0, h1 + 1), h0, -1
        elif part == 2:
            c0, c1, d = l1, min(h1, l0 - 1), 1
        else:
            c0, c1, d = max(l1, h0 + 1), h1, 1
        for c in range(c0, c1 + 1):
            n = S[_COUNT, c] + d
            S[_COUNT, c] = n
            sh = np.uint64(c & 63)
            U[c >> 6] = (U[c >> 6] & ~(np.uint64(1) << sh)) | (np.uint64(n > 0) << sh)


@njit(cache=True, nogil=True, inline="always")
def _count_cell(S, U, c, d):
    """Add ``d`` to the count of cell ``c`` (in the grid) and set its bit of ``U`` to count > 0."""
    n = S[_COUNT, c] + d
    S[_COUNT, c] = n
    sh = np.uint64(c & 63)
    U[c >> 6] = (U[c >> 6] & ~(np.uint64(1) << sh)) | (np.uint64(n > 0) << sh)


@njit(cache=True, nogil=True)
def _sparse_column(M, due, S, U, oz, r_in, r_out, r0, r1, nz, now, nt, bp, npend):
    """Bring the live rays whose cells may have changed up to this column, then count them.

    Gathered into the list row ``now`` (which already holds the ``nt`` rays filed for this
    column): every bucket below the column's far end ``r_out`` (from ``bp``, the first one not
    yet emptied) and the rays of the bucket it ends in that are due by ``r_out``. Each one's
    cells, exactly as :func:`_cell_lo` and :func:`_cell_hi` give them, move its counts if they
    changed; then it is filed where they may change next: the bucket of that distance from
    ``r0``, or the other list row (the next column), or nowhere beyond the footprint's end
    ``r1``. A ray whose cells in the next column are known now -- the single cell of its far
    end, one cell less than here -- is not refreshed there: the cell it leaves goes into the
    ``npend`` pending decrements, applied first thing in the next column. Returns the next
    column's list length, the new ``bp`` and the number of pending decrements."""
    nb = S.shape[1]
    # 0. the cells the rays carried over from the last column left
    for i in range(npend):
        _count_cell(S, U, S[_PEND, i], -1)
    npend = 0
    # 1. gather the due rays
    kb = min(int(r_out - r0), nb - 1)  # noqa: RUF046
    while bp < kb:
        v = S[_HEAD, bp]
        S[_HEAD, bp] = -1
        while v >= 0:
            S[now, nt] = v
            nt += 1
            v = S[_NEXT, v]
        bp += 1
    prev = -1
    v = S[_HEAD, kb]
    while v >= 0:
        w = S[_NEXT, v]
        if due[v] <= r_out:
            if prev < 0:
                S[_HEAD, kb] = w
            else:
                S[_NEXT, prev] = w
            S[now, nt] = v
            nt += 1
        else:
            prev = v
        v = w
    # 2. refresh them
    nxt_row = _LIST1 if now == _LIST0 else _LIST0
    nn = 0
    top = nz - 1
    for i in range(nt):
        v = S[now, i]
        if S[_DEAD, v]:
            continue
        m = M[v]
        zl, zh = _cell_bounds(oz, m, r_in, r_out)
        lo = int(math.floor(zl))  # noqa: RUF046
        hu = int(math.ceil(zh)) - 1  # noqa: RUF046
        hi = max(hu, lo)
        l0 = S[_LO, v]
        h0 = S[_HI, v]
        if lo != l0 or hi != h0:
            S[_LO, v] = lo
            S[_HI, v] = hi
            if 0 <= l0 <= h0 <= top and 0 <= lo <= hi <= top and abs(lo - l0) + abs(hi - h0) == 1:
                # (the common case written out: one end moved by one cell inside the grid)
                c = hi if hi > h0 else (h0 if hi < h0 else (l0 if lo > l0 else lo))
                d = 1 if (hi > h0 or lo < l0) else -1
                n = S[_COUNT, c] + d
                S[_COUNT, c] = n
                sh = np.uint64(c & 63)
                U[c >> 6] = (U[c >> 6] & ~(np.uint64(1) << sh)) | (np.uint64(n > 0) << sh)
            else:
                _move_cells(S, U, l0, h0, lo, hi, nz)
        # the ray's cells in the next column, whose near end is this column's far end: from the
        # cell P of that end, as long as its far end stays in P (until the distance below). When
        # that is P and one more cell of here, the other cell's count falls by one next column
        # and the ray is not refreshed there (the same counts, one refresh less a cell crossed)
        p = int(math.floor(zh if m > 0.0 else zl))  # noqa: RUF046
        if hi == lo + 1 and (p == lo or p == hi):
            c = hi if p == lo else lo
            if 0 <= c <= top:
                S[_PEND, npend] = c
                npend += 1
            S[_LO, v] = p
            S[_HI, v] = p
            t = _next_change(m, oz, p, p)
        else:
            t = _next_change(m, oz, lo, hu)
        if t > r_out:
            if t <= r1:
                bk = int(t - r0)  # noqa: RUF046
                due[v] = t
                S[_NEXT, v] = S[_HEAD, bk]
                S[_HEAD, bk] = v
        else:  # (a change may come in the very next column; or a NaN)
            S[nxt_row, nn] = v
            nn += 1
    return nn, bp, npend


@njit(cache=True, nogil=True)
def _start_sparse(M, due, S, U, ra, rb, nr, oz, r_in, r_out, r0, r1, nz):
    """Enter the sparse part of a fan (its rays at least a voxel apart from here on): no cell
    counted, no bucket filled, then every live ray (runs ``ra``, ``rb``) refreshed as in
    :func:`_sparse_column` from list row ``_LIST0``. Returns the next column's list length (in
    row ``_LIST1``) and number of pending decrements."""
    for c in range(nz):
        S[_COUNT, c] = 0
    for q in range(U.shape[0]):
        U[q] = 0
    for k in range(S.shape[1]):
        S[_HEAD, k] = -1
    nt = 0
    for ru in range(nr):
        for v in range(ra[ru], rb[ru] + 1):
            S[_DEAD, v] = 0
            S[_LO, v] = nz  # (no cells counted yet)
            S[_HI, v] = nz - 1
            S[_LIST0, nt] = v
            nt += 1
    # (every bucket lies beyond this column: bp = the last one, nothing gathered)
    nn, _, npend = _sparse_column(M, due, S, U, oz, r_in, r_out, r0, r1, nz, _LIST0, nt, S.shape[1], 0)
    return nn, npend


@njit(cache=True, nogil=True)
def _retire(S, U, a, b, nz):
    """Rays a..b leave the fan (traced one by one: they hit, or end, in this column): out of the
    counts."""
    for v in range(a, b + 1):
        _move_cells(S, U, S[_LO, v], S[_HI, v], nz, nz - 1, nz)
        S[_DEAD, v] = 1


@njit(cache=True, nogil=True)
def _fan(occ, mask, acc, R, S, due, U, ra, rb, sa, sb, nx, ny, nz, W, ox, oy, oz, hx, hy, M, t_range):
    """Trace one vertical fan (see "Algorithm 2"): origin o and unit horizontal direction h in
    voxel units, slopes ``M`` ascending, rays ``t_range`` voxels long. ``acc`` (W), ``R``, ``ra``,
    ``rb``, ``sa``, ``sb`` (len(M)) are scratch."""
    n = M.shape[0]
    if n == 0 or not (math.isfinite(ox + oy + oz) and t_range >= 0.0):
        return
    # 1. clip the horizontal line to the grid's footprint [0, nx] x [0, ny] (slab test in r)
    r0, r1 = slab(ox, hx, nx, 0.0, math.inf)
    r0, r1 = slab(oy, hy, ny, r0, r1)
    if not (r0 <= r1):
        return
    # 2. 2D DDA state of the entry column; horizontal range limit of each ray; the largest gap
    #    between neighbouring slopes (rays are less than a voxel apart while gmax * r < 1)
    i = clamp_floor(ox + r0 * hx, nx)
    j = clamp_floor(oy + r0 * hy, ny)
    tmx, tdx, sx, lx = axis_setup(ox, hx, i, nx)
    tmy, tdy, sy, ly = axis_setup(oy, hy, j, ny)
    gmax = 0.0
    ns = 0
    for v in range(n):
        m = abs(M[v])  # (1 + m^2 overflows beyond 1e154; libm's hypot is slower)
        R[v] = t_range / (math.sqrt(1.0 + m * m) if m < 1e150 else m)
        if v > 0:
            gmax = max(gmax, M[v] - M[v - 1])
        if R[v] >= r0:  # (a ray ending where it enters marks its entry voxel, as the 3D DDA)
            ns = _append_run(ra, rb, ns, v, v)
    nr = ns
    r_in = r0
    col = i * ny + j
    sparse = False
    nc = 0
    bp = 0
    npend = 0
    now = _LIST0
    # 3. column by column, while some ray is alive
    while nr > 0:
        # (a crossing computed below r_in -- the entry point on a lattice plane, up to rounding
        # -- leaves an empty column: r never runs backwards)
        r_out = max(min(tmx, tmy, r1), r_in)
        cb = col * W
        for q in range(W):
            acc[q] = 0
        dense = gmax * r_out < 1.0
        if not dense:
            if sparse:
                nc, bp, npend = _sparse_column(M, due, S, U, oz, r_in, r_out, r0, r1, nz, now, nc, bp, npend)
                now = _LIST1 if now == _LIST0 else _LIST0
            else:
                nc, npend = _start_sparse(M, due, S, U, ra, rb, nr, oz, r_in, r_out, r0, r1, nz)
                now = _LIST1
                bp = 0
                sparse = True
        ns = 0
        for ru in range(nr):
            a = ra[ru]
            b = rb[ru]
            # 3'. the common case first: no ray of the run ends here (R falls with |m|: its
            #     smallest values are at the run's ends), the run's range [lo of a, hi of b] is in
            #     the grid and free: nothing of 3a-3c applies and 3d marks that range (the very
            #     values the steps below compute)
            if R[a] > r_out and R[b] > r_out:
                lo_c = _cell_lo(oz, M[a], r_in, r_out)
                hi_c = _cell_hi(oz, M[b], r_in, r_out)
                if 0 <= lo_c and hi_c < nz and _next_occupied(occ, cb, lo_c, hi_c) < 0:
                    if dense:
                        _mark_range(acc, lo_c, hi_c)
                    ns = _append_run(sa, sb, ns, a, b)
                    continue
            # 3a. rays ending in this column: at the run's ends, one by one
            a0 = a
            while a <= b and R[a] <= r_out:
                a += 1
            if a > a0:
                if sparse:
                    _retire(S, U, a0, a - 1, nz)
                ns = _rays_column(occ, acc, cb, nz, M, R, a0, a - 1, oz, r_in, r_out, sa, sb, ns)
            b0 = b
            while a <= b and R[b] <= r_out:
                b -= 1
            if b < b0:
                if sparse:
                    _retire(S, U, b + 1, b0, nz)
                ns = _rays_column(occ, acc, cb, nz, M, R, b + 1, b0, oz, r_in, r_out, sa, sb, ns)
            # 3b. rays below the grid and not rising / above it and not falling are done
            while a <= b and M[a] <= 0.0 and _cell_hi(oz, M[a], r_in, r_out) < 0:
                S[_DEAD, a] = 1  # (no cells in the grid: nothing counted)
                a += 1
            while a <= b and M[b] >= 0.0 and _cell_lo(oz, M[b], r_in, r_out) >= nz:
                S[_DEAD, b] = 1
                b -= 1
            if a > b:
                continue
            # 3c. occupied runs [p, q] of the column inside the run's range split it: rays wholly
            #     below p are free, rays reaching into [p, q] are traced one by one
            HI = min(_cell_hi(oz, M[b], r_in, r_out), nz - 1)
            cur = a
            k = max(_cell_lo(oz, M[a], r_in, r_out), 0)
            while cur <= b:
                p = _next_occupied(occ, cb, k, HI)
                if p < 0:
                    break
                q = _next_free(occ, cb, p, HI) - 1
                # the last ray F in [cur - 1, b] whose range lies below p
                F = _last_ray(oz, M, r_in, r_out, cur - 1, b, p, False)
                if F >= cur:
                    # (the dense branch stays written out here and in 3d: behind a shared
                    # helper, numba's code for the fans ran 1.6x slower)
                    if dense:
                        lo_c = max(_cell_lo(oz, M[cur], r_in, r_out), 0)
                        hi_c = min(_cell_hi(oz, M[F], r_in, r_out), nz - 1)
                        if lo_c <= hi_c:
                            _mark_range(acc, lo_c, hi_c)
                    ns = _append_run(sa, sb, ns, cur, F)
                # the last ray G in [F, b] whose range starts at or below q: F + 1 .. G reach
                # into [p, q]
                G = _last_ray(oz, M, r_in, r_out, F, b, q, True)
                if G > F:
                    if sparse:
                        _retire(S, U, F + 1, G, nz)
                    ns = _rays_column(occ, acc, cb, nz, M, R, F + 1, G, oz, r_in, r_out, sa, sb, ns)
                cur = G + 1
                k = q + 1
            # 3d. the rest of the run is free
            if cur <= b:
                if dense:
                    lo_c = max(_cell_lo(oz, M[cur], r_in, r_out), 0)
                    if lo_c <= HI:
                        _mark_range(acc, lo_c, HI)
                ns = _append_run(sa, sb, ns, cur, b)
        # 3e. the column's marks into the mask, the survivors become the runs
        for q in range(W):
            w = acc[q] | U[q] if sparse else acc[q]
            if w != 0:
                _or_word(mask, cb + q, w)
        ra, sa = sa, ra
        rb, sb = sb, rb
        nr = ns
        # 4. next column (ties: x first); stop at the end of the footprint or of every ray
        if tmx <= tmy:
            if tmx >= r1 or lx == 0:
                break
            lx -= 1
            r_in = max(r_in, tmx)
            tmx += tdx
            col += sx * ny
        else:
            if tmy >= r1 or ly == 0:
                break
            ly -= 1
            r_in = max(r_in, tmy)
            tmy += tdy
            col += sy


@njit(cache=True, nogil=True)
def _fan_stripe(occ, mask, nx, ny, nz, W, O, H, M, t_range, first, step):
    """Fans first, first + step, ... of O (F, 3) origins, H (F, 2) horizontal directions and
    M (F, n) ascending slopes (voxel units), with one set of scratch buffers."""
    n = M.shape[1]
    acc = np.zeros(W, np.uint64)
    R = np.empty(n, np.float64)
    # the sparse part's state (its rows: _LO ... _HEAD); buckets of one voxel of r over the
    # footprint's longest chord
    S = np.empty((_SPARSE_ROWS, max(n, nz, nx + ny + 4)), np.int64)
    due = np.empty(n, np.float64)
    U = np.zeros(W, np.uint64)
    ra = np.empty(n, np.int64)
    rb = np.empty(n, np.int64)
    sa = np.empty(n, np.int64)
    sb = np.empty(n, np.int64)
    for f in range(first, H.shape[0], step):
        _fan(occ, mask, acc, R, S, due, U, ra, rb, sa, sb, nx, ny, nz, W, O[f, 0], O[f, 1], O[f, 2], H[f, 0], H[f, 1],
             M[f], t_range)


@njit(cache=True, nogil=True)
def _fans_serial(occ, mask, nx, ny, nz, W, O, H, M, t_range):
    """Every fan in the calling thread."""
    _fan_stripe(occ, mask, nx, ny, nz, W, O, H, M, t_range, 0, 1)


@njit(parallel=True, cache=True, nogil=True)
def _fans_parallel(occ, mask, nx, ny, nz, W, O, H, M, t_range):
    """:func:`_fans_serial` over numba's threads, fans dealt out in interleaved stripes."""
    stripes = min(_STRIPES, H.shape[0])
    for s in prange(stripes):
        _fan_stripe(occ, mask, nx, ny, nz, W, O, H, M, t_range, s, stripes)


# ----------------------------------------------------------------------------------------------
# Python entry points
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Fans:
    """Vertical ray fans: the rays of fan ``f`` start at ``origins[f]`` and run along
    ``(h_x, h_y, m) / sqrt(1 + m^2)`` for ``h = headings[f]`` and each slope ``m`` of
    ``slopes[f]`` (rise per metre of horizontal distance, ascending). Grid frame, metres."""

    origins: np.ndarray  # (F, 3)
    headings: np.ndarray  # (F, 2) unit horizontal directions
    slopes: np.ndarray  # (F, n), each row ascending

    def __post_init__(self):
        O = np.ascontiguousarray(self.origins, dtype=np.float64).reshape(-1, 3)
        H = np.ascontiguousarray(self.headings, dtype=np.float64).reshape(-1, 2)
        M = np.ascontiguousarray(self.slopes, dtype=np.float64)
        if M.ndim != 2 or not (len(O) == len(H) == len(M)):
            raise ValueError(f"fans need (F, 3) origins, (F, 2) headings and (F, n) slopes, got "
                             f"{np.shape(self.origins)}, {np.shape(self.headings)}, {np.shape(self.slopes)}")
        if not (np.isfinite(O).all() and np.isfinite(H).all() and np.isfinite(M).all()):
            raise ValueError("fan origins, headings and slopes must be finite")
        if len(H) and np.abs(np.linalg.norm(H, axis=1) - 1.0).max() > 1e-9:
            raise ValueError("fan headings must be unit horizontal vectors")
        if M.shape[1] > 1 and (np.diff(M, axis=1) < 0).any():
            raise ValueError("the slopes of each fan must be ascending")
        object.__setattr__(self, "origins", O)
        object.__setattr__(self, "headings", H)
        object.__setattr__(self, "slopes", M)

    def __len__(self) -> int:
        return len(self.headings)

    def directions(self) -> np.ndarray:
        """(F * n, 3) unit directions, fan by fan, slopes ascending within a fan."""
        M = self.slopes
        c = 1.0 / np.hypot(1.0, M)
        d = np.stack(np.broadcast_arrays(self.headings[:, 0:1] * c, self.headings[:, 1:2] * c, M * c), axis=-1)
        return np.ascontiguousarray(d.reshape(-1, 3))


def _as_flat_u8(a: np.ndarray) -> np.ndarray:
    """Flat C-order uint8 (nonzero = set) view of a bool/numeric volume; copies only when it must."""
    a = np.asarray(a)
    if a.dtype == np.bool_:
        a = np.ascontiguousarray(a).view(np.uint8)
    elif a.dtype != np.uint8:
        a = (a != 0).view(np.uint8)
    return np.ascontiguousarray(a).reshape(-1)


class _Volume:
    """An occupancy volume packed once into column bits (see "Working layout"), tracing ray sets
    and fans into column-bit masks.

    With ``reuse`` its bits and masks live in per-thread scratch buffers that stay mapped
    between frames (:mod:`carlaocc.stages.scratch`): the next reusing volume of the thread overwrites
    them, as does the next mask of the same name. Without it, they are arrays of its own."""

    def __init__(self, grid: GridSpec, occupied: np.ndarray | None = None, reuse: bool = False):
        self.grid = grid
        self.reuse = reuse
        self.shape = tuple(int(s) for s in grid.shape)
        nx, ny, nz = self.shape
        self.W = (nz + 63) // 64
        self.ncol = nx * ny
        # occupancy bits, packed whole here or slab by slab by the caller (pack_slab)
        size = self.ncol * self.W
        self.words = scratch("occupancy_columns", size, np.uint64) if reuse else np.empty(size, np.uint64)
        if occupied is not None:
            if np.shape(occupied) != self.shape:
                raise ValueError(f"occupied has shape {np.shape(occupied)}, the grid {self.shape}")
            self.pack_slab(0, occupied)

    def pack_slab(self, x0: int, occupied: np.ndarray) -> None:
        """Pack the occupancy of voxels ``[x0, x0 + len(occupied))`` (an x-slab, nonzero =
        occupied) into the column bits."""
        nx, ny, nz = self.shape
        if np.ndim(occupied) != 3 or tuple(np.shape(occupied)[1:]) != (ny, nz) or not 0 <= x0 <= nx - len(occupied):
            raise ValueError(f"an x-slab at {x0} of shape {np.shape(occupied)} does not fit the grid {self.shape}")
        c0 = x0 * ny
        n = len(occupied) * ny
        # 1. the slab's bytes -> a flat bit stream (numpy's packbits); 2. the stream's bits ->
        #    column words (two words shifted together per column word)
        stream = _bit_stream(_as_flat_u8(occupied))
        _columns_from_stream(stream, n, nz, self.W, self.words[c0 * self.W:(c0 + n) * self.W])

    def _to_voxels(self, origins: np.ndarray, max_range: float) -> tuple[np.ndarray, float]:
        t_range = float(max_range) / self.grid.voxel_size
        if math.isnan(t_range):
            raise ValueError(f"max_range must be a number, got {max_range!r}")
        # metres -> voxel units: origins shifted and scaled; unit directions are unchanged, so the
        # ray parameter counts voxels and the range is max_range / voxel_size voxels
        return (origins - np.asarray(self.grid.origin, dtype=np.float64)) / self.grid.voxel_size, t_range

    def new_mask(self, name: str = "mask_columns") -> np.ndarray:
        """An empty column-bit mask: with ``reuse``, the per-thread scratch buffer ``name``,
        zeroed (the next mask of that name reuses it); else a new array."""
        if self.reuse:
            return scratch(name, self.ncol * self.W, np.uint64, zero=True)
        return np.zeros(self.ncol * self.W, np.uint64)

    def trace(self, mask: np.ndarray, origins, directions, max_range: float) -> None:
        """Mark the voxels the rays visit (metres, grid frame) in ``mask`` (3D DDA)."""
        D = np.ascontiguousarray(directions, dtype=np.float64).reshape(-1, 3)
        if len(D) == 0:
            return
        O = np.ascontiguousarray(origins, dtype=np.float64).reshape(-1, 3)
        if len(O) not in (1, len(D)):
            raise ValueError(f"origins must be (3,) or ({len(D)}, 3), got {np.shape(origins)}")
        O, t_range = self._to_voxels(O, max_range)
        parallel = len(D) >= PARALLEL_MIN_RAYS and numba.get_num_threads() > 1
        kernel = _rays_parallel if parallel else _rays_serial
        kernel(self.words, mask, *self.shape, self.W, O, D, t_range)

    def trace_fans(self, mask: np.ndarray, fans: Fans, max_range: float) -> None:
        """Mark the voxels the fans' rays visit (``max_range`` metres each) in ``mask``."""
        if len(fans) == 0 or fans.slopes.shape[1] == 0:
            return
        O, t_range = self._to_voxels(fans.origins, max_range)
        parallel = len(fans) >= PARALLEL_MIN_FANS and numba.get_num_threads() > 1
        kernel = _fans_parallel if parallel else _fans_serial
        kernel(self.words, mask, *self.shape, self.W, O, fans.headings, fans.slopes, t_range)

    def or_into(self, mask: np.ndarray, out: np.ndarray) -> np.ndarray:
        """OR ``mask`` into the C-order uint8 volume ``out`` (returned)."""
        _unpack_or(mask, self.ncol, self.shape[2], self.W, out.reshape(-1))
        return out

    def block(self, mask: np.ndarray, i0: int, j0: int, bx: int, by: int, name: str = "mask_block") -> np.ndarray | None:
        """Voxels ``[i0, i0 + bx) x [j0, j0 + by)`` x all z of ``mask`` as uint8 (bx, by, Z) (1 =
        set) in the per-thread buffer ``name`` (the next call overwrites it); None when no voxel
        of the block is set."""
        nx, ny, nz = self.shape
        if not (0 <= i0 and 0 <= j0 and bx >= 0 and by >= 0 and i0 + bx <= nx and j0 + by <= ny):
            raise ValueError(f"block [{i0}, {i0 + bx}) x [{j0}, {j0 + by}) outside the grid's {nx} x {ny} columns")
        n = bx * by * nz
        # 1. the block's bits as one C-order bit stream; 2. the stream's bytes -> eight voxel bytes
        #    each (whole uint64 stores into a buffer rounded up to 8 voxels)
        stream = scratch(name + ".bits", n // 64 + 2, np.uint64, zero=True)
        nonzero = _block_stream(mask, ny, i0, j0, bx, by, nz, self.W, stream)
        if not nonzero:
            return None
        n8 = -(-n // 8)
        flat = scratch(name, 8 * n8, np.uint8)
        _stream_bytes(stream.view(np.uint8), n8, flat.view(np.uint64))
        out = flat[:n]
        return out.reshape(bx, by, nz) if nonzero else None


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
    occupied voxel (3D DDA; see the module docstring for the exact rules).

    ``occupied`` (X, Y, Z) of ``grid.shape``, bool or numeric (nonzero = occupied); ``origins``
    (3,) shared or (N, 3) per ray and ``directions`` (N, 3) in the grid frame (metres; directions
    are normalised here); ``max_range`` metres travelled from the origin. ``out`` (uint8,
    C-contiguous, same shape) is OR-ed into and returned when given.
    """
    shape = tuple(int(s) for s in grid.shape)
    out = _checked_out(out, shape)
    # 1. pack the occupancy, 2. trace into a column-bit mask, 3. OR it into out in C order
    vol = _Volume(grid, occupied)
    mask = vol.new_mask()
    vol.trace(mask, origins, directions, max_range)
    return vol.or_into(mask, out)


def fan_mask(
    occupied: np.ndarray,
    grid: GridSpec,
    fans: Fans,
    max_range: float,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """:func:`ray_mask` of the rays of ``fans`` (``fans.directions()`` from each fan's origin),
    traced as fans (see "Algorithm 2"): the same voxels up to the tie rule."""
    shape = tuple(int(s) for s in grid.shape)
    out = _checked_out(out, shape)
    vol = _Volume(grid, occupied)
    mask = vol.new_mask()
    vol.trace_fans(mask, fans, max_range)
    return vol.or_into(mask, out)


def _lidar_angles(lidar: LidarSpec) -> tuple[np.ndarray, np.ndarray]:
    """The beams' elevations (channels,) and azimuths (steps,), radians: ``steps =
    points_per_frame // channels`` azimuths evenly over 360 degrees from 0 (+x), counter-clockwise."""
    steps = max(lidar.points_per_frame // lidar.channels, 1)
    elev = np.radians(np.asarray(lidar.beam_elevations_deg, dtype=np.float64))
    return elev, (2.0 * np.pi / steps) * np.arange(steps, dtype=np.float64)


def lidar_directions(lidar: LidarSpec) -> np.ndarray:
    """(channels * steps, 3) unit beam directions in the LiDAR frame (x fwd, y left, z up).

    ``steps = points_per_frame // channels`` azimuths evenly over 360 degrees, starting at 0
    (forward, +x) and turning counter-clockwise (towards +y); channel-major order: row
    ``c * steps + a`` is channel ``c`` (``beam_elevations_deg[c]``) at azimuth step ``a``.
    """
    elev, azim = _lidar_angles(lidar)
    elev, azim = elev[:, None], azim[None, :]
    # spherical -> cartesian, (channels, steps) then flattened channel-major
    d = np.stack(
        np.broadcast_arrays(np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim), np.sin(elev)), axis=-1
    )
    return np.ascontiguousarray(d.reshape(-1, 3))


# a ray whose horizontal part is shorter than this (a beam at +-90 degrees) is not in any fan
_VERTICAL = 1e-9


def lidar_fans(lidar: LidarSpec) -> tuple[Fans, np.ndarray]:
    """The beams of :func:`lidar_directions` as vertical fans, one per azimuth step (origin at the
    LiDAR, the channels' slopes ``tan(elevation)`` ascending), and the (N, 3) directions of the
    beams too close to vertical to belong to a fan (none for the reference rig)."""
    elev, azim = _lidar_angles(lidar)
    steps = len(azim)
    steep = np.cos(elev) < _VERTICAL
    slopes = np.sort(np.tan(elev[~steep]))
    fans = Fans(origins=np.zeros((steps, 3)), headings=np.stack([np.cos(azim), np.sin(azim)], axis=1),
                slopes=np.broadcast_to(slopes, (steps, len(slopes))))
    vertical = np.stack([np.zeros(steep.sum()), np.zeros(steep.sum()), np.sign(np.sin(elev[steep]))], axis=1)
    return fans, vertical


def _pixel_rays(camera: CameraSpec, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """Optical-frame x and y of the sampled pixel centres: ``((u + 0.5 - cx) / fx)`` over every
    ``stride``-th column u and ``((v + 0.5 - cy) / fy)`` over every ``stride``-th row v."""
    if stride < 1:
        raise ValueError(f"stride must be >= 1, got {stride}")
    K = np.asarray(camera.intrinsics, dtype=np.float64)
    u = np.arange(0, camera.width, stride, dtype=np.float64) + 0.5
    v = np.arange(0, camera.height, stride, dtype=np.float64) + 0.5
    return (u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]


def camera_rays(camera: CameraSpec, camera_to_grid: np.ndarray, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Rays through the pixel centres of every ``stride``-th row and column of a camera.

    ``camera_to_grid`` is the 4x4 pose of the OpenCV optical frame (x right, y down, z forward)
    in the grid frame. Returns the camera centre (3,) and unit directions (N, 3) in the grid
    frame, row-major over the sampled pixels (row v outer, column u inner).
    """
    T = np.asarray(camera_to_grid, dtype=np.float64)
    # 1. pixel centres (u + 0.5, v + 0.5) -> optical-frame rays ((u - cx) / fx, (v - cy) / fy, 1)
    x, y = _pixel_rays(camera, stride)
    d = np.empty((len(y), len(x), 3), dtype=np.float64)
    d[..., 0] = x[None, :]
    d[..., 1] = y[:, None]
    d[..., 2] = 1.0
    d = d.reshape(-1, 3)
    # 2. normalise, then rotate into the grid frame; the origin is the pose's translation
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d = d @ T[:3, :3].T
    return T[:3, 3].copy(), np.ascontiguousarray(d)


def camera_fans(camera: CameraSpec, camera_to_grid: np.ndarray, stride: int = 1) -> Fans | None:
    """The rays of :func:`camera_rays` as vertical fans, one per sampled image column, when the
    camera's optical y axis is vertical (a level camera: the rig's, which only turn about z);
    None otherwise.

    The ray through optical (x, y, 1) is ``x * R[:, 0] + y * R[:, 1] + R[:, 2]``; with
    ``R[:2, 1] == 0`` its horizontal part ``g = x * R[:2, 0] + R[:2, 2]`` does not depend on y,
    so column x is the fan of heading ``g / |g|`` and slopes ``(x R[2, 0] + y R[2, 1] + R[2, 2]) /
    |g|`` (sorted ascending: row order reversed when the optical y points down)."""
    T = np.asarray(camera_to_grid, dtype=np.float64)
    R = T[:3, :3]
    if np.abs(R[:2, 1]).max() > 1e-12:
        return None
    x, y = _pixel_rays(camera, stride)
    g = x[:, None] * R[:2, 0][None, :] + R[:2, 2][None, :]  # (U, 2)
    gn = np.linalg.norm(g, axis=1)
    if len(gn) and gn.min() < _VERTICAL:
        return None
    slopes = (x[:, None] * R[2, 0] + y[None, :] * R[2, 1] + R[2, 2]) / gn[:, None]
    return Fans(origins=np.broadcast_to(T[:3, 3], (len(x), 3)), headings=g / gn[:, None],
                slopes=np.sort(slopes, axis=1))


def sensor_to_lidar(rig: RigConfig) -> dict[str, np.ndarray]:
    """4x4 poses in the LiDAR frame, by sensor name: each camera's OpenCV optical frame
    (``inv(lidar.sensor_to_ego()) @ camera.camera_to_ego()``) and the LiDAR itself (identity)."""
    ego_to_lidar = np.linalg.inv(np.asarray(rig.lidar.sensor_to_ego(), dtype=np.float64))
    out = {cam.name: ego_to_lidar @ np.asarray(cam.camera_to_ego(), dtype=np.float64) for cam in rig.cameras}
    out[rig.lidar.name] = ego_to_lidar @ np.asarray(rig.lidar.sensor_to_ego(), dtype=np.float64)
    return out


def pack_occupancy(occupied: np.ndarray | None, grid: GridSpec, reuse: bool = False) -> _Volume:
    """The occupancy packed once (column bits) for any number of ray sets and fans; with
    ``occupied`` None, an unpacked volume to fill with :meth:`_Volume.pack_slab`. ``reuse``:
    keep the bits and masks in per-thread scratch buffers (see :class:`_Volume`; the pipeline's
    tasks, one frame after another)."""
    return _Volume(grid, occupied, reuse)


def lidar_visibility_bits(packed: _Volume, rig: RigConfig) -> np.ndarray:
    """mask_lidar as column bits: the rig's beams (:func:`lidar_directions`, traced as
    :func:`lidar_fans`) from the LiDAR origin up to ``rig.lidar.range_m``; of a reusing volume,
    a per-thread buffer that the next call overwrites."""
    mask = packed.new_mask("mask_lidar_columns")
    fans, vertical = lidar_fans(rig.lidar)
    packed.trace_fans(mask, fans, rig.lidar.range_m)
    packed.trace(mask, np.zeros(3), vertical, rig.lidar.range_m)
    return mask


def camera_visibility_bits(packed: _Volume, rig: RigConfig, camera_stride: int = 1,
                           max_range: float | None = None) -> np.ndarray:
    """mask_camera as column bits: every camera's pixel rays (every ``camera_stride``-th
    row/column, from the camera centre, up to ``max_range`` m; default the grid's diagonal);
    level cameras are traced as fans (:func:`camera_fans`), others ray by ray; of a reusing
    volume, a per-thread buffer that the next call overwrites."""
    if max_range is None:
        max_range = float(np.linalg.norm(np.asarray(packed.shape, dtype=np.float64) * packed.grid.voxel_size))
    poses = sensor_to_lidar(rig)
    mask = packed.new_mask("mask_camera_columns")
    for cam in rig.cameras:  # one camera at a time into one mask
        fans = camera_fans(cam, poses[cam.name], camera_stride)
        if fans is not None:
            packed.trace_fans(mask, fans, max_range)
        else:
            origin, dirs = camera_rays(cam, poses[cam.name], camera_stride)
            packed.trace(mask, origin, dirs, max_range)
    return mask


def lidar_visibility(packed: _Volume, rig: RigConfig, out: np.ndarray | None = None) -> np.ndarray:
    """mask_lidar (:func:`lidar_visibility_bits`) OR-ed into ``out`` (uint8 grid volume) or a
    new volume."""
    out = _checked_out(out, packed.shape)
    return packed.or_into(lidar_visibility_bits(packed, rig), out)


def camera_visibility(packed: _Volume, rig: RigConfig, camera_stride: int = 1, max_range: float | None = None,
                      out: np.ndarray | None = None) -> np.ndarray:
    """mask_camera (:func:`camera_visibility_bits`) OR-ed into ``out`` (uint8 grid volume) or a
    new volume."""
    out = _checked_out(out, packed.shape)
    return packed.or_into(camera_visibility_bits(packed, rig, camera_stride, max_range), out)


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
    vol = _Volume(grid, occ)
    mask = vol.new_mask()
    O = np.full((1, 3), 0.5)
    D = np.array([[1.0, 0.5, 0.25]])
    H = np.array([[1.0, 0.0]])
    M = np.array([[-0.5, 0.0, 0.5]])
    _rays_serial(vol.words, mask, *vol.shape, vol.W, O, D, 10.0)
    _rays_parallel(vol.words, mask, *vol.shape, vol.W, O, D, 10.0)
    _fans_serial(vol.words, mask, *vol.shape, vol.W, O, H, M, 10.0)
    _fans_parallel(vol.words, mask, *vol.shape, vol.W, O, H, M, 10.0)
    vol.or_into(mask, np.zeros(grid.shape, dtype=np.uint8))
    vol.block(mask, 0, 0, 1, 1)
