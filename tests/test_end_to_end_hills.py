"""End to end on a config whose town is the builtin hills.xodr (crest, sag, banked curves): the
CLI builds scenes and occupancy with pitched and rolled cars, recorded in SQL-queryable tables."""

from __future__ import annotations

import math

import numpy as np
import yaml
from typer.testing import CliRunner

from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.sql import query
from carlaocc.catalog.store import Store
from carlaocc.pipeline.cli import app
from carlaocc.schemas.configs import DatasetConfig
from carlaocc.stages.geometry import rotation_matrix

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
    # the actors table carries pitch and roll, consistent with the pose matrix
    _, rows = query(store, "SELECT pitch, roll, yaw, pose FROM actors WHERE semantic_id = 14")
    assert rows
    assert max(abs(p) for p, *_ in rows) > 0.01 or max(abs(r) for _, r, *_ in rows) > 0.05
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
