"""A stage's code version covers exactly the code its task runs (derived from imports)."""

import sys
import textwrap

import pytest

from carlaocc.pipeline.engine import code_version as cv
from carlaocc.pipeline.engine.registry import STAGES


def closure(stage: str) -> set[str]:
    return set(cv.module_closure(STAGES[stage].task.__module__))


def test_each_stage_covers_its_compute_and_its_wiring():
    assert {"carlaocc.pipeline.tasks.voxelize", "carlaocc.stages.voxelize.kernels", "carlaocc.stages.voxelize.visibility",
            "carlaocc.stages.scenes.assembly", "carlaocc.catalog.occupancy", "carlaocc.schemas.grid"} <= closure("voxelize")
    assert {"carlaocc.stages.sensors.raycast", "carlaocc.stages.sensors.rectify", "carlaocc.catalog.sensors"} <= closure("sensors")
    assert {"carlaocc.stages.quality.continuity", "carlaocc.stages.quality.temporal"} <= closure("quality")
    assert {"carlaocc.stages.report.statistics", "carlaocc.stages.report.plots"} <= closure("report")
    assert any(m.startswith("carlaocc.stages.ingest.procedural") for m in closure("ingest"))
    assert any(m.startswith("carlaocc.stages.scenes.town.") for m in closure("scenes"))


def test_a_root_from_before_observed_bits_is_stale_not_broken():
    """A root voxelized before observed_bits existed has no such array: what writes it is in
    voxelize's code version and what reads it in quality's, so ``run`` finds both stages' frames
    changed and rebuilds them (and quality over frames without it reads the two masks:
    tests/stages/test_quality.py)."""
    assert {"carlaocc.stages.voxelize.observed", "carlaocc.catalog.occupancy"} <= closure("voxelize")
    assert {"carlaocc.stages.quality.blocks", "carlaocc.stages.quality.temporal",
            "carlaocc.catalog.occupancy"} <= closure("quality")
    from carlaocc.pipeline.tasks.voxelize import occupancy_arrays
    from carlaocc.schemas.configs import VoxelizeConfig

    assert "observed_bits" in occupancy_arrays(VoxelizeConfig())  # an output of every masked frame
    assert "observed_bits" not in occupancy_arrays(VoxelizeConfig(masks=False))


def test_a_stage_does_not_cover_code_it_never_runs():
    # editing the procedural town or the traffic re-runs the scenes stage, not every voxelized frame
    for stage in ("voxelize", "sensors", "quality"):
        ran = closure(stage)
        assert not any(m.startswith(("carlaocc.stages.scenes.town.", "carlaocc.stages.scenes.traffic.",
                                     "carlaocc.stages.ingest", "carlaocc.stages.report")) for m in ran), stage
    assert not any(m.startswith("carlaocc.stages.voxelize") for m in closure("quality"))
    assert not any(m.startswith("carlaocc.stages.quality") for m in closure("voxelize"))
    # the engine decides when tasks run, not what they write
    for stage in STAGES:
        assert not any(m == cv.ENGINE or m.startswith(cv.ENGINE + ".") for m in closure(stage)), stage


def test_every_stage_has_its_own_version():
    versions = {name: spec.code_version() for name, spec in STAGES.items()}
    assert len(set(versions.values())) == len(versions)


@pytest.fixture
def probe(tmp_path, monkeypatch):
    """A task module outside the package, importing one of ours through a re-exporting package."""
    monkeypatch.syspath_prepend(str(tmp_path))
    path = tmp_path / "cv_probe_task.py"
    path.write_text("from carlaocc.stages.quality import spatial_continuity_counts\n")
    yield path
    sys.modules.pop("cv_probe_task", None)
    for f in (cv._source, cv._tree, cv.module_closure, cv.code_version):
        f.cache_clear()


def test_re_exports_count_the_defining_module_only(probe):
    got = set(cv.module_closure("cv_probe_task"))
    assert {"cv_probe_task", "carlaocc.stages.quality", "carlaocc.stages.quality.continuity"} <= got
    # the package re-exports temporal too, but the probe does not use it
    assert "carlaocc.stages.quality.temporal" not in got


def test_editing_the_code_changes_the_version(probe):
    before = cv.code_version("cv_probe_task")
    probe.write_text(probe.read_text() + "X = 1\n")
    for f in (cv._source, cv._tree, cv.module_closure, cv.code_version):
        f.cache_clear()
    assert cv.code_version("cv_probe_task") != before


def test_a_stale_import_is_named(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(tmp_path))
    (tmp_path / "cv_stale_task.py").write_text(textwrap.dedent("""
        def task():
            from carlaocc.stages.no_such_module import f
    """))
    with pytest.raises(ImportError, match="cv_stale_task imports carlaocc.stages.no_such_module"):
        cv.module_closure("cv_stale_task")
