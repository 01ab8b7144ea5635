"""The paper's dataset plan as a preset: 8 towns x (1 none, 3 low, 3 medium, 6 high) = 104
sequences of 1,000 frames at 10 Hz; --maps and --limit-frames pick towns and a slice; a slice
of one of its towns builds end to end, the traffic-free sequence included."""

from __future__ import annotations

import pytest

import yaml
from typer.testing import CliRunner

from carlaocc.catalog.presets import PAPER_LEVELS, preset_names, preset_path
from carlaocc.catalog.sql import query
from carlaocc.catalog.store import Store
from carlaocc.pipeline.cli import app
from carlaocc.schemas.configs import DatasetConfig, TownSpec

cli = CliRunner()


def test_the_paper_plan():
    assert "paper" in preset_names()
    cfg = DatasetConfig.model_validate(yaml.safe_load(preset_path("paper").read_text()))
    assert len(cfg.scenes.towns) == 8 and cfg.scenes.frame_count == 1000 and cfg.scenes.rate_hz == 10.0
    assert all({lv: t.sequences_of(lv) for lv in t.traffic_levels} == PAPER_LEVELS for t in cfg.scenes.towns)
    assert sum(t.sequences_of(lv) for t in cfg.scenes.towns for lv in t.traffic_levels) == 104
    grid = cfg.voxelize.grid(0.1)
    assert grid.shape == (768, 512, 130)  # the paper's 76.8 x 51.2 x 13 m
    r = cli.invoke(app, ["config", "--preset", "paper", "--limit-frames", "2"])
    assert r.exit_code == 0 and "plan: 8 towns, 104 simulated sequences x 2 frames at 10 Hz" in r.output


def test_plan_options_are_checked(tmp_path):
    r = cli.invoke(app, ["config", "--preset", "nope"])
    assert r.exit_code == 2 and "unknown preset 'nope'; presets: paper" in r.output
    cfg = tmp_path / "c.yaml"
    cfg.write_text("{}")
    r = cli.invoke(app, ["config", "--preset", "paper", "--config", str(cfg)])
    assert r.exit_code == 2 and "not both" in r.output
    r = cli.invoke(app, ["config", "--preset", "paper", "--maps", str(tmp_path)])
    assert r.exit_code == 2 and "no .xodr files" in r.output
    (tmp_path / "A.xodr").write_text("<OpenDRIVE/>")
    r = cli.invoke(app, ["config", "--preset", "paper", "--maps", str(tmp_path)])
    assert r.exit_code == 0 and "plan: 1 towns, 13 simulated sequences" in r.output
    assert "A.xodr" in r.output


def test_sequences_per_level_is_checked():
    spec = TownSpec(traffic_levels=("none", "high"), sequences_per_level={"none": 1, "high": 2})
    assert (spec.sequences_of("none"), spec.sequences_of("high")) == (1, 2)
    for bad in ({"none": 1}, {"none": 1, "high": 0}, {"none": 1, "high": 2, "low": 1}):
        try:
            TownSpec(traffic_levels=("none", "high"), sequences_per_level=bad)
        except ValueError as exc:
            assert "sequences_per_level" in str(exc)
        else:
            raise AssertionError(f"{bad} accepted")


@pytest.mark.slow  # `make test-all`; the default run builds every stage end to end elsewhere
def test_a_slice_of_the_plan_builds(tmp_path):
    plan = yaml.safe_load(preset_path("paper").read_text())
    plan["scenes"]["towns"] = plan["scenes"]["towns"][:1]  # the plan's first town, its 13 sequences
    path = tmp_path / "slice.yaml"
    path.write_text(yaml.safe_dump(plan))
    root = tmp_path / "data"
    r = cli.invoke(app, ["run", "--config", str(path), "--limit-frames", "2", "--res", "0.4", "--root", str(root),
                         "--stages", "ingest,scenes,voxelize", "--scheduler", "synchronous"])  # fmt: skip
    assert r.exit_code == 0, r.output
    store = Store(str(root))
    _, rows = query(store, "SELECT traffic_level, count(*), sum(frame_count) FROM sequences GROUP BY 1 ORDER BY 1")
    assert rows == [("high", 6, 12), ("low", 3, 6), ("medium", 3, 6), ("none", 1, 2)]
    # the traffic-free sequence has no actors, and its frames were voxelized
    _, actors = query(store, "SELECT count(*) FROM actors WHERE sequence_id LIKE '%none%'")
    assert actors == [(0,)]
    _, runs = query(store, "SELECT count(*) FROM runs WHERE stage = 'voxelize' AND status = 'completed'")
    assert runs[0][0] == 26


def test_config_prints_the_rig_in_the_dataset_frame():
    r = cli.invoke(app, ["config"])
    assert r.exit_code == 0
    # the YAML still loads as the same config (the rig lines are comments)
    cfg = DatasetConfig.model_validate(yaml.safe_load(r.stdout))
    assert cfg == DatasetConfig()
    lines = [ln[4:] for ln in r.stdout.splitlines() if ln.startswith("#   ")]
    # camera_02 is at CARLA y = -0.46, yaw -90: in the dataset's frame y +0.46, yaw +90, facing left
    assert any(ln.startswith("camera_02  x +0.00  y +0.46  z 1.55  yaw  +90.0 deg  left") for ln in lines)
    assert "stereo pair camera_00 (left) / camera_01 (right): baseline 0.60 m" in lines
    assert "y left" in r.stdout and "CARLA's convention" in r.stdout
