"""Exports onto another dataset's grid say how much of it our built region covers: grid.json's
``built_region`` (target frame) and ``coverage``, the voxels outside marked unobserved in every
mask the format has (with its ignore label where it has one), and a warning on stderr below
100 %. The default region covers about half of Occ3D's grid; ``voxelize.region: occ3d`` all of
it (a tiny build: one sequence, two frames at 0.4 m)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from carlaocc.catalog.formats import load_occ3d, load_semantickitti
from carlaocc.pipeline.cli import app
from carlaocc.schemas.configs import DatasetConfig, named_region
from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.rig import LidarSpec
from carlaocc.stages.export.boxes import grid_coverage
from carlaocc.stages.export.resample import OCC3D_NUSCENES, SSCBENCH_KITTI360

cli = CliRunner()
SEQ = "town00_high_seq000"


def test_the_occ3d_region_is_occ3d_s_box_seen_from_the_lidar():
    lo, hi = named_region("occ3d", LidarSpec().sensor_to_ego())
    assert lo == (-40.0, -40.0, -2.73) and hi == (40.0, 40.0, 3.67)
    cfg = DatasetConfig.model_validate({"voxelize": {"region": "occ3d"}})
    assert (cfg.voxelize.region_min, cfg.voxelize.region_max) == (lo, hi)
    assert [cfg.voxelize.grid(v).shape for v in (0.4, 0.2, 0.1)] == [(200, 200, 16), (400, 400, 32), (800, 800, 64)]
    assert not any(cfg.voxelize.grid(v).grown for v in (0.05, 0.1, 0.2, 0.4))
    # the LiDAR mount moves the box; the default region is untouched (default builds stay the same)
    moved = DatasetConfig.model_validate({"scenes": {"rig": {"lidar": {"z": 2.0}}}, "voxelize": {"region": "occ3d"}})
    assert moved.voxelize.region_min[2] == -3.0 and moved.voxelize.region_max[2] == 3.4
    assert DatasetConfig().model_dump() == DatasetConfig.model_validate({}).model_dump()
    for bad in ({"region": "kitti"}, {"region": "occ3d", "region_min": [0, 0, 0]}):
        with pytest.raises(ValueError):
            DatasetConfig.model_validate({"voxelize": bad})


def test_the_default_region_covers_half_the_occ3d_grid_and_says_so(default_01, tmp_path):
    out = tmp_path / "occ3d"
    r = cli.invoke(app, ["export", "occ3d", "--res", "0.1", "--root", default_01.url, "--out", str(out),
                         "--sequence", SEQ])
    assert r.exit_code == 0, r.output
    doc = json.loads((out / "grid.json").read_text())
    assert doc["coverage"] == pytest.approx(0.5248, abs=1e-4)
    assert doc["built_region"] == {"frame": "ego", "min": [-25.6, -25.6, -1.27], "max": [51.2, 25.6, 11.73]}
    assert ("warning: the built region covers 52.5 % of the occ3d grid; voxels outside it are marked unobserved "
            "(see grid.json coverage)") in r.stderr
    inside = grid_coverage(OCC3D_NUSCENES, GridSpec(voxel_size=0.1), np.asarray(LidarSpec().sensor_to_ego()))
    for f in sorted(out.glob(f"gts/{SEQ}/*/labels.npz")):
        frame = load_occ3d(f)
        assert not frame.mask_lidar[~inside].any() and not frame.mask_camera[~inside].any()
        assert (frame.semantics[~inside] == 17).all() and frame.mask_lidar[inside].any()


@pytest.fixture(scope="module")
def occ3d_region_04(tmp_path_factory):
    """One sequence, two frames, voxelized at 0.4 m in the region occ3d."""
    base = tmp_path_factory.mktemp("occ3d_region")
    cfg = base / "cfg.json"
    cfg.write_text(json.dumps({"voxelize": {"region": "occ3d"}, "sensors": {"cameras": ["camera_00"]}}))
    root = base / "data"
    r = cli.invoke(app, ["run", "--res", "0.4", "--limit-frames", "2", "--root", str(root), "--config", str(cfg),
                         "--sequences", SEQ, "--stages", "ingest,scenes,splits,voxelize", "--scheduler", "synchronous"])
    assert r.exit_code == 0, r.output
    return str(root)


def test_with_the_occ3d_region_the_occ3d_export_covers_its_whole_grid(occ3d_region_04, tmp_path):
    out = tmp_path / "occ3d"
    r = cli.invoke(app, ["export", "occ3d", "--res", "0.4", "--root", occ3d_region_04, "--out", str(out)])
    assert r.exit_code == 0, r.output
    doc = json.loads((out / "grid.json").read_text())
    assert doc["coverage"] == 1.0 and doc["built_region"]["min"] == [-40.0, -40.0, -1.0]
    assert doc["built_region"]["max"] == [40.0, 40.0, 5.4]
    assert "warning" not in r.stderr


def test_forward_grids_beyond_the_region_carry_their_ignore_marks(occ3d_region_04, tmp_path):
    # the occ3d region stops at z 3.67 m: the KITTI grids' top (4.4 m) lies outside it
    inside = grid_coverage(SSCBENCH_KITTI360, DatasetConfig.model_validate({"voxelize": {"region": "occ3d"}})
                           .voxelize.grid(0.4), np.eye(4))
    assert 0.6 < inside.mean() < 0.7
    for fmt in ("sscbench-kitti360", "semantickitti"):
        out = tmp_path / fmt
        r = cli.invoke(app, ["export", fmt, "--res", "0.4", "--root", occ3d_region_04, "--out", str(out)])
        assert r.exit_code == 0, r.output
        assert json.loads((out / "grid.json").read_text())["coverage"] == pytest.approx(inside.mean())
        assert f"covers 68.4 % of the {fmt} grid" in r.stderr
        if fmt == "sscbench-kitti360":
            ssc = np.load(out / "preprocess" / "labels" / SEQ / "000000_1_1.npy")
            assert (ssc[~inside] == 255).all() and (ssc[inside] != 255).any()
        else:
            v = load_semantickitti(out / "sequences" / SEQ / "voxels", "000000")
            assert v.invalid[~inside].all() and v.occluded[~inside].all() and not v.occupied[~inside].any()
            assert (v.labels[~inside] == 0).all()
