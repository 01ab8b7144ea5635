"""Voxelization stage: panoptic occupancy from the frame's scene meshes (see DESIGN "Occupancy grid").

``surface_voxels``/``fill_interior`` are the numba kernels (linear indices over a grid);
``voxelize_scene`` composes a frame's meshes in elevation order into semantic/instance volumes.
"""

from stages.voxelize.compose import elevation_order, voxelize_scene
from stages.voxelize.kernels import fill_interior, surface_voxels

__all__ = ["voxelize_scene", "elevation_order", "surface_voxels", "fill_interior"]
