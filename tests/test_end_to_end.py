"""End to end on the embedded default at a coarse voxel size: ingest -> scenes -> voxelize ->
metrics through the CLI, then the arrays, the catalog, re-runs and scheduler independence."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import zarr
from typer.testing import CliRunner

from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.sql import query
from carlaocc.catalog.store import Store
from carlaocc.pipeline.cli import app
from carlaocc.schemas import taxonomy
from carlaocc.schemas.configs import DatasetConfig
from carlaocc.schemas.grid import GridSpec

VOXEL_SIZE = 0.4
cli = CliRunner()
# the embedded default with shorter sequences (3 x 6 frames instead of 3 x 20): every stage and
# every path of the default, at a fraction of the suite's time (`make test-all` builds the full
# default at 0.05 m)
E2E = DatasetConfig.model_validate({"scenes": {"frame_count": 6}})
F = E2E.scenes.frame_count


@pytest.fixture(scope="module")
def config_file(tmp_path_factory) -> str:
    path = tmp_path_factory.mktemp("e2e_config") / "e2e.json"
    path.write_text(E2E.model_dump_json())
    return str(path)


@pytest.fixture(scope="module")
def built(tmp_path_factory, config_file):
    root = tmp_path_factory.mktemp("e2e") / "data"
    r = cli.invoke(app, ["run", "--config", config_file, "--res", str(VOXEL_SIZE), "--root", str(root),
                         "--scheduler", "synchronous"])
    assert r.exit_code == 0, r.output
    return Store(str(root))


def _snapshot(store: Store) -> dict[str, tuple[int, bytes]]:
    """Every file's modification time (ns) and bytes."""
    import os

    return {p: (os.stat(p).st_mtime_ns, store.fs.cat_file(p)) for p in store.fs.find(store.root)}


def test_occupancy_arrays(built):
    grid = GridSpec(voxel_size=VOXEL_SIZE)
    seq = query(built, "SELECT min(sequence_id) FROM sequences")[1][0][0]
    occ = OccupancyStore(built)
    sem_arr = occ.open(seq, grid, "semantic")
    inst_arr = occ.open(seq, grid, "instance")
    frames = E2E.scenes.frame_count
    # region and attributes
    assert sem_arr.shape == inst_arr.shape == (frames, *grid.shape)
    assert sem_arr.dtype == np.uint8 and inst_arr.dtype == np.uint32
    attrs = dict(sem_arr.attrs)
    assert attrs["origin"] == [-25.6, -25.6, -3.0] and attrs["voxel_size"] == VOXEL_SIZE
    assert attrs["frame"] == "lidar" and attrs["taxonomy_version"] == taxonomy.TAXONOMY_VERSION
    assert attrs["effective_region"][1] == pytest.approx(list(grid.effective_max))
    sem, inst = sem_arr[0], inst_arr[0]
    # classes present: the town and its traffic
    present = {taxonomy.by_id(int(c)).name for c in np.unique(sem) if c}
    for name in ("Road", "Sidewalk", "Building", "Car", "Vegetation", "Terrain"):
        assert name in present, f"{name} missing from frame 0 (present: {sorted(present)})"
    # stuff voxels carry instance 0, thing voxels an instance id
    things = np.isin(sem, taxonomy.thing_ids())
    assert not inst[~things].any()
    assert inst[things].all()
    # instances are distinct objects: one class per id, except a traffic light's pole and head
    # (one placed object, two classes: the release's table makes both things); several cars
    ids, first = np.unique(inst[things], return_index=True)
    cls_of = sem[things][first]
    pole_and_light = {taxonomy.by_name(n).id for n in ("Pole", "TrafficLight", "TrafficSign")}
    for i in ids:
        classes = set(np.unique(sem[things][inst[things] == i]).tolist())
        assert len(classes) == 1 or classes <= pole_and_light, f"instance {i} spans classes {classes}"
    car = taxonomy.by_name("Car").id
    assert (cls_of == car).sum() >= 3
    # the release's table: poles are instances, buildings are not
    assert (inst[sem == taxonomy.by_name("Pole").id] > 0).all() and not inst[sem == taxonomy.by_name("Building").id].any()
    # the road lies under the LiDAR at about -1.73 m
    road = taxonomy.by_name("Road").id
    k = np.flatnonzero((sem == road).any(axis=(0, 1)))
    z_road = -3.0 + (k.mean() + 0.5) * VOXEL_SIZE
    assert -2.4 < z_road < -1.2


def test_instances_are_stable_across_frames(built):
    grid = GridSpec(voxel_size=VOXEL_SIZE)
    seq = query(built, "SELECT min(sequence_id) FROM sequences")[1][0][0]
    occ = OccupancyStore(built)
    a, b = occ.read_frame(seq, grid, 0), occ.read_frame(seq, grid, 5)
    # an instance seen in both frames keeps its class
    common = np.intersect1d(np.unique(a["instance"]), np.unique(b["instance"]))
    common = common[common > 0]
    assert common.size > 0
    for i in common:
        assert np.unique(a["semantic"][a["instance"] == i]).tolist() == np.unique(b["semantic"][b["instance"] == i]).tolist()


def test_catalog_tables_and_metrics(built):
    _, rows = query(built, "SELECT count(*), count(DISTINCT category) FROM assets")
    n_assets, n_categories = rows[0]
    assert n_assets >= 50 and n_categories >= 9
    scenes = E2E.scenes
    n_seq = sum(t.sequences_of(level) for t in scenes.towns for level in t.traffic_levels)
    _, rows = query(built, "SELECT count(*) FROM frames")
    assert rows[0][0] == scenes.frame_count * n_seq
    _, rows = query(built, "SELECT value FROM quality WHERE frame_index IS NULL AND metric = 'spatial_continuity'")
    assert len(rows) == n_seq and all(0.9 < r[0] <= 1.0 for r in rows)
    _, rows = query(built, "SELECT DISTINCT stage FROM runs WHERE status = 'completed' ORDER BY 1")
    assert [r[0] for r in rows] == ["aggregate", "ingest", "quality", "report", "scenes", "sensors", "splits",
                                    "voxelize"]
    _, rows = query(built, "SELECT count(*) FROM quality_classes q JOIN classes c ON q.semantic_id = c.id WHERE c.name = 'Car'")
    assert rows[0][0] > 0


def test_report_and_statistics_tables(built):
    """The report stage: statistics tables agree with the occupancy, and report.html opens offline."""
    import re

    seq = query(built, "SELECT min(sequence_id) FROM sequences")[1][0][0]
    occ = OccupancyStore(built)
    sem = occ.open(seq, GridSpec(voxel_size=VOXEL_SIZE), "semantic")[:]
    _, rows = query(built, f"SELECT semantic_id, voxels, instances FROM statistics_classes WHERE sequence_id = '{seq}'")
    voxels = {r[0]: r[1] for r in rows}
    assert voxels == {int(c): int((sem == c).sum()) for c in np.unique(sem)}
    assert dict((r[0], r[2]) for r in rows)[taxonomy.by_name("Car").id] >= 3
    _, rows = query(built, "SELECT sum(assets) FROM statistics_assets")
    assert rows[0][0] == query(built, "SELECT count(*) FROM assets")[1][0][0]
    page = built.read_bytes("metrics/report.html").decode()
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:|//)""", page) and "<script" not in page
    assert page.count("data:image/png;base64,") >= 6 and "sensors.zarr" in page and 'id="lineage"' in page


def _metrics(store: Store) -> dict[str, list]:
    tables = {"quality": "sequence_id, voxel_size, frame_index, metric, value, occupied, isolated, numerator, denominator",
              "quality_classes": "sequence_id, voxel_size, frame_index, semantic_id, occupied, isolated",
              "statistics_classes": "*", "statistics_frames": "*"}
    return {t: sorted(query(store, f"SELECT {cols} FROM {t}")[1], key=repr) for t, cols in tables.items()}


def test_quality_map_reduce_is_independent_of_the_frames_per_task(config_file, built, tmp_path):
    """Scoring 3 frames per task (3 tasks a sequence, the pairs across their borders read from the
    next task's first frame) gives every row bit-identical to scoring a whole sequence in one
    task, and to the scores computed in one pass over the frames here; going back to one task a
    sequence retires the other tasks and leaves none of their rows behind."""
    import shutil

    from carlaocc.stages.quality import (column_ranges, sequence_continuity, sequence_temporal,
                                         spatial_continuity_counts, temporal_consistency_counts)

    copy = Store(str(tmp_path / "copy"))
    shutil.copytree(built.root, copy.root)
    cfg = tmp_path / "k3.json"
    cfg.write_text(E2E.model_copy(update={"quality": E2E.quality.model_copy(update={"frames_per_task": 3})})
                   .model_dump_json())
    r = cli.invoke(app, ["run", "--config", str(cfg), "--res", str(VOXEL_SIZE), "--root", copy.url, "--stages",
                         "quality,aggregate", "--scheduler", "synchronous"])
    runs = -(-F // 3)  # quality tasks a sequence
    assert r.exit_code == 0 and f"quality: ran {3 * runs}," in r.output and "aggregate: ran 3," in r.output, r.output
    assert len(copy.glob("metrics/statistics_frames", ".parquet")) == 3 * runs
    a, b = _metrics(built), _metrics(copy)
    assert a == b and len(a["quality"]) == 3 * (F + F - 1 + 2) and len(a["statistics_frames"]) > 3 * F
    # back to one task a sequence: the runs of frames after the first three are retired (their files removed,
    # their lineage says so), the tables hold each row once, and verify finds nothing missing
    r = cli.invoke(app, ["run", "--config", config_file, "--res", str(VOXEL_SIZE), "--root", copy.url, "--stages",
                         "quality,aggregate", "--scheduler", "synchronous"])
    assert r.exit_code == 0 and "quality: ran 3," in r.output, r.output
    assert len(copy.glob("metrics/statistics_frames", ".parquet")) == 3 and _metrics(copy) == a
    retired = query(copy, "SELECT count(*) FROM runs WHERE stage = 'quality' AND status = 'retired'")[1][0][0]
    assert retired == 3 * (runs - 1)
    r = cli.invoke(app, ["verify", "--root", copy.url, "--stages", "quality,aggregate"])
    assert r.exit_code == 0 and "quality   3/3 partitions intact" in r.output, r.output
    # the sequence rows against one pass over the frames
    grid = GridSpec(voxel_size=VOXEL_SIZE)
    occ = OccupancyStore(built)
    seq = query(built, "SELECT min(sequence_id) FROM sequences")[1][0][0]
    poses = {f: np.asarray(p, float).reshape(4, 4) for f, p in
             query(built, f"SELECT frame_index, lidar_pose FROM frames WHERE sequence_id = '{seq}'")[1]}
    frames = [occ.read_frame(seq, grid, t, ("semantic", "mask_camera", "mask_lidar")) for t in range(F)]
    sems = [f["semantic"] for f in frames]
    masks = [(f["mask_camera"] | f["mask_lidar"]).astype(bool) for f in frames]
    # what the stage read: the masks' union as voxelize kept it in bits
    for t in range(F):
        bits = occ.read_frame(seq, grid, t, ("observed_bits",))["observed_bits"]
        np.testing.assert_array_equal(np.unpackbits(bits, axis=-1, count=grid.shape[2], bitorder="little"), masks[t])
    cont = sequence_continuity([spatial_continuity_counts(s) for s in sems])
    temp = sequence_temporal([temporal_consistency_counts(sems[t], sems[t + 1], poses[t], poses[t + 1], VOXEL_SIZE, grid.origin,
                                                          mask_t=masks[t], mask_t1=masks[t + 1],
                                                          ranges_t=column_ranges(sems[t]))
                              for t in range(F - 1)])
    rows = dict(query(built, f"SELECT metric, value FROM quality WHERE sequence_id = '{seq}' AND frame_index IS NULL")[1])
    assert rows == {"spatial_continuity": cont.score, "temporal_consistency": temp.score}


def test_scene_tables(built):
    """Two towns (a procedural style and the builtin OpenDRIVE town), several traffic levels,
    rig poses every frame, actors with angular velocity and matched gait phases."""
    _, rows = query(built, "SELECT town, style, lane_count, crosswalk_count, placement_count FROM towns ORDER BY 1")
    assert [r[:2] for r in rows] == [("town00", "downtown"), ("town01", "opendrive")]
    assert all(r[2] > 10 and r[3] > 0 and r[4] > 50 for r in rows)
    _, rows = query(built, "SELECT DISTINCT traffic_level FROM sequences")
    assert len(rows) >= 2
    _, rows = query(built, "SELECT count(*) FROM sensor_poses")
    assert rows[0][0] == 7 * query(built, "SELECT count(*) FROM frames")[1][0][0]
    _, rows = query(built, "SELECT count(*) FILTER (WHERE is_thing), count(*) FILTER (WHERE aabb_max[3] < aabb_min[3]) "
                           "FROM placements")
    assert rows[0][0] > 50 and rows[0][1] == 0
    _, rows = query(built, "SELECT count(*), count(phase_index), min(phase_index), max(phase_index) FROM actors a "
                           "JOIN classes c ON a.semantic_id = c.id WHERE c.name = 'Pedestrian'")
    n, with_phase, lo, hi = rows[0]
    assert n > 0 and with_phase == n and -1 <= lo and hi < 32
    _, rows = query(built, "SELECT max(abs(angular_velocity[3])) FROM actors")
    assert rows[0][0] > 0.05  # somebody turns


def test_town_and_frame_mesh_exports(built, tmp_path):
    from carlaocc.catalog.panoptic import load_panoptic_glb

    out = tmp_path / "town00.glb"
    r = cli.invoke(app, ["scenes", "town-mesh", "town00", "--out", str(out), "--root", built.url])
    assert r.exit_code == 0, r.output
    V, F, sem, inst, transparent = load_panoptic_glb(out.read_bytes())
    present = {taxonomy.by_id(int(c)).name for c in np.unique(sem)}
    assert {"Road", "Sidewalk", "Building", "RoadLine", "Terrain"} <= present
    assert (inst[np.isin(sem, taxonomy.stuff_ids())] == 0).all() and len(np.unique(inst)) > 50
    r = cli.invoke(app, ["scenes", "town-mesh", "town99", "--out", str(out), "--root", built.url])
    assert r.exit_code == 2 and "town99" in r.output
    seq = query(built, "SELECT min(sequence_id) FROM sequences")[1][0][0]
    out = tmp_path / "frame.glb"
    r = cli.invoke(app, ["scenes", "frame-mesh", seq, "3", "--out", str(out), "--root", built.url])
    assert r.exit_code == 0, r.output
    V, F, sem, inst, transparent = load_panoptic_glb(out.read_bytes())
    assert (np.isin(sem, taxonomy.thing_ids()) == (inst > 0)).all() and transparent.any()
    assert np.abs(V[:, :2]).max() < 60.0  # LiDAR frame, cut to the occupancy region
    r = cli.invoke(app, ["scenes", "frame-mesh", seq, "999", "--out", str(out), "--root", built.url])
    assert r.exit_code == 2 and "no frame 999" in r.output


def test_rerun_with_nothing_changed_writes_nothing(config_file, built):
    before = _snapshot(built)
    r = cli.invoke(app, ["run", "--config", config_file, "--res", str(VOXEL_SIZE), "--root", built.url, "--scheduler", "synchronous"])
    assert r.exit_code == 0 and "nothing to do" in r.output
    assert _snapshot(built) == before
    r = cli.invoke(app, ["status", "--config", config_file, "--res", str(VOXEL_SIZE), "--root", built.url])
    assert r.exit_code == 0 and "stale" not in r.output


def test_local_cluster_output_is_byte_identical(config_file, built, tmp_path):
    """The same graph on a distributed LocalCluster (every stage, one sequence: the busiest)
    writes the same bytes as the synchronous run of the whole default."""
    root = tmp_path / "dist"
    seq = "town00_high_seq000"
    r = cli.invoke(app, ["run", "--config", config_file, "--res", str(VOXEL_SIZE), "--root", str(root), "--workers", "2",
                         "--sequences", seq])
    assert r.exit_code == 0, r.output
    a, b = _snapshot(built), _snapshot(Store(str(root)))
    # lineage differs (run ids, times), and the report over one sequence is not the whole one's
    # plan.yaml: the run remembers the slice it was asked for (one sequence), the API build has none
    strip = lambda snap, base: {k[len(base):]: v[1] for k, v in snap.items()
                                if "/catalog/runs/" not in k and not k.endswith("/metrics/report.html")
                                and "/metrics/plots/" not in k and not k.endswith("/plan.yaml")}
    sa, sb = strip(a, built.root), strip(b, str(root))
    assert sb.keys() <= sa.keys()
    assert [k for k in sb if sa[k] != sb[k]] == []
    # every stage's outputs of the sequence are among those compared
    for part in (f"/occupancy.zarr/{seq}/", f"/sensors.zarr/{seq}/", f"/lidar/{seq}/", f"/metrics/quality/{seq}/",
                 f"/metrics/statistics_classes/{seq}/", "/admesh/", "/scenes/", "/splits/"):
        assert any(k.startswith(part) for k in sb), part
    assert not any(k.startswith("/occupancy.zarr/town01") for k in sb)


def test_tampered_frame_is_detected_and_rebuilt(config_file, built, tmp_path):
    """Deleting one chunk of one frame makes exactly that frame stale; a run rebuilds it."""
    import shutil

    copy = Store(str(tmp_path / "copy"))
    shutil.copytree(built.root, copy.root)
    grid = GridSpec(voxel_size=VOXEL_SIZE)
    seq = query(copy, "SELECT min(sequence_id) FROM sequences")[1][0][0]
    chunk_dir = f"{copy.root}/occupancy.zarr/{seq}/{grid.key}/semantic/c/3"
    victim = sorted(copy.fs.find(chunk_dir))[0]
    copy.fs.rm(victim)
    r = cli.invoke(app, ["status", "--config", config_file, "--res", str(VOXEL_SIZE), "--root", copy.url, "-v"])
    assert "voxelize  stale 1/" in r.output and f"{seq}/{grid.key}/0003: outputs missing or modified" in r.output
    r = cli.invoke(app, ["run", "--config", config_file, "--res", str(VOXEL_SIZE), "--root", copy.url, "--scheduler", "synchronous"])
    # the rebuilt frame is byte-identical, so what metrics read is unchanged: it stays up to date
    assert r.exit_code == 0 and "voxelize: ran 1," in r.output and "quality: 3 up to date" in r.output
    np.testing.assert_array_equal(OccupancyStore(copy).read_frame(seq, grid, 3)["semantic"],
                                  OccupancyStore(built).read_frame(seq, grid, 3)["semantic"])


_OPENED: list[str] | None = None  # paths opened while recording (see _opened_files)


def _audit(event: str, args) -> None:
    if _OPENED is not None and event == "open" and isinstance(args[0], (str, bytes)):
        _OPENED.append(args[0] if isinstance(args[0], str) else args[0].decode())


def _opened_files(fn) -> list[str]:
    """Every file this process opened while ``fn`` ran (Python's audit hook: builtins.open,
    os.open, io.open_code...)."""
    import sys

    global _OPENED
    if not getattr(_opened_files, "hooked", False):
        sys.addaudithook(_audit)
        _opened_files.hooked = True
    _OPENED = []
    try:
        fn()
        return list(_OPENED)
    finally:
        _OPENED = None


def test_status_reads_no_chunk_data_and_verify_rehashes(config_file, built, tmp_path):
    """``status`` on a built root trusts the fingerprints recorded at write time while the outputs'
    stat signatures hold: it opens no chunk of any Zarr array (nor a LiDAR sweep, a mesh, a
    picture). A copied root (new inodes) is re-hashed once by ``verify``, which records its
    signatures; a chunk overwritten in place with garbage of the same size and its times put back
    is seen by ``status`` (its ctime moved) and by ``verify``, which drops the partition's
    signatures; ``run`` rebuilds it."""
    import os
    import shutil

    copy = Store(str(tmp_path / "copy"))
    shutil.copytree(built.root, copy.root)
    status = lambda: cli.invoke(app, ["status", "--config", config_file, "--res", str(VOXEL_SIZE), "--root", copy.url, "-v"])
    r = cli.invoke(app, ["verify", "--root", copy.url])
    assert r.exit_code == 0, r.output
    assert f"voxelize  {3 * F}/{3 * F} partitions intact" in r.output and f"signatures recorded anew for {3 * F}" in r.output
    out = []
    opened = _opened_files(lambda: out.append(status()))
    assert out[0].exit_code == 0 and "stale" not in out[0].output, out[0].output
    data = [p for p in opened if p.startswith(copy.root) and (
        ".zarr/" in p and "/c/" in p or "/lidar/" in p or p.endswith((".glb", ".png", ".npz", ".html")))]
    assert data == []
    assert any(p.endswith(".parquet") for p in opened)  # it did look at the catalog
    # a second verify finds every signature as recorded
    r = cli.invoke(app, ["verify", "--root", copy.url, "--stages", "voxelize"])
    assert r.exit_code == 0 and "recorded anew" not in r.output, r.output
    # garbage in place, same size, its times put back: status sees it too (the ctime moved)
    grid = GridSpec(voxel_size=VOXEL_SIZE)
    seq = query(copy, "SELECT min(sequence_id) FROM sequences")[1][0][0]
    victim = sorted(copy.fs.find(f"{copy.root}/occupancy.zarr/{seq}/{grid.key}/semantic/c/2"))[0]
    st = os.stat(victim)
    with open(victim, "r+b") as f:
        f.write(b"\xff" * st.st_size)
    os.utime(victim, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert f"voxelize  stale 1/{3 * F}" in status().output
    r = cli.invoke(app, ["verify", "--root", copy.url, "-v"])
    assert r.exit_code == 1 and f"{seq}/{grid.key}/0002: outputs damaged: occupancy.zarr/{seq}/{grid.key}/semantic" in r.output
    after = status().output
    assert f"voxelize  stale 1/{3 * F}" in after and f"    {seq}/{grid.key}/0002: outputs damaged" in after
    r = cli.invoke(app, ["run", "--config", config_file, "--res", str(VOXEL_SIZE), "--root", copy.url, "--stages", "voxelize",
                         "--scheduler", "synchronous"])
    assert r.exit_code == 0 and "voxelize: ran 1," in r.output, r.output
    assert cli.invoke(app, ["verify", "--root", copy.url, "--stages", "voxelize"]).exit_code == 0


def test_swap_makes_a_sequence_that_voxelizes(config_file, built, tmp_path):
    """``scenes swap`` on a copy: the edited sequence keeps the trajectories (same instances in
    the same places) with other car models, and the pipeline voxelizes it."""
    import shutil

    copy = Store(str(tmp_path / "copy"))
    shutil.copytree(built.root, copy.root)
    seq = query(copy, "SELECT min(sequence_id) FROM sequences")[1][0][0]
    r = cli.invoke(app, ["scenes", "swap", "--class", "Car", "--seed", "5", "--sequence", seq, "--root", copy.url])
    assert r.exit_code == 0 and "Car actor(s)" in r.output, r.output
    new = query(copy, f"SELECT sequence_id FROM sequences WHERE parent_sequence_id = '{seq}'")[1][0][0]
    r = cli.invoke(app, ["run", "--config", config_file, "--res", str(VOXEL_SIZE), "--root", copy.url, "--scheduler", "synchronous",
                         "--stages", "voxelize", "--sequences", new])
    assert r.exit_code == 0 and f"voxelize: ran {F}," in r.output, r.output
    grid = GridSpec(voxel_size=VOXEL_SIZE)
    a, b = OccupancyStore(copy).read_frame(seq, grid, 0), OccupancyStore(copy).read_frame(new, grid, 0)
    car = taxonomy.by_name("Car").id
    cars_a = set(np.unique(a["instance"][a["semantic"] == car]))
    cars_b = set(np.unique(b["instance"][b["semantic"] == car]))
    assert cars_a and cars_a == cars_b
    assert not np.array_equal(a["semantic"], b["semantic"])  # other models, other voxels


def test_building_swap_changes_voxels_only_where_the_swapped_buildings_stand(config_file, built, tmp_path):
    """``scenes swap --class Building`` (static objects) on a copy: new buildings on the same lots,
    traffic unchanged; the edited sequence's occupancy differs from the original's only inside
    the boxes of the swapped buildings (old or new, one voxel of margin). A class with nothing to
    swap writes nothing and exits 2."""
    import shutil

    from carlaocc.catalog.parquet import ParquetTable
    from carlaocc.schemas.records import FrameRecord, PlacementRecord, SequenceRecord
    from carlaocc.stages.geometry import invert_pose, transform_points

    copy = Store(str(tmp_path / "copy"))
    shutil.copytree(built.root, copy.root)
    seq = query(copy, "SELECT min(sequence_id) FROM sequences")[1][0][0]
    before = sorted(p.name for p in Path(copy.root, "scenes").rglob("*.parquet"))
    r = cli.invoke(app, ["scenes", "swap", "--class", "Train", "--seed", "5", "--sequence", seq, "--root", copy.url])
    assert r.exit_code == 2 and "nothing to swap" in r.output, r.output
    assert sorted(p.name for p in Path(copy.root, "scenes").rglob("*.parquet")) == before  # nothing written
    r = cli.invoke(app, ["scenes", "swap", "--class", "Building", "--seed", "5", "--sequence", seq, "--root", copy.url])
    assert r.exit_code == 0 and "static placement(s) swapped" in r.output, r.output
    (new,) = [s for s in ParquetTable(copy, SequenceRecord).load() if s.parent_sequence_id == seq]
    old_pl = {p.placement_id: p for p in ParquetTable(copy, PlacementRecord).load([f"town={new.town}"])}
    new_pl = {p.placement_id: p for p in ParquetTable(copy, PlacementRecord).load([new.placements_key()])}
    assert old_pl.keys() == new_pl.keys()
    swapped = [k for k in old_pl if old_pl[k].asset_id != new_pl[k].asset_id]
    assert swapped and all(old_pl[k].semantic_id == taxonomy.by_name("Building").id for k in swapped)
    assert all(old_pl[k].pose == new_pl[k].pose for k in swapped)  # same lots
    r = cli.invoke(app, ["run", "--config", config_file, "--res", str(VOXEL_SIZE), "--root", copy.url,
                         "--stages", "voxelize", "--scheduler", "synchronous"])
    assert r.exit_code == 0, r.output
    grid = GridSpec(voxel_size=VOXEL_SIZE)
    a = OccupancyStore(copy).read_frame(seq, grid, 0, ("semantic", "instance"))
    b = OccupancyStore(copy).read_frame(new.sequence_id, grid, 0, ("semantic", "instance"))
    differ = (a["semantic"] != b["semantic"]) | (a["instance"] != b["instance"])
    assert differ.any()
    # every differing voxel centre lies in the LiDAR-frame box of a swapped building, old or new
    (f0,) = [f for f in ParquetTable(copy, FrameRecord).load([seq]) if f.frame_index == 0]
    to_lidar = invert_pose(np.array(f0.lidar_pose, dtype=np.float64).reshape(4, 4))
    centres = np.asarray(grid.origin) + (np.argwhere(differ) + 0.5) * VOXEL_SIZE
    inside = np.zeros(len(centres), dtype=bool)
    for k in swapped:
        for pl in (old_pl[k], new_pl[k]):
            lo, hi = np.array(pl.aabb_min), np.array(pl.aabb_max)
            corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
            c = transform_points(to_lidar, corners)
            inside |= np.all((centres >= c.min(axis=0) - VOXEL_SIZE) & (centres <= c.max(axis=0) + VOXEL_SIZE), axis=1)
    assert inside.all(), f"{int((~inside).sum())} voxels changed outside the swapped buildings"


def test_skeletons_lie_on_their_walkers(built):
    """The ``skeletons`` table (SQL): 11 named joints per pedestrian and frame, world and LiDAR
    frames consistent with the frame's LiDAR pose, and every joint within one voxel of that
    walker's voxels."""
    from carlaocc.stages.geometry import pose_from_list, transform_points

    seq = query(built, "SELECT min(sequence_id) FROM sequences")[1][0][0]
    cols, rows = query(built, "SELECT frame_index, instance_id, joint, world, lidar FROM skeletons "
                              f"WHERE sequence_id = '{seq}' ORDER BY frame_index, instance_id, joint_index")
    assert rows, "no skeletons"
    _, peds = query(built, f"SELECT count(*) FROM actors WHERE sequence_id = '{seq}' AND semantic_id = "
                           f"{taxonomy.by_name('Pedestrian').id}")
    assert len(rows) == 11 * peds[0][0]
    from carlaocc.stages.scenes.people.pedestrians import JOINT_NAMES

    assert [r[2] for r in rows[:11]] == list(JOINT_NAMES)
    grid = GridSpec(voxel_size=VOXEL_SIZE)
    _, frames = query(built, f"SELECT frame_index, lidar_pose FROM frames WHERE sequence_id = '{seq}'")
    lidar_pose = {f: pose_from_list(p) for f, p in frames}
    checked = 0
    for t in sorted({r[0] for r in rows})[:3]:
        occ = OccupancyStore(built).read_frame(seq, grid, t, ("instance",))["instance"]
        for inst in sorted({r[1] for r in rows if r[0] == t}):
            joints = [r for r in rows if r[0] == t and r[1] == inst]
            world = np.array([r[3] for r in joints])
            lidar = np.array([r[4] for r in joints])
            np.testing.assert_allclose(transform_points(lidar_pose[t], lidar), world, atol=1e-6)
            vox = np.argwhere(occ == inst)
            if len(vox) == 0:
                continue  # the walker is outside the grid this frame
            ijk = np.floor((lidar - np.asarray(grid.origin)) / VOXEL_SIZE).astype(int)
            # Chebyshev distance (voxels) from each joint's voxel to the nearest voxel of the walker
            d = np.abs(ijk[:, None, :] - vox[None, :, :]).max(axis=2).min(axis=1)
            assert (d <= 1).all(), (t, inst, [j[2] for j, dd in zip(joints, d) if dd > 1])
            checked += 1
    assert checked > 0


def _frame(built, names=("semantic", "instance", "mask_camera", "mask_lidar", "flow"), t=3):
    grid = GridSpec(voxel_size=VOXEL_SIZE)
    seq = query(built, "SELECT min(sequence_id) FROM sequences")[1][0][0]
    return seq, grid, OccupancyStore(built).read_frame(seq, grid, t, names)


def test_visibility_masks(built):
    seq, grid, d = _frame(built)
    sem, cam, lid = d["semantic"], d["mask_camera"], d["mask_lidar"]
    assert cam.dtype == lid.dtype == np.uint8 and set(np.unique(cam)) <= {0, 1} and set(np.unique(lid)) <= {0, 1}
    # the air around the rig is observed by both; the inside of buildings (filled) by neither
    li, lj, lk = (int((0.0 - o) / VOXEL_SIZE) for o in grid.origin)
    assert lid[li, lj, lk] and cam[li + 3, lj, lk]
    building = sem == taxonomy.by_name("Building").id
    from scipy import ndimage

    deep = ndimage.binary_erosion(building, iterations=2)
    assert deep.any() and not (cam[deep].any() or lid[deep].any())
    # observed occupied voxels exist (the first voxel a ray hits is observed) and the LiDAR
    # (12.5k beams) observes less than the cameras
    assert (cam.astype(bool) & (sem > 0)).any() and (lid.astype(bool) & (sem > 0)).any()
    assert lid.sum() < cam.sum()


def test_flow_of_dynamic_instances(built):
    seq, grid, d = _frame(built)
    sem, inst, flow = d["semantic"], d["instance"], d["flow"]
    assert flow.dtype == np.float16 and flow.shape == (*grid.shape, 3)
    speed = np.linalg.norm(flow.astype(np.float32), axis=-1)
    # static voxels (stuff, buildings, parked cars...) have no flow; some car voxels move
    dynamic = np.isin(sem, taxonomy.dynamic_ids())
    assert not speed[~dynamic].any()
    car = sem == taxonomy.by_name("Car").id
    assert (speed[car] > 0.5).any()
    # a rigid car's voxels share one horizontal velocity up to its yaw rate (|w| r << v)
    moving = np.unique(inst[car & (speed > 0.5)])
    i = moving[0]
    v = flow[inst == i].astype(np.float32)
    assert np.ptp(v[:, 2]) < 0.05 and np.linalg.norm(v[:, :2].std(axis=0)) < 0.5


@pytest.mark.parametrize("fmt", ["occ3d", "semantickitti", "surroundocc", "carlaocc-npz"])
def test_export_formats_read_back(built, tmp_path, fmt):
    from carlaocc.catalog import formats

    seq = query(built, "SELECT min(sequence_id) FROM sequences")[1][0][0]
    out = tmp_path / fmt
    r = cli.invoke(app, ["export", fmt, "--res", str(VOXEL_SIZE), "--root", built.url, "--out", str(out),
                         "--sequence", seq])
    assert r.exit_code == 0, r.output
    frames = E2E.scenes.frame_count
    car = taxonomy.by_name("Car")
    if fmt == "occ3d":
        f = formats.load_occ3d(out / "gts" / seq / f"{seq}_000003" / "labels.npz")
        assert f.semantics.shape == (200, 200, 16) and (f.semantics == 17).mean() > 0.5
        assert (f.semantics == car.occ3d_nuscenes).any() and f.mask_camera.any() and f.mask_lidar.any()
    elif fmt == "semantickitti":
        v = formats.load_semantickitti(out / "sequences" / seq / "voxels", "000003")
        assert v.labels.shape == (256, 256, 32) and (v.labels == 40).any()  # raw 40 = road
        assert v.occupied.any() and v.occluded.any() and not (v.invalid & ~v.occluded).any()
    elif fmt == "surroundocc":
        rows = formats.load_surroundocc(out / seq / "000003.npy")
        assert rows.shape[1] == 4 and len(rows) > 1000 and rows[:, 3].max() <= 16
    else:
        f = formats.load_carlaocc_npz(out / seq / "000003.npz")
        _, grid, d = _frame(built, ("semantic", "instance"))
        np.testing.assert_array_equal(f.semantic, d["semantic"])
        assert f.voxel_size == VOXEL_SIZE and (f.instance > 0).sum() == (d["instance"] > 0).sum()
        note = json.loads((out / seq / "instances.json").read_text())
        table = {tuple(int(v) for v in k.split(":")): v for k, v in note["instances"].items()}
        actors = {r[0] for r in query(built, f"SELECT DISTINCT instance_id FROM actors WHERE sequence_id = '{seq}'")[1]}
        # per class: placed objects 1..999, the simulated actors 1000 + id % 1000 (the release's code)
        for c in {c for c, _ in table}:
            new = [v for (k, i), v in table.items() if k == c]
            assert len(set(new)) == len(new) and 0 not in new
        assert any(i in actors for _, i in table)
        for (c, i), v in table.items():
            assert (1000 <= v <= 2047) if i in actors else (1 <= v <= 999)
        # the same instance keeps its exported id in every frame
        f0 = formats.load_carlaocc_npz(out / seq / "000000.npz")
        d0 = OccupancyStore(built).read_frame(seq, grid, 0, ("semantic", "instance"))
        for (c, k), v in table.items():
            here = (d0["instance"] == k) & (d0["semantic"] == c)
            if here.any():
                assert (f0.instance[here] == v).all()
    assert len(list(out.rglob("*"))) >= frames


def test_show_occupancy_png(built, tmp_path):
    seq = query(built, "SELECT min(sequence_id) FROM sequences")[1][0][0]
    out = tmp_path / "occ.png"
    r = cli.invoke(app, ["show", "occupancy", "--seq", seq, "--frame", "2", "--res", str(VOXEL_SIZE),
                         "--root", built.url, "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    r = cli.invoke(app, ["show", "occupancy", "--seq", seq, "--frame", "99", "--res", str(VOXEL_SIZE),
                         "--root", built.url, "--out", str(out)])
    assert r.exit_code == 2 and "frames 0.." in r.output


def test_export_refuses_a_voxel_size_not_built(built, tmp_path):
    r = cli.invoke(app, ["export", "occ3d", "--res", "0.8", "--root", built.url, "--out", str(tmp_path / "x")])
    assert r.exit_code == 2 and "0.8" in r.output


def test_second_voxel_size_pooling_report_and_multi_voxel_size_figure(config_file, built, tmp_path):
    import shutil

    root = tmp_path / "data"
    shutil.copytree(built.root, root)
    r = cli.invoke(app, ["run", "--config", config_file, "--stages", "voxelize", "--voxel-size", "0.8", "--root", str(root), "--scheduler", "synchronous"])
    assert r.exit_code == 0, r.output
    seq = query(built, "SELECT min(sequence_id) FROM sequences")[1][0][0]
    out = tmp_path / "pool.json"
    r = cli.invoke(app, ["compare-voxel-sizes", "--fine", str(VOXEL_SIZE), "--coarse", "0.8", "--root", str(root),
                         "--sequence", seq, "--json", str(out)])
    assert r.exit_code == 0, r.output
    rows = json.loads(out.read_text())
    assert len(rows) == E2E.scenes.frame_count
    # closed-box overlap nests: a triangle meets a 0.8 m box iff it meets one of its eight 0.4 m
    # boxes, so pooled occupancy equals the direct one (fills, decided at voxel centres, could
    # differ); labels differ where class priority and elevation order disagree (measured ~4 %)
    assert all(r["occupancy_iou"] > 0.99 and 0 < r["mismatch_rate"] < 0.15 for r in rows)
    png = tmp_path / "multi.png"
    r = cli.invoke(app, ["show", "occupancy", "--seq", seq, "--frame", "0", "--res", f"{VOXEL_SIZE},0.8",
                         "--root", str(root), "--out", str(png)])
    assert r.exit_code == 0, r.output and png.stat().st_size > 1000


# -- sensors ----------------------------------------------------------------------------------------
def test_sensor_maps_lidar_and_rectification_records(built):
    from carlaocc.catalog.sensors import SensorStore, LidarStore

    seq = query(built, "SELECT min(sequence_id) FROM sequences")[1][0][0]
    frames = E2E.scenes.frame_count
    sensors = SensorStore(built)
    rig = E2E.scenes.rig
    assert sensors.cameras(seq) == sorted(c.name for c in rig.cameras)
    for cam in rig.cameras:
        assert sensors.names(seq, cam.name) == sorted(["depth", "semantic", "instance", "normal", "depth_raw",
                                                       "semantic_raw", "instance_raw", "rgb"])
        arr = sensors.open(seq, cam.name, "depth")
        assert arr.shape == (frames, 376, 1408) and arr.chunks == (1, 376, 1408)
        assert dict(arr.attrs)["intrinsics"][0][0] == pytest.approx(cam.focal_px)
    depth = sensors.read_image(seq, "camera_00", 5, "depth")
    sem = sensors.read_image(seq, "camera_00", 5, "semantic")
    inst = sensors.read_image(seq, "camera_00", 5, "instance")
    normal = sensors.read_image(seq, "camera_00", 5, "normal")
    # the front camera sees the road ahead and sky above; the flat road's planar depth at image
    # row v is camera height x focal / (v + 0.5 - cy), 1.55 m above the ground
    assert (sem == taxonomy.by_name("Road").id).mean() > 0.05 and (sem == 11).mean() > 0.05
    assert ((depth == 0) == (sem == 11)).all()
    road = sem == taxonomy.by_name("Road").id
    f = rig.cameras[0].focal_px
    for v in (375, 330, 290):
        assert road[v].sum() > 50
        assert np.median(depth[v][road[v]]) == pytest.approx(1.55 * f / (v + 0.5 - 188), rel=0.02)
    things = np.isin(sem, taxonomy.thing_ids())
    assert (inst[~things] == 0).all() and (inst[things] > 0).mean() > 0.99
    # RGB for every camera and frame: sky blue above, the road an asphalt grey, colours elsewhere
    rgb = sensors.read_image(seq, "camera_00", 5, "rgb")
    assert rgb.shape == (376, 1408, 3) and rgb.dtype == np.uint8
    sky = rgb[sem == 11].astype(int)
    assert (sky[:, 2] > sky[:, 0]).all() and (sky[:, 2] - sky[:, 0]).max() > 40  # bluer towards the zenith
    asphalt = rgb[road].astype(int)
    assert np.median(np.ptp(asphalt, axis=1)) < 12 and 20 < np.median(asphalt) < 90
    assert all(sensors.exists(seq, c.name, "rgb", t) for c in rig.cameras for t in range(frames))
    # normals are unit vectors; the flat road's is "up", -y in the OpenCV camera frame
    n = normal.astype(np.float32)
    ok = np.abs(np.linalg.norm(n[depth > 0], axis=-1) - 1) < 1e-2
    assert ok.mean() > 0.9
    near_road = n[290:][road[290:]]
    assert (near_road[:, 1] < -0.99).mean() > 0.95
    # rectification: artifacts present in the raw maps, gone after (glass within 5 cm of what is
    # behind it is the only case the paper's rule leaves)
    _, rows = query(built, "SELECT sum(pixels), sum(transparency), sum(omission), sum(raw_semantic_wrong), "
                           "sum(semantic_mismatch), sum(depth_mismatch), count(*) FROM rectification")
    pixels, transp, omis, raw_wrong, mismatch, depth_mis, n_rows = (int(x) for x in rows[0])
    assert n_rows == frames * 6 * 3 and transp > 0 and omis > 0 and raw_wrong > 0.01 * pixels
    assert mismatch < 1e-4 * pixels and depth_mis == 0
    # LiDAR: one Parquet per frame, points within range, the road below the sensor
    lidar = LidarStore(built)
    assert lidar.frames(seq) == list(range(frames))
    pts = lidar.load(seq, 5)
    assert len(pts["x"]) > 5000 and pts["distance"].max() <= 80.0 + 1e-3
    on_road = pts["semantic"] == taxonomy.by_name("Road").id
    assert on_road.any() and np.all(pts["z"][on_road] < -1.0)
    assert lidar.metadata(seq, 5)["lidar_to_world"]


def test_recorded_path_rectifies_stored_raw_maps_like_the_raycast_path(built, tmp_path):
    """A recorder's raw maps (here: the raw maps the raycast path stored) rectified by the
    recorded path give the same bytes; the raw arrays are never touched; a missing raw map is an
    error naming it."""
    import shutil

    from carlaocc.catalog.sensors import SensorStore
    from carlaocc.catalog.store import StoreError
    from carlaocc.pipeline.engine.spec import Partition
    from carlaocc.pipeline.tasks.sensors import sensors_config, sensors_task

    copy = Store(str(tmp_path / "copy"))
    shutil.copytree(built.root, copy.root)
    seq = query(copy, "SELECT min(sequence_id) FROM sequences")[1][0][0]
    cfg = sensors_config(E2E).model_copy(update={"source": "recorded"})
    sensors = SensorStore(copy)
    raw_before = {c: sensors.fingerprints(seq, c, 4, ("depth_raw", "semantic_raw", "instance_raw"))
                  for c in sensors.cameras(seq)}
    for name in ("depth", "semantic", "instance", "normal"):
        sensors.write_image(seq, "camera_03", 4, name, np.zeros_like(sensors.read_image(seq, "camera_03", 4, name)))
    out = sensors_task(copy, cfg, Partition("x", {"sequence_id": seq, "frame_index": 4}))
    assert not any(k.endswith("_raw[4]") for k in out)
    for cam in sensors.cameras(seq):
        for name in ("depth", "semantic", "instance", "normal"):
            a = sensors.read_image(seq, cam, 4, name)
            b = SensorStore(built).read_image(seq, cam, 4, name)
            assert a.tobytes() == b.tobytes(), (cam, name)
        assert sensors.fingerprints(seq, cam, 4, ("depth_raw", "semantic_raw", "instance_raw")) == raw_before[cam]
    _, rows = query(copy, f"SELECT source, sum(transparency) FROM rectification WHERE sequence_id = '{seq}' "
                          f"AND frame_index = 4 GROUP BY source")
    assert rows[0][0] == "recorded" and rows[0][1] > 0
    last = F - 1
    shutil.rmtree(f"{copy.root}/sensors.zarr/{seq}/camera_02/depth_raw/c/{last}")
    with pytest.raises(StoreError, match=f"camera_02/depth_raw has no frame {last}"):
        sensors_task(copy, cfg, Partition("x", {"sequence_id": seq, "frame_index": last}))


def test_show_sensors_png(built, tmp_path):
    seq = query(built, "SELECT min(sequence_id) FROM sequences")[1][0][0]
    out = tmp_path / "sensors.png"
    r = cli.invoke(app, ["show", "sensors", "--seq", seq, "--frame", "3", "--root", built.url, "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # a column per camera (704 px at --step 2) and its key; nine rows of 188 px (rgb, the four
    # maps, the four rectification maps), each with its titles
    w, h = (int(v) for v in r.output.split("(")[1].split(")")[0].split("x"))
    assert 6 * 704 < w < 6 * 704 + 1000 and 9 * 188 < h < 9 * (188 + 60), r.output
    r = cli.invoke(app, ["show", "sensors", "--seq", seq, "--frame", "3", "--camera", "camera_09",
                         "--root", built.url, "--out", str(out)])
    assert r.exit_code == 2 and "camera_09" in r.output


def test_show_sensors_draws_skeletons_where_walkers_are_seen(built, tmp_path):
    """``show sensors --skeletons``: in some frame a walker is seen by a camera, and the sheet
    then differs from the one without skeletons only by skeleton colours (white/grey)."""
    from PIL import Image

    seq = query(built, "SELECT min(sequence_id) FROM sequences")[1][0][0]
    ped = taxonomy.by_name("Pedestrian").id
    for t in range(0, 20, 2):
        a, b = tmp_path / f"plain{t}.png", tmp_path / f"skel{t}.png"
        args = ["show", "sensors", "--seq", seq, "--frame", str(t), "--root", built.url, "--step", "1"]
        assert cli.invoke(app, [*args, "--out", str(a)]).exit_code == 0
        r = cli.invoke(app, [*args, "--skeletons", "--out", str(b)])
        assert r.exit_code == 0, r.output
        A, B = np.asarray(Image.open(a).convert("RGB")), np.asarray(Image.open(b).convert("RGB"))
        # the panels (six 1408 px columns with 10 px gaps, from x = 10): the keys at the right add
        # the skeletons' entries
        A, B = A[:, : 10 + 6 * 1418], B[:, : 10 + 6 * 1418]
        changed = np.any(A != B, axis=2)
        if changed.any():
            colours = {tuple(c) for c in B[changed]}
            assert colours <= {(255, 255, 255), (140, 140, 140)}, colours
            return
    pytest.fail(f"no frame of {seq} shows a walker ({ped}) to a camera")
