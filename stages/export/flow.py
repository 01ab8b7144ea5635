"""Occupancy flow in the units other datasets train on (pure numpy; frames in the docstrings).

* :func:`voxel_centres` — the centres of a target grid's voxels in its own frame
* :func:`uniocc_flow`   — UniOcc's forward / backward flow, in voxels, from our velocities
"""

from __future__ import annotations

import numpy as np


def voxel_centres(target) -> np.ndarray:
    """(X, Y, Z, 3) float64 centres of the voxels of ``target`` (a ``TargetGrid``: ``shape``,
    ``voxel_size`` m, ``range_min`` m) in its own frame, metres."""
    axes = [target.range_min[a] + (np.arange(target.shape[a]) + 0.5) * target.voxel_size for a in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)


def uniocc_flow(labels: np.ndarray, velocity: np.ndarray, ego_now: np.ndarray, ego_other: np.ndarray | None,
                dt: float, target) -> np.ndarray:
    """UniOcc flow (X, Y, Z, 3) float32 in voxels towards another frame (``dt`` s later, negative
    for the previous one) whose ego pose is ``ego_other`` (4x4 ego-to-world; None: zeros).

    ``labels`` (X, Y, Z) are on ``target`` (its ``free_label`` marks free voxels), ``velocity``
    (X, Y, Z, 3) m/s along the current ego axes, ``ego_now`` the current ego-to-world pose."""
    out = np.zeros((*labels.shape, 3), np.float32)
    if ego_other is None:
        return out
    # each labelled voxel's centre p (current ego frame) moves with its velocity for dt
    sel = labels != target.free_label
    p = voxel_centres(target)[sel]
    moved = p + velocity[sel].astype(np.float64) * dt
    # to the world by the current ego pose, back into the other frame's ego frame
    to_other = np.linalg.inv(ego_other) @ ego_now  # current ego -> other ego
    q = moved @ to_other[:3, :3].T + to_other[:3, 3]
    # flow = (q - p) / voxel size
    out[sel] = ((q - p) / target.voxel_size).astype(np.float32)
    return out
