"""End to end on a config whose town is the builtin hills.xodr (crest, sag, banked curves): the
CLI builds scenes and occupancy with pitched and rolled cars, recorded in SQL-queryable tables."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.sql import query
from carlaocc.catalog.store import Store
from carlaocc.pipeline.cli import app
from carlaocc.schemas.configs import DatasetConfig
from carlaocc.pipeline.tasks.frame import frame_inputs
from carlaocc.stages.geometry import pose_from_list, rotation_matrix, yaw_pitch_roll
from carlaocc.stages.scenes.assembly import region_of_grid
from carlaocc.stages.voxelize import voxelize_scene

HILLS = {"scenes": {"towns": [{"style": "opendrive", "opendrive": "builtin:hills.xodr", "traffic_levels": ["high"]}],
                    "frame_count": 4}}  # fmt: skip


def test_hills_config_builds_pitched_and_rolled_cars(tmp_path):
    config = tmp_path / "hills.yaml"
    config.write_text(yaml.safe_dump(HILLS))
    root = tmp_path / "data"
    r = CliRunner().invoke(app, ["run", "--config", str(config), "--res", "0.4", "--root", str(root),
                                 "--stages", "ingest,scenes,voxelize", "--scheduler", "synchronous"])  # fmt: skip
    assert r.exit_code == 0, r.output
    store = Store(str(root))
    # the actors table carries pitch and roll (the start is on a banked curve), stored consistently
    # with the pose matrix
    _, rows = query(store, "SELECT pitch, roll, yaw, pose FROM actors WHERE semantic_id = 14")
    assert rows and max(abs(r) for _, r, *_ in rows) > 0.1
    for pitch, roll, yaw, pose in rows:
        R = np.asarray(pose, dtype=float).reshape(4, 4)[:3, :3]
        assert np.allclose(R, rotation_matrix(yaw, pitch, roll), atol=1e-9)
        assert abs(pitch) < math.atan(0.16) and abs(roll) < 0.13
    # every frame was voxelized
    (seq,) = [s for (s,) in query(store, "SELECT sequence_id FROM sequences")[1]]
    cfg = DatasetConfig.model_validate(HILLS)
    grid = cfg.voxelize.grid(0.4)
    occ = OccupancyStore(store)
    for f in range(4):
        semantic = occ.read_frame(seq, grid, f, ("semantic",))["semantic"]
        assert semantic.shape == grid.shape and np.any(semantic == 14)
    # the ego is rolled too, and the stored frame was composed along the world's up in its LiDAR
    # frame: recomposing it so gives the same voxels, along the LiDAR's z other ones
    inputs = frame_inputs(store, seq, 0, region_of_grid(grid))
    assert abs(yaw_pitch_roll(pose_from_list(inputs.frame.ego_pose))[2]) > 0.1
    assert inputs.up == pytest.approx(pose_from_list(inputs.frame.lidar_pose)[2, :3])
    stored = occ.read_frame(seq, grid, 0, ("semantic",))["semantic"]
    along_up, _ = voxelize_scene(inputs.scene, grid, up=inputs.up)
    along_z, _ = voxelize_scene(inputs.scene, grid)
    assert np.array_equal(stored, along_up) and not np.array_equal(stored, along_z)
