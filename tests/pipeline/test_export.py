"""Export helpers that the end-to-end test does not reach (it builds with masks)."""

from __future__ import annotations

import numpy as np

from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.rig import RigConfig
from carlaocc.stages.export.boxes import grid_coverage
from carlaocc.stages.export.resample import OCC3D_NUSCENES, SEMANTICKITTI_GRID


def test_coverage_without_masks_is_our_region_in_the_target_grid():
    grid = GridSpec(voxel_size=0.4)  # x [-25.6, 51.2], y [-25.6, 25.6], z [-3, 10] in the LiDAR frame
    lidar_to_ego = np.asarray(RigConfig().lidar.sensor_to_ego())
    cov = grid_coverage(OCC3D_NUSCENES, grid, lidar_to_ego)
    # Occ3D x [-40, 40]: the rear 14.4 m and |y| > 25.6 m are outside our region
    assert not cov[0].any() and not cov[:, 0].any() and not cov[:, -1].any()
    assert cov[100, 100].all() and cov[-1, 100].all()
    # the forward-only SemanticKITTI grid lies inside our region entirely
    assert grid_coverage(SEMANTICKITTI_GRID, grid, np.eye(4)).all()
