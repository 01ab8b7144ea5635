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


def test_the_registry_lists_every_format_once_with_its_writer_and_options():
    from carlaocc.pipeline.commands import export as ex

    assert list(ex.FORMATS) == ["occ3d", "semantickitti", "sscbench-kitti360", "surroundocc", "carlaocc-npz",
                                "carlaocc-release", "mmdet3d-infos", "openocc-v2", "uniocc", "det-gt"]
    for name, fmt in ex.FORMATS.items():
        assert fmt.name == name and callable(fmt.write) and fmt.description
    assert {n for n, f in ex.FORMATS.items() if "encoding" in f.options} == {"carlaocc-npz", "carlaocc-release"}
    assert ex.FORMATS["carlaocc-release"].default_voxel_size == 0.1 and ex.FORMATS["det-gt"].finest_by_default


def test_an_option_a_format_does_not_take_is_refused_before_anything_is_read(tmp_path):
    import pytest

    from carlaocc.catalog.store import Store
    from carlaocc.pipeline.commands.export import export, resolve_voxel_size
    from carlaocc.schemas.configs import DatasetConfig

    store = Store(str(tmp_path / "nothing-here"))
    with pytest.raises(ValueError, match="export occ3d takes no encoding option"):
        export(store, DatasetConfig(), "occ3d", 0.2, tmp_path / "out", encoding="bits")
    with pytest.raises(ValueError, match="encoding must be one of bits, decimal"):
        export(store, DatasetConfig(), "carlaocc-npz", 0.2, tmp_path / "out", encoding="hex")
    with pytest.raises(ValueError, match="unknown format 'occ4d'"):
        export(store, DatasetConfig(), "occ4d", 0.2, tmp_path / "out")
    with pytest.raises(ValueError, match="export occ3d needs --voxel-size"):
        resolve_voxel_size(store, "occ3d", None)
    assert resolve_voxel_size(store, "carlaocc-release", None) == 0.1
    assert not (tmp_path / "out").exists() and not (tmp_path / "nothing-here").exists()


def test_the_cli_refuses_label_encoding_for_a_format_without_it(tmp_path):
    from typer.testing import CliRunner

    from carlaocc.pipeline.cli import app

    r = CliRunner().invoke(app, ["export", "occ3d", "--out", str(tmp_path / "out"), "--voxel-size", "0.2",
                                 "--root", str(tmp_path / "root"), "--label-encoding", "decimal"])
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert r.exit_code == 2 and lines == ["error: --label-encoding applies to carlaocc-npz, carlaocc-release, not occ3d"]
    assert not (tmp_path / "out").exists() and not (tmp_path / "root").exists()
    # the help lists the registry's formats
    r = CliRunner().invoke(app, ["export", "--help"])
    assert r.exit_code == 0 and "uniocc:" in r.output and "det-gt:" in r.output
