"""What the interactive viewer (``carlaocc view``) draws, prepared as arrays: small pure numpy
functions, testable without a browser or a store.

Frames and units: voxels come as the sparse rows of :class:`carlaocc.catalog.samples.FrameSamples`
(``i, j, k`` grid indices, a class id); positions are metres in the frame's LiDAR frame (x forward,
y left, z up), ``centre = origin + (ijk + 0.5) * voxel_size``; cameras in the OpenCV optical frame
(x right, y down, z forward); flow in m/s along the LiDAR axes (``docs/architecture.md`` "Frames
and units").

* :func:`surface_voxels`: the occupied voxels with a free face (what the eye can see of a solid
  grid), :func:`block_surface`: the same of one stored column block given its neighbours' facing
  planes (a frame read chunk by chunk), and :func:`level_of_detail`: one voxel per ``factor**3`` block until a point budget holds,
  so a 0.05 m frame stays interactive in a browser;
* :func:`class_colours` / :func:`ghost`: colours from the one label table (instances hashed as
  every other picture: :mod:`carlaocc.stages.render.colours`), unobserved voxels washed out;
  :func:`label_colours`: another label space's ids (Occ3D...) in the colours of their classes;
* :func:`prediction_outcome`: every voxel occupied in the ground truth or a prediction as true
  positive, false positive, false negative or wrong class (:data:`OUTCOMES`);
* :func:`flow_arrows`, :func:`box_edges`, :func:`camera_frustum`: the overlays.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from carlaocc.schemas.taxonomy import palette
from carlaocc.stages.geometry import quaternion_wxyz
from carlaocc.stages.render.colours import voxel_colours

__all__ = ["OUTCOMES", "OUTCOME_COLOURS", "block_surface", "box_edges", "camera_frustum", "class_colours",
           "flow_arrows", "ghost", "label_colours", "level_of_detail", "linear_index", "prediction_outcome",
           "surface_voxels", "voxel_centres"]

OUTCOMES = ("true positive", "false positive", "false negative", "wrong class")
"""The outcome of a voxel against the ground truth, by code 0..3: same class in both; occupied only
in the prediction; occupied only in the ground truth; occupied in both with different classes (a
false positive of the predicted class and a false negative of the true one, as SSC IoU counts it)."""
OUTCOME_COLOURS = np.array([(60, 200, 75), (230, 40, 40), (40, 110, 240), (250, 170, 20)], np.uint8)
"""Display colour of each outcome code (green, red, blue, orange)."""
_PALETTE = np.asarray(palette() + ((0, 0, 0),) * (256 - len(palette())), np.uint8)


def linear_index(ijk: np.ndarray, shape) -> np.ndarray:
    """int64 C-order flat index of voxel indices ``ijk`` (N, 3) in a grid of ``shape`` (X, Y, Z)."""
    ijk = np.asarray(ijk, np.int64)
    X, Y, Z = (int(s) for s in shape)
    return (ijk[:, 0] * Y + ijk[:, 1]) * Z + ijk[:, 2]


@njit(cache=True)
def _has_neighbour(flat: np.ndarray, offset: int) -> np.ndarray:
    """For each value of the sorted unique int64 ``flat``, whether ``value + offset`` is in it: one
    merge walk of a second pointer (O(N), no search)."""
    n = len(flat)
    out = np.zeros(n, np.bool_)
    j = 0
    for i in range(n):
        target = flat[i] + offset
        # the second pointer only moves forward: the targets are sorted too
        while j < n and flat[j] < target:
            j += 1
        if j == n:
            break
        out[i] = flat[j] == target
    return out


def surface_voxels(ijk: np.ndarray, shape) -> np.ndarray:
    """Bool mask (N,) of the occupied voxels ``ijk`` (N, 3, unique, in a grid of ``shape``) that
    have at least one free face neighbour; a face on the grid's border counts as free."""
    ijk = np.asarray(ijk, np.int64)
    n = len(ijk)
    if n == 0:
        return np.zeros(0, bool)
    shape = np.asarray(shape, np.int64)
    # the occupied set as sorted flat indices (the store's rows come in C order: no sort then)
    flat = linear_index(ijk, shape)
    order = None
    if n > 1 and not bool(np.all(flat[1:] > flat[:-1])):
        order = np.argsort(flat, kind="stable")
        flat = flat[order]
        ijk = ijk[order]
    exposed = np.zeros(n, bool)
    strides = (int(shape[1] * shape[2]), int(shape[2]), 1)
    for axis in range(3):
        for step in (-1, 1):
            # a neighbour outside the grid is free space; inside, free unless it is in the set
            edge = ijk[:, axis] == (0 if step < 0 else shape[axis] - 1)
            exposed |= edge | ~_has_neighbour(flat, step * strides[axis])
    if order is not None:
        out = np.empty(n, bool)
        out[order] = exposed
        return out
    return exposed


@njit(cache=True)
def _block_surface_kernel(sem, x_lo, x_hi, y_lo, y_hi, occupied):  # pragma: no cover - jitted
    bx, by, bz = sem.shape
    out = np.empty(occupied, np.int64)  # at most every occupied voxel is on the surface
    col = np.empty(bz, np.uint8)
    n = 0
    for i in range(bx):
        for j in range(by):
            # the column and its four side neighbours, each contiguous along z (a neighbour
            # across the block's x / y faces comes from the halo planes)
            c = sem[i, j]
            xm = x_lo[j] if i == 0 else sem[i - 1, j]
            xp = x_hi[j] if i == bx - 1 else sem[i + 1, j]
            ym = y_lo[i] if j == 0 else sem[i, j - 1]
            yp = y_hi[i] if j == by - 1 else sem[i, j + 1]
            # occupied with a free side neighbour: branch-free, so the loop vectorises
            for k in range(bz):
                col[k] = (c[k] != 0) & ((xm[k] == 0) | (xp[k] == 0) | (ym[k] == 0) | (yp[k] == 0))
            # or a free neighbour above or below; the grid's top and bottom faces are free
            for k in range(1, bz - 1):
                col[k] |= (c[k] != 0) & ((c[k - 1] == 0) | (c[k + 1] == 0))
            col[0] = c[0] != 0
            col[bz - 1] = c[bz - 1] != 0
            base = (i * by + j) * bz
            for k in range(bz):
                if col[k]:
                    out[n] = base + k
                    n += 1
    return out[:n]


def block_surface(block: np.ndarray, x_lo=None, x_hi=None, y_lo=None, y_hi=None, occupied: int | None = None) -> np.ndarray:
    """Flat indices (C order in the block, int64, sorted) of the occupied voxels of one column
    block of a grid (``block`` (bx, by, Z), nonzero = occupied, the grid's whole z range) that
    have a free face neighbour, as :func:`surface_voxels` finds them on the whole grid.

    ``x_lo`` / ``x_hi`` (by, Z) are the planes of the grid just before / after the block along x,
    ``y_lo`` / ``y_hi`` (bx, Z) along y (nonzero = occupied); None where the block touches the
    grid's border (outside the grid is free). So a grid read chunk by chunk never has to be
    assembled: each block needs only its neighbours' facing planes. ``occupied``: the block's
    nonzero count when the caller has it (else counted here)."""
    block = np.asarray(block)
    bx, by, bz = block.shape
    free_x, free_y = np.zeros((by, bz), block.dtype), np.zeros((bx, bz), block.dtype)
    planes = [free_x if x_lo is None else x_lo, free_x if x_hi is None else x_hi,
              free_y if y_lo is None else y_lo, free_y if y_hi is None else y_hi]
    for p, want in zip(planes, ((by, bz), (by, bz), (bx, bz), (bx, bz))):
        if p.shape != want:
            raise ValueError(f"a halo plane of shape {p.shape}; the block {block.shape} needs {want}")
    return _block_surface_kernel(block, *(np.asarray(p, block.dtype) for p in planes), int(np.count_nonzero(block)) if occupied is None else int(occupied))


@njit(cache=True)
def _first_per_block(ijk, factor, dims):  # pragma: no cover - jitted
    # one flag per coarse block; a voxel is kept when its block is not flagged yet
    seen = np.zeros(dims[0] * dims[1] * dims[2], np.bool_)
    keep = np.empty(len(ijk), np.int64)
    n = 0
    for r in range(len(ijk)):
        key = ((ijk[r, 0] // factor) * dims[1] + ijk[r, 1] // factor) * dims[2] + ijk[r, 2] // factor
        if not seen[key]:
            seen[key] = True
            keep[n] = r
            n += 1
    return keep[:n]


def level_of_detail(ijk: np.ndarray, budget: int) -> tuple[np.ndarray, int]:
    """``(keep, factor)``: indices into ``ijk`` (N, 3 non-negative voxel indices) of one voxel per
    ``factor``-cube block (the first in the given order; ``factor`` the smallest power of two >= 1
    leaving at most ``budget`` voxels), ascending, and that factor. Drawn ``factor`` times larger,
    the kept voxels cover the blocks."""
    ijk = np.asarray(ijk, np.int64)
    if budget < 1:
        raise ValueError(f"budget {budget}: at least 1 voxel")
    factor = 1
    keep = np.arange(len(ijk))
    if len(ijk) == 0:
        return keep, factor
    top = ijk.max(axis=0)
    while len(keep) > budget:
        factor *= 2
        # the first voxel of each block, in one pass over a flag per block (no sort)
        keep = _first_per_block(ijk, factor, top // factor + 1)
    return keep, factor


def voxel_centres(ijk: np.ndarray, origin, voxel_size: float) -> np.ndarray:
    """float32 (N, 3) centres in metres of voxels ``ijk`` on a grid with minimum corner ``origin``."""
    return (np.asarray(origin, np.float64) + (np.asarray(ijk, np.float64) + 0.5) * float(voxel_size)).astype(np.float32)


def class_colours(semantic: np.ndarray, instance: np.ndarray | None = None, mode: str = "semantic",
                  colours: np.ndarray | None = None) -> np.ndarray:
    """uint8 RGB (N, 3): ``semantic`` the class's colour (``colours`` (256, 3) by label id, default
    the label table's palette of CarlaOcc ids); ``instance`` things (nonzero ``instance``) by their
    hashed instance colour, stuff by class."""
    semantic = np.asarray(semantic, np.uint8)
    pal = _PALETTE if colours is None else np.asarray(colours, np.uint8)
    if mode == "semantic" or instance is None:
        return pal[semantic]
    if mode != "instance":
        raise ValueError(f"colour mode {mode!r}: semantic or instance")
    z = np.zeros(len(semantic))
    instance = np.asarray(instance, np.uint32)
    out = pal[semantic].copy()
    things = instance != 0
    out[things] = np.round(voxel_colours(semantic[things], instance[things], z[things], "instance", (0.0, 1.0))).astype(np.uint8)
    return out


def label_colours(from_carlaocc) -> np.ndarray:
    """uint8 (256, 3) display colour of each id of another label space, given the id of every
    CarlaOcc class there (``from_carlaocc[k]``, as :class:`carlaocc.stages.evaluation.LabelMap`
    holds it): the palette colour of the first CarlaOcc class (by id, None excluded) mapped to
    it, so Occ3D's ``car`` is drawn as Car and ``driveable_surface`` as Road; ids no class maps
    to are grey."""
    out = np.full((256, 3), 128, np.uint8)
    seen = set()
    for k, t in enumerate(from_carlaocc):
        if k == 0 or t in seen or not 0 <= t < 255:  # 255: ignored, not a label
            continue
        seen.add(t)
        out[t] = _PALETTE[k]
    return out


def ghost(colours: np.ndarray, observed: np.ndarray, strength: float = 0.75) -> np.ndarray:
    """``colours`` with the unobserved ones (``observed`` False) blended ``strength`` of the way to
    white: what no sensor saw stays in place but fades."""
    out = np.asarray(colours, np.float32).copy()
    hidden = ~np.asarray(observed, bool)
    out[hidden] += (255.0 - out[hidden]) * float(strength)
    return np.round(out).astype(np.uint8)


def prediction_outcome(gt_flat: np.ndarray, gt_class: np.ndarray, pred_flat: np.ndarray,
                       pred_class: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(flat, outcome, class)`` of every voxel occupied in the ground truth or the prediction,
    both given as unique flat indices and their classes (nonzero): the sorted flat indices, the
    outcome code (:data:`OUTCOMES`), and the class shown (the prediction's, or the ground truth's
    for a false negative)."""
    gt_flat, pred_flat = np.asarray(gt_flat, np.int64), np.asarray(pred_flat, np.int64)
    gt_class, pred_class = np.asarray(gt_class), np.asarray(pred_class)
    flat = np.union1d(gt_flat, pred_flat)
    # each side's class at every voxel of the union (0 where that side is free)
    g = np.zeros(len(flat), np.int64)
    p = np.zeros(len(flat), np.int64)
    g[np.searchsorted(flat, gt_flat)] = gt_class
    p[np.searchsorted(flat, pred_flat)] = pred_class
    outcome = np.where(g == 0, 1, np.where(p == 0, 2, np.where(g == p, 0, 3))).astype(np.uint8)
    return flat, outcome, np.where(p == 0, g, p).astype(np.uint8)


def flow_arrows(centres: np.ndarray, instance: np.ndarray, flow: np.ndarray, min_speed: float = 0.1,
                seconds: float = 0.5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One arrow per moving thing: ``(start, end, ids)``, float32 (M, 3) metres, from the centroid of
    each instance's voxels (``centres`` (N, 3) m, ``instance`` (N,), ``flow`` (N, 3) m/s) to where
    its mean flow carries it in ``seconds``; instances whose mean speed is under ``min_speed`` m/s
    (and stuff, id 0) have none."""
    instance = np.asarray(instance, np.int64)
    things = instance != 0
    if not things.any():
        z = np.zeros((0, 3), np.float32)
        return z, z, np.zeros(0, np.int64)
    ids, inv = np.unique(instance[things], return_inverse=True)
    count = np.bincount(inv, minlength=len(ids)).astype(np.float64)[:, None]
    # per-instance means of position and flow by weighted bincounts, one column at a time
    mean_c = np.stack([np.bincount(inv, centres[things, a], len(ids)) for a in range(3)], 1) / count
    mean_f = np.stack([np.bincount(inv, flow[things, a], len(ids)) for a in range(3)], 1) / count
    moving = np.linalg.norm(mean_f, axis=1) >= min_speed
    start = mean_c[moving]
    return start.astype(np.float32), (start + mean_f[moving] * seconds).astype(np.float32), ids[moving]


_CORNERS = np.array([[sx, sy, sz] for sx in (-0.5, 0.5) for sy in (-0.5, 0.5) for sz in (-0.5, 0.5)])
_EDGES = np.array([[a, b] for a in range(8) for b in range(a + 1, 8)
                   if np.abs(_CORNERS[a] - _CORNERS[b]).sum() == 1.0])  # the 12 cube edges


def box_edges(box_pose: np.ndarray, size: np.ndarray) -> np.ndarray:
    """float32 (M * 12, 2, 3) line segments (metres, the poses' frame) of the edges of boxes with
    box-to-frame poses ``box_pose`` (M, 4, 4) (origin at the box centre) and ``size`` (M, 3)
    ``l, w, h`` along the box's x, y, z."""
    box_pose, size = np.asarray(box_pose, np.float64), np.asarray(size, np.float64)
    if len(box_pose) == 0:
        return np.zeros((0, 2, 3), np.float32)
    # the 8 corners in each box's frame, then in the target frame
    local = _CORNERS[None] * size[:, None, :]
    world = np.einsum("mij,mkj->mki", box_pose[:, :3, :3], local) + box_pose[:, None, :3, 3]
    return world[:, _EDGES].reshape(-1, 2, 3).astype(np.float32)


def camera_frustum(K: np.ndarray, cam_to_frame: np.ndarray, width: int, height: int) -> dict:
    """A pinhole camera as the viewer draws it: ``fov`` (vertical, rad), ``aspect`` (width /
    height), ``wxyz`` (the camera's rotation in the frame, a unit quaternion) and ``position`` (m)
    of intrinsics ``K`` (3, 3) and the pose ``cam_to_frame`` (4, 4; OpenCV camera axes)."""
    K = np.asarray(K, np.float64)
    T = np.asarray(cam_to_frame, np.float64)
    # the vertical field of view from the focal length in pixels and the image height
    fov = 2.0 * np.arctan2(height / 2.0, K[1, 1])
    return {"fov": float(fov), "aspect": float(width) / float(height),
            "wxyz": np.asarray(quaternion_wxyz(T[:3, :3]), np.float64), "position": T[:3, 3].copy()}
