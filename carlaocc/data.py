"""Training data: a map-style dataset over a built carlaocc root, usable as a PyTorch ``Dataset``
without importing torch.

::

    from carlaocc.data import CarlaOccDataset
    ds = CarlaOccDataset("data", split="train", voxel_size=0.2)
    sample = ds[0]            # a dict of numpy arrays (and a few str / int / float)
    len(ds)                   # frames of the split's sequences voxelized at 0.2 m

One sample is one frame of one sequence. Frames and units: everything geometric is in the
frame's **LiDAR frame** (x forward, y left, z up, metres) unless its key says otherwise; poses
are 4x4 float64 matrices ``A_to_B`` mapping points of A into B.

=======================  ====================================================================
key                      value
=======================  ====================================================================
``sequence_id``          str; ``frame_index`` int; ``timestamp`` float, s since the start
``ego_pose``             (4, 4) ego-to-world; ``lidar_pose`` (4, 4) LiDAR-to-world;
                         ``lidar_to_ego`` (4, 4)
``voxel_size``           float, m; ``grid_origin`` (3,) float64, the grid's minimum corner (m,
                         LiDAR frame); ``grid_shape`` (3,) int64 (x, y, z). Voxel ``(i, j, k)``
                         has its centre at ``grid_origin + (ijk + 0.5) * voxel_size``
``occ``                  ``occupancy="sparse"`` (the default): (N, 4) int32 rows ``i, j, k,
                         semantic`` of the occupied voxels (C order); ``occ_instance`` (N,)
                         uint32; ``occ_flow`` (N, 3) float32 (m/s, world motion in the LiDAR
                         frame's axes); ``occ_mask_camera`` / ``occ_mask_lidar`` (N,) bool,
                         whether each occupied voxel is observed
``semantic``             ``occupancy="dense"`` or ``"crop"``: (X, Y, Z) uint8 (0 free);
                         ``instance`` uint32; ``flow`` (X, Y, Z, 3) float32; ``mask_camera`` /
                         ``mask_lidar`` bool; for a crop, ``crop_offset`` (3,) int64 is the
                         crop's first voxel in the grid
``images``               (C, H, W, 3) uint8 RGB of the rig's cameras (``camera_names``, list
                         of str); ``cam_intrinsics`` (C, 3, 3) float64 (OpenCV: x right, y
                         down, z forward); ``cam_to_lidar`` and ``cam_to_ego`` (C, 4, 4)
``cam_depth`` ...        the camera maps named in ``camera_maps``, each as ``cam_<map>`` (C, H,
                         W): ``cam_depth`` float32 m planar, ``cam_semantic`` uint8,
                         ``cam_instance`` uint32, ``cam_normal`` (C, H, W, 3) float16 (never
                         the bare ``semantic`` / ``instance``: those are the 3D grids)
``points``               (P, 3) float32 LiDAR points; ``points_semantic`` (P,) uint8,
                         ``points_instance`` (P,) uint32, ``points_channel`` (P,) uint8 (beam, 0 top)
``boxes``                (M, 7) float32 ``x, y, z, length, width, height, yaw`` (centre, yaw
                         about the LiDAR z from its x axis); ``box_pose`` (M, 4, 4) box-to-LiDAR
                         (pitch and roll included); ``box_velocity`` (M, 3) float32 m/s (LiDAR
                         axes); ``box_instance`` (M,) uint32 (the instance ids of ``occ`` and the
                         camera maps); ``box_semantic`` (M,) uint8
=======================  ====================================================================

Reading: a sample reads only its own frame's chunks (every Zarr chunk holds one frame), the
camera images, the frame's LiDAR file and, once per worker process and sequence (the last 256
kept), the sequence's frames and actors tables and the cameras' calibration. Sparse occupancy is gathered chunk by chunk, so a 0.05 m
frame (409 M voxels) never exists dense in memory; ``occupancy="dense"`` is refused above
``dense_limit`` voxels with the advice to use sparse or a crop.

A release: ``root`` a folder in the official CarlaOcc release's layout (the authors' download, or
``carlaocc export carlaocc-release``'s output) is read by :class:`CarlaOccReleaseDataset` with
the same options and keys, where the layout holds them (:mod:`carlaocc.catalog.release_samples`
says which: no occupancy flow or masks, no point labels, no boxes, no camera instance maps;
``voxel_size`` 0.1, 0.2 or 0.4 picks the release's grid).

Workers: the dataset holds the root's URL and an index of (sequence, frame) pairs; stores are
opened lazily in each process, so a ``torch.utils.data.DataLoader`` with workers (fork or spawn)
works on a directory or object-store root. A ``memory://`` root lives in one process: workers
started by spawn see an empty one (use a directory). Batches of variable-size samples (points,
boxes, sparse occupancy) need :func:`collate`, which stacks what has one shape and lists the rest.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from carlaocc.catalog.release_samples import ReleaseSamples, is_release
from carlaocc.catalog.samples import CAMERA_MAPS, DENSE_LIMIT, OCCUPANCY_MODES, DatasetError, FrameSamples
from carlaocc.stages.geometry import BOX_KEYS, boxes_in_frame

__all__ = ["CarlaOccDataset", "CarlaOccReleaseDataset", "DatasetError", "collate", "OCCUPANCY_MODES", "DENSE_LIMIT", "CAMERA_MAPS"]


class CarlaOccDataset(FrameSamples):
    """Frames of a built carlaocc root as samples (see the module doc for the keys).

    ``root``: a directory or fsspec URL. ``split``: ``train`` / ``val`` / ``test`` (the root's
    ``splits/``), or None for every sequence. ``voxel_size``: a built voxel size (m).
    ``occupancy``: ``sparse`` | ``dense`` | ``crop`` (with ``crop=((x0, y0, z0), (x1, y1, z1))``
    metres in the LiDAR frame: the voxels whose centres lie inside) | ``none``. ``cameras``:
    RGB images with their calibration; ``camera_maps``: which of the rendered maps to add;
    ``lidar``, ``boxes``: include those. ``sequences``: restrict to these ids. ``voxel_size``
    None: the finest voxel size every selected sequence was built at.

    No two parts of a sample share a key (:meth:`key_plan`); options under which they would are
    refused with a :class:`DatasetError`.

    The store reading is :class:`carlaocc.catalog.samples.FrameSamples`; this adds the boxes. A
    ``root`` in the release's layout gives a :class:`CarlaOccReleaseDataset` instead."""

    def __new__(cls, *args, **kwargs):
        root = args[0] if args else kwargs.get("root")
        if cls is CarlaOccDataset and root is not None and is_release(root):
            return super().__new__(CarlaOccReleaseDataset)
        return super().__new__(cls)

    def key_plan(self) -> dict[str, frozenset[str]]:
        plan = super().key_plan()
        if self.boxes:
            plan["boxes"] = frozenset(BOX_KEYS)
        return plan

    def __getitem__(self, index: int) -> dict:
        out = super().__getitem__(index)
        if self.boxes:
            out.update(boxes_in_frame(self.actor_rows(index), np.linalg.inv(out["lidar_pose"])))
        return out


class CarlaOccReleaseDataset(ReleaseSamples, CarlaOccDataset):
    """Frames of a folder in the official CarlaOcc release's layout as samples, with
    :class:`CarlaOccDataset`'s options and keys where the layout holds them (the reading and what
    it cannot hold: :class:`carlaocc.catalog.release_samples.ReleaseSamples`). ``boxes`` is
    accepted and gives nothing: the layout holds no boxes."""


def collate(batch: Sequence[dict]) -> dict:
    """A batch of samples as one dict: numpy arrays of one shape across the batch stacked on a new
    first axis, everything else (variable-size arrays, strings, lists) as a list per key. Pass it
    as ``collate_fn`` to a ``torch.utils.data.DataLoader`` (torch turns neither into tensors here:
    do it in your training step, or wrap this)."""
    out: dict = {}
    for key in batch[0]:
        values = [b[key] for b in batch]
        if all(isinstance(v, np.ndarray) for v in values) and len({v.shape for v in values}) == 1:
            out[key] = np.stack(values)
        elif all(isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) for v in values):
            out[key] = np.asarray(values)
        else:
            out[key] = values
    return out
