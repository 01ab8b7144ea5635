"""Boxes against points and grids (pure numpy; frames in the docstrings).

* :func:`points_in_boxes` — how many points each oriented box holds
* :func:`grid_coverage`   — which voxels of another dataset's grid lie inside our grid's region
* :func:`region_in_target` — our grid's region as a box in another dataset's frame
"""

from __future__ import annotations

import numpy as np


def points_in_boxes(points: np.ndarray, box_pose: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """(M,) int64: how many of ``points`` (P, 3) lie inside each box, faces included.

    ``box_pose`` (M, 4, 4) box-to-frame and ``points`` in that same frame (metres);
    ``boxes`` (M, >= 6) with the full length, width, height in columns 3:6."""
    out = np.zeros(len(boxes), np.int64)
    for k in range(len(boxes)):
        # the points in the box's own frame (inverse of a rigid pose: R^T (p - t))
        local = (points - box_pose[k, :3, 3]) @ box_pose[k, :3, :3]
        # inside when within the half extents on every axis
        out[k] = int(np.count_nonzero(np.all(np.abs(local) <= boxes[k, 3:6] / 2, axis=1)))
    return out


def grid_coverage(target, grid, grid_to_target: np.ndarray) -> np.ndarray:
    """bool ``target.shape``: the voxels of ``target`` (a ``TargetGrid`` in its own frame) whose
    centre lies inside ``grid``'s region (a ``GridSpec``, our LiDAR frame), i.e. what an export
    without visibility masks can claim as known. ``grid_to_target`` (4, 4) maps our frame into
    the target's."""
    # the target voxels' centres in the target frame
    idx = np.indices(target.shape).reshape(3, -1).T
    centres = np.asarray(target.range_min) + (idx + 0.5) * target.voxel_size
    # back into our frame, then the half-open box test against our region
    inv = np.linalg.inv(grid_to_target)
    p = centres @ inv[:3, :3].T + inv[:3, 3]
    inside = np.all((p >= np.asarray(grid.origin)) & (p < np.asarray(grid.effective_max)), axis=1)
    return inside.reshape(target.shape)


def region_in_target(grid, grid_to_target: np.ndarray) -> tuple[list[float], list[float]]:
    """``(min, max)`` (m, rounded to micrometres): the axis-aligned box in the target frame of
    ``grid``'s region (a ``GridSpec``, our LiDAR frame, ``origin`` .. ``effective_max``), its
    corners mapped by ``grid_to_target`` (4, 4)."""
    lo, hi = np.asarray(grid.origin, float), np.asarray(grid.effective_max, float)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    p = corners @ np.asarray(grid_to_target, float)[:3, :3].T + np.asarray(grid_to_target, float)[:3, 3]
    return [round(float(v), 6) + 0.0 for v in p.min(axis=0)], [round(float(v), 6) + 0.0 for v in p.max(axis=0)]
