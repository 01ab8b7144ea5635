"""Issue 40, a researcher's first hour: the errors that misled (each one line, exit 2, the right
hint, the root untouched), the root's remembered plan as `run` and `status` use it, the last line
of a build, `carlaocc info` and `--version`."""

import os
from importlib.metadata import version

import pytest
import yaml
from typer.testing import CliRunner

from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.plan import PlanStore
from carlaocc.catalog.store import PLAN_FILE, Store
from carlaocc.pipeline.cli import app
from carlaocc.schemas.plan import Plan, PlanSlice
from carlaocc.schemas.records import SequenceRecord

cli = CliRunner()
SEQS = ("town00_high_seq000", "town00_low_seq000", "town01_medium_seq000")


@pytest.fixture
def root(tmp_path):
    """A root holding a sequences table and a remembered default plan."""
    store = Store(str(tmp_path / "root"))
    ParquetTable(store, SequenceRecord).save("s", [SequenceRecord(
        sequence_id=s, town=s[:6], seed=1, frame_count=20, rate_hz=20.0, traffic_level=s.split("_")[1],
        ego_asset_id="e") for s in SEQS])
    PlanStore(store).save(Plan())
    return store


def _tree(store):
    return {p: store.fs.cat_file(p) for p in store.fs.find(store.root)}


@pytest.mark.parametrize("args, hint", [
    (["run", "--resolution", "0.2"], "did you mean --voxel-size / --res?"),
    (["run", "--frames", "2"], "did you mean --limit-frames?"),
    (["status", "--sequence", "x"], "did you mean --sequences?"),
    (["--verison"], "no such option --verison for `carlaocc` (did you mean --version?)"),
    (["stauts"], "no such command 'stauts' (did you mean status or stages?)"),
    (["catalog", "qurey", "SELECT 1"], "no such command 'qurey' (did you mean query?)"),
    (["catalog", "query", "SELECT 1", "--rooot", "x"], "did you mean --root?"),
    (["run", "--stages", "voxelise"], "unknown stage 'voxelise' (did you mean voxelize?)"),
    (["run", "--sequences", "town00_hihg_seq000"], "no sequence 'town00_hihg_seq000' in"),
    (["export", "carlaocc-release", "--out", "{out}", "--sequence", "town00_hihg_seq000"],
     "did you mean town00_high_seq000"),
    (["show", "occupancy", "--seq", "town00_hihg_seq000", "--frame", "0", "--res", "0.2", "--out", "{out}"],
     "--seq town00_hihg_seq000: no such sequence in"),
    (["export", "carlaocc-release", "--out", "{out}", "--res", "0.2"],
     "build 0.1 m first (`carlaocc run --res 0.1 --root"),
])
def test_misleading_errors_are_one_line_with_the_right_hint(root, tmp_path, args, hint):
    out = tmp_path / "export"
    before = _tree(root)
    r = cli.invoke(app, [a.replace("{out}", str(out)) for a in args] + ["--root", root.url])
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert r.exit_code == 2, r.output
    assert len(lines) == 1 and lines[0].startswith("error:") and hint in lines[0], r.output
    assert _tree(root) == before and not out.exists()  # a refusal touches nothing


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs /proc")
def test_a_root_that_cannot_be_made_is_refused_before_any_work():
    r = cli.invoke(app, ["run", "--root", "/proc/nope"])
    assert r.exit_code == 2, r.output
    assert r.output.strip().splitlines() == [r.output.strip()]
    assert r.output.startswith("error: dataset root /proc/nope cannot be created: /proc refuses new files")


@pytest.fixture
def fake_runner(monkeypatch):
    """`run`'s engine replaced by one that records the plan it is given and starts one stage
    (the CLI's own work -- the plan, its file, its messages -- is what these tests check)."""
    from carlaocc.pipeline.engine import runner

    calls = []

    def fake(store, cfg, voxel_sizes, names, scheduler, force, progress, workers, log, sequences, wait=True):
        calls.append((cfg, voxel_sizes, sequences))
        progress.start("ingest", 0)
        return []

    monkeypatch.setattr(runner, "run", fake)
    monkeypatch.setattr(runner, "resolve_scheduler", lambda *a, **k: None)
    return calls


def test_the_root_remembers_its_plan(tmp_path, fake_runner):
    root = str(tmp_path / "new")
    r = cli.invoke(app, ["run", "--root", root, "--limit-frames", "2", "--sequences", "town00_*"])
    assert r.exit_code == 0, r.output
    cfg, sizes, seqs = fake_runner[-1]
    assert cfg.scenes.frame_count == 2 and sizes == (0.2,) and seqs == ("town00_*",)
    assert "first 2 of 20 frames of sequences town00_*" in r.output and "remembered in" in r.output
    saved = yaml.safe_load((tmp_path / "new" / PLAN_FILE).read_text())
    assert saved["slice"] == {"limit_frames": 2, "sequences": ["town00_*"]}
    # without options: the remembered plan, not the default
    r = cli.invoke(app, ["run", "--root", root])
    assert fake_runner[-1] == (cfg, sizes, seqs)
    # another plan: says which keys change and replaces it (the slice stays)
    r = cli.invoke(app, ["run", "--root", root, "--taxonomy", "carlaocc-v1", "--res", "0.1"])
    assert r.exit_code == 0, r.output
    assert "2 key(s) change: voxel_sizes: [0.2] -> [0.1], config.taxonomy: release -> carlaocc-v1" in r.output
    plan = PlanStore(Store(root)).load()
    assert plan.config.taxonomy == "carlaocc-v1" and plan.voxel_sizes == (0.1,) and plan.slice.limit_frames == 2
    # status of the remembered plan, and of other options, naming the keys they change
    r = cli.invoke(app, ["status", "--root", root, "--limit-frames", "3"])
    assert r.exit_code == 0, r.output
    assert r.output.splitlines()[0].endswith(
        f"differs from the remembered plan in {root}/{PLAN_FILE} by slice.limit_frames: 2 -> 3 "
        "(`carlaocc run` with these options would replace it)")
    # the documented way back
    r = cli.invoke(app, ["run", "--root", root, "--default-plan"])
    assert r.exit_code == 0, r.output
    cfg, sizes, seqs = fake_runner[-1]
    assert cfg.scenes.frame_count == 20 and sizes == (0.2,) and seqs == () and cfg.taxonomy == "release"
    assert PlanStore(Store(root)).load() == Plan()
    # the last line: what was built, where the report is, what to run next
    last = r.output.strip().splitlines()[-1]
    assert last.startswith(f"built in {root}: no occupancy yet; no report yet")
    assert last.endswith(f"what the root holds: carlaocc info --root {root}")


def test_a_refused_run_does_not_replace_the_plan(root):
    before = _tree(root)
    r = cli.invoke(app, ["run", "--root", root.url, "--limit-frames", "2", "--stages", "voxelize"])
    assert r.exit_code == 2 and "cannot run voxelize" in r.output
    assert _tree(root) == before


def test_info_and_version(root):
    PlanStore(root).save(Plan(slice=PlanSlice(limit_frames=2)))
    r = cli.invoke(app, ["info", "--root", root.url])
    assert r.exit_code == 0, r.output
    lines = dict(ln.split(":", 1) for ln in r.output.splitlines() if not ln.startswith(" "))
    assert lines["plan"].strip().startswith("0.2 m; first 2 of 20 frames of every sequence; label table release")
    assert lines["sequences"].strip() == "3 in 2 town(s), 60 frames planned (town00, town01)"
    assert lines["occupancy"].strip() == "none built" and lines["splits"].strip() == "none written"
    assert all(f"    {s}:" in r.output for s in SEQS)
    r = cli.invoke(app, ["--version"])
    assert r.exit_code == 0 and r.output.strip() == f"carlaocc {version('carlaocc')}"


def test_the_report_states_the_slice_it_covers():
    from carlaocc.pipeline.tasks.report import slice_line
    from carlaocc.pipeline.tasks.report_page import render_html

    seqs = [SequenceRecord(sequence_id=s, town=s[:6], seed=1, frame_count=2, rate_hz=20.0, traffic_level="low",
                           ego_asset_id="e") for s in SEQS]
    line = slice_line(seqs[:2], seqs, ("town00_*",))
    assert line == "2 of 3 sequences (--sequences town00_*), 2 frames each"
    assert slice_line(seqs, seqs, ()) == "every sequence (3), 2 frames each"
    page = render_html(root="r", sequences=seqs[:2], grids=[], totals={}, asset_rows=[], quality=[], usage=[],
                       lineage=[], images={}, slice=line)
    assert f'<p class="muted" id="slice">covers: {line}</p>' in page


def test_status_names_the_config_keys_that_changed(tmp_path):
    """A stage whose recorded config hash differs says which of its keys the options change
    against the remembered plan (`make status` said only "config changed")."""
    from datetime import datetime, timezone

    from carlaocc.catalog.lineage import LineageLog
    from carlaocc.pipeline.engine.registry import STAGES
    from carlaocc.pipeline.engine.spec import Context
    from carlaocc.schemas.records import RunRecord

    store = Store(str(tmp_path / "root"))
    plan = Plan()
    PlanStore(store).save(plan)
    ingest, cfg = STAGES["ingest"], plan.effective_config()
    [part] = ingest.partitions(Context(store, cfg, plan.voxel_sizes))
    now = datetime.now(timezone.utc)
    LineageLog(store).append("ingest", "r1", [RunRecord(
        run_id="r1", stage="ingest", partition=part.key, code_version=ingest.code_version(),
        config_hash=ingest.config_hash(cfg), cache_key="k", input_fingerprints="{}", output_fingerprints="{}",
        status="completed", started_at=now, ended_at=now, host="h")])
    other = tmp_path / "cfg.yaml"
    other.write_text(yaml.safe_dump({"ingest": {"seed": cfg.ingest.seed + 1}}))
    r = cli.invoke(app, ["status", "--root", store.url, "--config", str(other)])
    assert r.exit_code == 0, r.output
    lines = r.output.splitlines()
    assert f"by config.ingest.seed: {cfg.ingest.seed} -> {cfg.ingest.seed + 1}" in lines[0]
    assert lines[1] == "ingest    stale 1/1: 1 config changed (seed)"


def test_export_without_a_voxel_size_takes_the_remembered_plans(root, tmp_path):
    """occ3d needs a voxel size: without --voxel-size it is the remembered plan's (finest), and
    the export says so (the root holds no occupancy, so it then stops naming that size)."""
    PlanStore(root).save(Plan(voxel_sizes=(0.4, 0.8)))
    r = cli.invoke(app, ["export", "occ3d", "--out", str(tmp_path / "o"), "--root", root.url])
    assert "export occ3d: --voxel-size 0.4 (the root's remembered plan)" in r.output, r.output
    assert r.exit_code == 2 and "0.4 m" in r.output.splitlines()[-1], r.output
