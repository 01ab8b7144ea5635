"""CLI contract: one-line errors naming the culprit with exit code 2, nothing in the root touched;
SQL refusals and syntax errors exit 2 without a traceback."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.store import Store
from carlaocc.pipeline.cli import app
from carlaocc.schemas.configs import DatasetConfig
from carlaocc.schemas.records import SequenceRecord

cli = CliRunner()


@pytest.fixture
def root(tmp_path):
    """A root holding one table, to prove bad invocations leave it untouched."""
    store = Store(str(tmp_path / "root"))
    ParquetTable(store, SequenceRecord).save("s", [SequenceRecord(
        sequence_id="town00_seq000", town="town00", seed=1, frame_count=20, rate_hz=20.0,
        traffic_level="low", ego_asset_id="e")])
    return store


def _tree(store):
    fs = store.fs
    return {p: fs.cat_file(p) for p in fs.find(store.root)}


@pytest.mark.parametrize("args, culprit", [
    (["run", "--stages", "voxelise"], "unknown stage 'voxelise'"),
    (["run", "--res", "0"], "--voxel-size 0"),
    (["run", "--voxel-size", "-0.1"], "--voxel-size -0.1"),
    (["run", "--res", "nan"], "--voxel-size nan"),
    (["run", "--voxel-size", "abc"], "--voxel-size abc"),
    (["run", "--res", "14"], "smaller than one voxel"),
    (["run", "--res", "0.02"], "exceeds"),
    (["run", "--scheduler", "foo"], "--scheduler 'foo'"),
    (["run", "--stages", "voxelize"], "cannot run voxelize"),
])
def test_bad_invocations_exit_2_and_touch_nothing(root, args, culprit):
    before = _tree(root)
    r = cli.invoke(app, [*args, "--root", root.url])
    assert r.exit_code == 2, r.output
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:") and culprit in lines[0]
    assert _tree(root) == before


def test_bad_invocation_on_a_new_root_creates_nothing(tmp_path):
    new = tmp_path / "new-root"
    for args in (["--stages", "metrics"], ["--scheduler", "nonsense://x:1"], ["--res", "0"]):
        r = cli.invoke(app, ["run", "--root", str(new), *args])
        assert r.exit_code == 2, r.output
        assert not new.exists()


def test_config_with_unknown_key(root, tmp_path):
    cfg = tmp_path / "c.yaml"
    cfg.write_text("scenes:\n  frame_cont: 3\n")
    before = _tree(root)
    r = cli.invoke(app, ["run", "--config", str(cfg), "--root", root.url])
    assert r.exit_code == 2
    assert "unknown key 'scenes.frame_cont'" in r.output and str(cfg) in r.output
    assert _tree(root) == before


def test_missing_config_file(root, tmp_path):
    r = cli.invoke(app, ["run", "--config", str(tmp_path / "nope.yaml"), "--root", root.url])
    assert r.exit_code == 2 and "nope.yaml does not exist" in r.output


def test_unwritable_root(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    r = cli.invoke(app, ["run", "--root", str(f)])
    assert r.exit_code == 2 and str(f) in r.output and f.read_text() == "x"


def test_query_table_csv_json(root):
    r = cli.invoke(app, ["catalog", "query", "SELECT sequence_id, frame_count FROM sequences", "--root", root.url])
    assert r.exit_code == 0 and "town00_seq000" in r.output and "(1 rows)" in r.output
    r = cli.invoke(app, ["catalog", "query", "SELECT frame_count FROM sequences", "--root", root.url, "--format", "csv"])
    assert r.output.split() == ["frame_count", "20"]
    r = cli.invoke(app, ["catalog", "query", "SELECT frame_count FROM sequences", "--root", root.url, "--format", "json"])
    import json

    assert json.loads(r.output) == [{"frame_count": 20}]


@pytest.mark.parametrize("sql", ["DELETE FROM sequences", "COPY sequences TO 'x.csv'", "ATTACH 'x.db'",
                                 "INSTALL httpfs", "DROP VIEW sequences", "CREATE TABLE t (a INT)"])
def test_query_refusals_exit_2(root, sql):
    before = _tree(root)
    r = cli.invoke(app, ["catalog", "query", sql, "--root", root.url])
    assert r.exit_code == 2 and "read-only" in r.output and "Traceback" not in r.output
    assert _tree(root) == before


def test_query_syntax_error_exit_2(root):
    r = cli.invoke(app, ["catalog", "query", "SELEC 1", "--root", root.url])
    assert r.exit_code == 2 and "syntax error" in r.output.lower() and "Traceback" not in r.output


def test_query_unknown_table_exit_2(root):
    r = cli.invoke(app, ["catalog", "query", "SELECT * FROM nope", "--root", root.url])
    assert r.exit_code == 2 and "nope" in r.output


def test_help_lists_commands():
    r = cli.invoke(app, ["--help"])
    assert r.exit_code == 0
    for cmd in ("run", "status", "stages", "catalog"):
        assert cmd in r.output
    r = cli.invoke(app, ["run", "--help"])
    assert "--scheduler" in r.output and "--force" in r.output


def test_query_json_has_no_nan(tmp_path):
    import json

    from carlaocc.schemas.records import QualityRecord

    store = Store(str(tmp_path / "r"))
    ParquetTable(store, QualityRecord).save("q", [QualityRecord(
        sequence_id="s", voxel_size=0.2, frame_index=None, metric="m", value=float("nan"), occupied=0, isolated=0)])
    r = cli.invoke(app, ["catalog", "query", "SELECT value, frame_index FROM quality", "--root", store.url, "--format", "json"])
    assert r.exit_code == 0 and json.loads(r.output) == [{"value": None, "frame_index": None}]


def test_stage_names_and_the_retired_metrics_name(tmp_path):
    from carlaocc.pipeline.engine.registry import STAGES
    from carlaocc.pipeline.engine.runner import PlanError, stage_order

    assert list(STAGES) == ["ingest", "scenes", "splits", "voxelize", "sensors", "quality", "aggregate", "report"]
    assert [s.name for s in stage_order(["quality", "voxelize"])] == ["voxelize", "quality"]
    # the earlier name is refused with the one to use, on the command line and in a config file
    with pytest.raises(PlanError, match="stage 'metrics' was renamed 'quality': use --stages quality"):
        stage_order(["metrics", "voxelize"])
    with pytest.raises(PlanError, match="unknown stage 'metric'"):
        stage_order(["metric"])
    # the top-level help names every stage
    r = cli.invoke(app, ["--help"])
    assert r.exit_code == 0 and all(f"{name}:" in r.output for name in STAGES)
    cfg = tmp_path / "old.yaml"
    cfg.write_text("metrics:\n  neighbourhood: 6\n")
    r = cli.invoke(app, ["run", "--config", str(cfg), "--root", str(tmp_path / "new")])
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert r.exit_code == 2 and len(lines) == 1, r.output
    assert "config section 'metrics' was renamed 'quality'" in lines[0] and "Value error" not in lines[0]
    assert not (tmp_path / "new").exists()


def test_compare_voxel_sizes_and_the_retired_compare_resolutions_name(tmp_path):
    # the command's earlier name is refused in one line naming the new one (options or --help
    # alike), is left out of --help, and touches no root
    for args in ([], ["--fine", "0.05", "--coarse", "0.2", "--root", str(tmp_path / "r")], ["--help"]):
        r = cli.invoke(app, ["compare-resolutions", *args])
        lines = [ln for ln in r.output.splitlines() if ln.strip()]
        assert r.exit_code == 2 and len(lines) == 1, r.output
        assert lines[0] == ("error: compare-resolutions was renamed compare-voxel-sizes: "
                            "use carlaocc compare-voxel-sizes ..."), lines[0]
    assert not (tmp_path / "r").exists()
    top = cli.invoke(app, ["--help"]).output
    assert "compare-voxel-sizes" in top and "compare-resolutions" not in top
    r = cli.invoke(app, ["compare-voxel-sizes", "--help"])
    assert r.exit_code == 0 and "--fine" in r.output and "voxel size" in r.output and "resolution" not in r.output
