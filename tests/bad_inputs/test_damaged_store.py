"""Damaged artefacts are stale, not fatal: a dataset root whose Zarr metadata (of an array, of a
group), a chunk, a lineage file or a Parquet table file is truncated or overwritten with garbage.
``status`` exits 0 and names the damaged file as the reason its stage is stale (writing nothing);
a re-run exits 0 and leaves the root equal to an undamaged build, which is never touched."""

from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path

import pytest
import yaml
from conftest import invoke, snapshot

import carlaocc
from carlaocc.schemas.configs import DatasetConfig

REPO = Path(__file__).resolve().parents[2]
VOXEL_SIZE = "0.4"
SEQ = "town00_low_seq000"
# one small town, one sequence of two frames, camera mask rays through every 8th pixel, one camera
CONFIG = {"scenes": {"frame_count": 2, "towns": [{"style": "downtown", "traffic_levels": ["low"], "blocks": 2}]},
          "voxelize": {"camera_ray_stride": 8}, "sensors": {"cameras": ["camera_00"], "lidar": False}}
STAGES = "ingest,scenes,voxelize,sensors"


def _digests(root: Path) -> dict[str, str]:
    """tools/dataset_digest.py's digests: every artefact's hash, lineage (catalog/runs) excluded."""
    spec = importlib.util.spec_from_file_location("dataset_digest", REPO / "tools" / "dataset_digest.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.digests(root)


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> tuple[Path, Path]:
    """(an undamaged root built by ``ingest,scenes,voxelize,sensors`` at 0.4 m, its config file)."""
    base = tmp_path_factory.mktemp("damaged")
    config = base / "config.yaml"
    config.write_text(yaml.safe_dump(CONFIG))
    root = base / "good"
    # one lineage file per stage (a slow machine would otherwise flush a stage's records in parts)
    from carlaocc.pipeline.engine import runner

    flush, runner._LINEAGE_FLUSH_SECONDS = runner._LINEAGE_FLUSH_SECONDS, float("inf")
    try:
        outcomes = carlaocc.run(str(root), config=DatasetConfig.model_validate(CONFIG), voxel_sizes=(float(VOXEL_SIZE),),
                                stages=STAGES.split(","), scheduler="synchronous")
    finally:
        runner._LINEAGE_FLUSH_SECONDS = flush
    assert all(not o.failed for o in outcomes) and {o.stage: o.ran for o in outcomes} == {
        "ingest": 1, "scenes": 1, "voxelize": 2, "sensors": 2}
    return root, config


def _status(root: Path, config: Path):
    return invoke("status", "--root", root, "--config", config, "--voxel-size", VOXEL_SIZE)


def _run(root: Path, config: Path):
    return invoke("run", "--root", root, "--config", config, "--voxel-size", VOXEL_SIZE, "--stages", STAGES,
                  "--scheduler", "synchronous")


def _stage_line(output: str, stage: str) -> str:
    (line,) = [ln for ln in output.splitlines() if ln.split(" ", 1)[0] == stage]
    return line


def _assert_no_traceback(result, code: int = 0) -> None:
    assert result.exit_code == code, f"exit {result.exit_code}:\n{result.output}"
    assert "Traceback" not in result.output and "error:" not in result.output, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)


OCC = f"occupancy.zarr/{SEQ}/{VOXEL_SIZE}"
# (victim: a glob under the root, the stage it makes stale, the reason status gives, partitions stale)
CASES = {
    "array metadata": (f"{OCC}/semantic/zarr.json", "voxelize", "outputs damaged: {} unreadable", "2/2"),
    "group metadata": (f"{OCC}/zarr.json", "voxelize", "outputs damaged: {} unreadable", "2/2"),
    "root metadata": ("occupancy.zarr/zarr.json", "voxelize", "outputs damaged: {} unreadable", "2/2"),
    "chunk": (f"{OCC}/instance/c/1/0/0/0", "voxelize", "outputs damaged: {} unreadable", "1/2"),
    "camera map metadata": (f"sensors.zarr/{SEQ}/camera_00/depth/zarr.json", "sensors",
                            "outputs damaged: {} unreadable", "2/2"),
    "camera group metadata": (f"sensors.zarr/{SEQ}/camera_00/zarr.json", "sensors", "outputs damaged: {} unreadable",
                              "2/2"),
    "lineage file": ("catalog/runs/stage=voxelize/*.parquet", "voxelize", "lineage unreadable: {}", "2/2"),
    "scenes table file": (f"scenes/frames/{SEQ}.parquet", "scenes", "outputs damaged: {} unreadable", "1/1"),
    "scenes table partitioned by": (f"scenes/sequences/{SEQ}.parquet", "scenes", "outputs damaged: {} unreadable",
                                    "1/1"),
}


# every artefact overwritten with garbage; the files also truncated (half their bytes) where that
# is another path through the readers (zstd blocks, JSON, Parquet footers)
DAMAGE = [(case, "garbage") for case in CASES] + [
    (case, "truncated") for case in ("array metadata", "chunk", "lineage file", "scenes table file")]


@pytest.mark.parametrize(("case", "how"), DAMAGE, ids=[f"{c}-{h}" for c, h in DAMAGE])
def test_a_damaged_artefact_is_stale_and_a_rerun_rebuilds_it(built, tmp_path, case, how):
    good, config = built
    pattern, stage, reason, stale = CASES[case]
    good_before = snapshot(good)
    root = tmp_path / "root"
    shutil.copytree(good, root)
    (victim,) = sorted(root.glob(pattern))
    rel = victim.relative_to(root).as_posix()
    data = victim.read_bytes()
    victim.write_bytes(data[: len(data) // 2] if how == "truncated" else b"\x00garbage\xff" * 3)
    damaged_bytes = victim.read_bytes()

    damaged = snapshot(root)
    r = _status(root, config)
    _assert_no_traceback(r)
    assert _stage_line(r.output, stage) == f"{stage:<9} stale {stale}: {stale.split('/')[0]} {reason.format(rel)}"
    assert snapshot(root) == damaged  # status writes nothing

    r = _run(root, config)
    _assert_no_traceback(r)
    assert f"{stage}: ran {stale.split('/')[0]}," in r.output, r.output
    if case == "lineage file":  # one line names the file and where it was set aside
        (line,) = [ln for ln in r.output.splitlines() if rel in ln]
        assert "cannot be read" in line and f"{rel}.damaged" in line
        assert (root / f"{rel}.damaged").read_bytes() == damaged_bytes  # kept as it was, no longer read
    assert _digests(root) == _digests(good)  # equal to an undamaged build
    r = _status(root, config)
    _assert_no_traceback(r)
    for s in STAGES.split(","):
        assert "up to date" in _stage_line(r.output, s), r.output
    assert snapshot(good) == good_before


def test_a_run_of_a_stage_whose_upstream_table_is_damaged_names_it(built, tmp_path):
    """A run of voxelize alone cannot partition over a damaged sequences table: one error line
    naming the file (exit 2), nothing written; the full run repairs it (above)."""
    good, config = built
    root = tmp_path / "root"
    shutil.copytree(good, root)
    victim = root / "scenes" / "sequences" / f"{SEQ}.parquet"
    victim.write_bytes(b"PAR1" + b"\x00" * 10)
    before = snapshot(root)
    r = invoke("run", "--root", root, "--config", config, "--voxel-size", VOXEL_SIZE, "--stages", "voxelize",
               "--scheduler", "synchronous")
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    (line,) = [ln for ln in r.output.splitlines() if ln.startswith("error:")]
    assert f"scenes/sequences/{SEQ}.parquet" in line and "damaged" in line
    assert snapshot(root) == before
