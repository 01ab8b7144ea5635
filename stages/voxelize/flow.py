"""Occupancy flow: the velocity of the material point at each dynamic voxel's centre.

Frames and units
----------------
The instance volume (or a tile of it) lives in the LiDAR frame (x forward, y left, z up, metres);
``tile_origin`` is the minimum corner of its voxel (0, 0, 0), so voxel (i, j, k) has its centre at
``tile_origin + ((i, j, k) + 0.5) * voxel_size``. Actor states are in the world frame: the rotation
centre ``c`` (the actor's pose origin, metres), linear velocity ``v`` (m/s) and angular velocity
``w`` (rad/s). ``lidar_to_world`` is the LiDAR's 4x4 pose in the world.

The flow of a voxel of actor (c, v, w) is the rigid-body velocity ``v + w x (p - c)`` of the voxel
centre ``p`` (mapped to the world), computed in the world frame and expressed in the LiDAR frame's
axes (rotated by the inverse of ``lidar_to_world``'s rotation). It is the actor's own motion: the
ego's motion is *not* subtracted. Voxels of other instances (static things, unknown ids) and of
instance 0 (free space, stuff) get 0.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["instance_flow", "actor_voxels", "voxel_flow"]


def instance_flow(
    instance: np.ndarray,
    tile_origin,
    voxel_size: float,
    instance_ids: np.ndarray,
    centres: np.ndarray,
    velocities: np.ndarray,
    angular_velocities: np.ndarray,
    lidar_to_world: np.ndarray,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """float16 (X, Y, Z, 3) flow (m/s, LiDAR axes) of the voxels of the given actors, 0 elsewhere.

    ``instance`` (X, Y, Z) uint32 instance ids (a tile of the grid, ``tile_origin`` metres in the
    LiDAR frame); ``instance_ids`` (K,) unique actor ids with ``centres`` (K, 3) world metres,
    ``velocities`` (K, 3) world m/s and ``angular_velocities`` (K, 3) world rad/s;
    ``lidar_to_world`` 4x4. Work is proportional to the nonzero voxels. ``out``: a float16
    (X, Y, Z, 3) buffer to fill (zeroed here) instead of a new array.
    """
    inst = np.asarray(instance)
    if inst.ndim != 3:
        raise ValueError(f"instance must be a 3D volume, got shape {inst.shape}")
    ids = np.asarray(instance_ids, dtype=np.uint32).reshape(-1)
    C = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    Vl = np.asarray(velocities, dtype=np.float64).reshape(-1, 3)
    W = np.asarray(angular_velocities, dtype=np.float64).reshape(-1, 3)
    if not (len(C) == len(Vl) == len(W) == len(ids)):
        raise ValueError("instance_ids, centres, velocities and angular_velocities must have one row per actor")
    if len(np.unique(ids)) != len(ids):
        raise ValueError("instance_ids must be unique")
    T = np.asarray(lidar_to_world, dtype=np.float64)
    if out is None:
        out = np.zeros(inst.shape + (3,), dtype=np.float16)
    elif out.shape != inst.shape + (3,) or out.dtype != np.float16 or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous float16 array of shape {inst.shape + (3,)}")
    else:
        out[...] = 0
    if len(ids) == 0:
        return out
    # 1. the nonzero voxels and their ids (instance 0 is free space / stuff)
    flat = np.flatnonzero(inst)
    if len(flat) == 0:
        return out
    vox_ids = inst.reshape(-1)[flat].astype(np.uint32, copy=False)
    # 2. actor of each voxel: binary search in the sorted ids; voxels of other instances dropped
    order = np.argsort(ids, kind="stable")
    sorted_ids = ids[order]
    pos = np.minimum(np.searchsorted(sorted_ids, vox_ids), len(ids) - 1)
    hit = sorted_ids[pos] == vox_ids
    flat = flat[hit]
    actor = order[pos[hit]]
    if len(flat) == 0:
        return out
    out.reshape(-1, 3)[flat] = voxel_flow(flat, inst.shape, tile_origin, voxel_size, actor, C, Vl, W, T)
    return out


def voxel_flow(flat: np.ndarray, shape, tile_origin, voxel_size: float, actor: np.ndarray, centres: np.ndarray,
               velocities: np.ndarray, angular_velocities: np.ndarray, lidar_to_world: np.ndarray) -> np.ndarray:
    """(N, 3) float16 flow (m/s, LiDAR axes) of the voxels at C-order indices ``flat`` of a volume
    of ``shape`` whose voxel (0, 0, 0) has its minimum corner at ``tile_origin``; ``actor`` (N,)
    indexes the rows of ``centres``, ``velocities`` and ``angular_velocities`` (world frame)."""
    T = np.asarray(lidar_to_world, dtype=np.float64)
    C = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    Vl = np.asarray(velocities, dtype=np.float64).reshape(-1, 3)
    W = np.asarray(angular_velocities, dtype=np.float64).reshape(-1, 3)
    # 1. voxel centres: LiDAR frame -> world
    ijk = np.stack(np.unravel_index(flat, tuple(shape)), axis=1).astype(np.float64)
    p_lidar = np.asarray(tile_origin, dtype=np.float64).reshape(3) + (ijk + 0.5) * float(voxel_size)
    R = T[:3, :3]
    p_world = p_lidar @ R.T + T[:3, 3]
    # 2. rigid-body velocity in the world, v + w x (p - c), then in the LiDAR's axes (R^T v)
    v_world = Vl[actor] + np.cross(W[actor], p_world - C[actor])
    return (v_world @ R).astype(np.float16)


@njit(cache=True, nogil=True)
def _gather(inst, ny, nz, boxes, box_actor, out_flat, out_actor):  # pragma: no cover - numba
    """Flat indices (and the actor row) of the voxels of ``inst`` (flat C order, (., ny, nz))
    equal to each box's id inside that box; boxes are rows (id, i0, i1, j0, j1, k0, k1)."""
    n = 0
    for b in range(boxes.shape[0]):
        ident = np.uint32(boxes[b, 0])
        for i in range(boxes[b, 1], boxes[b, 2]):
            for j in range(boxes[b, 3], boxes[b, 4]):
                base = (i * ny + j) * nz
                for k in range(boxes[b, 5], boxes[b, 6]):
                    if inst[base + k] == ident:
                        out_flat[n] = base + k
                        out_actor[n] = box_actor[b]
                        n += 1
    return n


def actor_voxels(instance: np.ndarray, things: np.ndarray, instance_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(flat C-order indices, actor rows) of the voxels of ``instance`` (X, Y, Z) that belong to
    the actors ``instance_ids``, looked for only inside the boxes ``things`` (rows (instance, i0,
    i1, j0, j1, k0, k1), half-open voxel boxes that hold every voxel of their instance, e.g.
    :attr:`carlaocc.stages.voxelize.compose.Tile.things`). Ascending indices per actor, actors in the order
    of ``instance_ids``."""
    inst = np.ascontiguousarray(instance)
    ids = np.asarray(instance_ids, dtype=np.int64).reshape(-1)
    if len(np.unique(ids)) != len(ids):
        raise ValueError("instance_ids must be unique")
    things = np.asarray(things, dtype=np.int64).reshape(-1, 7)
    # one box per actor: the union of its meshes' boxes (a voxel is then found once)
    rows, actors = [], []
    for a, ident in enumerate(ids):
        mine = things[things[:, 0] == ident]
        mine = mine[(mine[:, 2] > mine[:, 1]) & (mine[:, 4] > mine[:, 3]) & (mine[:, 6] > mine[:, 5])]
        if len(mine):
            rows.append([ident, mine[:, 1].min(), mine[:, 2].max(), mine[:, 3].min(), mine[:, 4].max(),
                         mine[:, 5].min(), mine[:, 6].max()])
            actors.append(a)
    boxes = np.array(rows, dtype=np.int64).reshape(-1, 7)
    size = int(np.prod(boxes[:, 2::2] - boxes[:, 1::2], axis=1).sum()) if len(boxes) else 0
    flat = np.empty(size, dtype=np.int64)
    actor = np.empty(size, dtype=np.int64)
    n = _gather(inst.reshape(-1), inst.shape[1], inst.shape[2], boxes, np.array(actors, dtype=np.int64), flat, actor)
    return flat[:n], actor[:n]
