"""Voxelization stage: panoptic occupancy from the frame's scene meshes (see docs/architecture.md
"Occupancy grid").

``surface_voxels``/``fill_interior`` are the numba kernels (linear indices over a grid),
``winding_interior`` the solid fill of meshes with holes (generalized winding numbers) and
``fills`` the rule of which meshes are filled;
``voxelize_scene``/``voxelize_tiles`` compose a frame's meshes in elevation order into
semantic/instance volumes (whole, or one x-slab at a time); ``visibility_masks`` casts the rig's
camera and LiDAR rays through them (DDA ray traversal; the rig's rays as vertical fans);
``instance_flow`` gives dynamic voxels their velocity; ``pooling`` pools onto coarser grids of
ours (resampling onto other datasets' grids is :mod:`carlaocc.stages.export`).
"""

from carlaocc.stages.voxelize.compose import elevation_order, voxelize_scene, voxelize_tiles
from carlaocc.stages.voxelize.fill import FILL_MODES, fills
from carlaocc.stages.voxelize.kernels import fill_interior, surface_voxels
from carlaocc.stages.voxelize.winding import winding_interior
from carlaocc.stages.voxelize.visibility import ray_mask, visibility_masks

__all__ = ["voxelize_scene", "voxelize_tiles", "elevation_order", "surface_voxels", "fill_interior",
           "visibility_masks", "ray_mask", "FILL_MODES", "fills", "winding_interior"]
