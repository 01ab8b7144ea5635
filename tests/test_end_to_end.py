"""End to end on the embedded default at a coarse resolution: ingest -> scenes -> voxelize ->
metrics through the CLI, then the arrays, the catalog, re-runs and scheduler independence."""

from __future__ import annotations

import json

import numpy as np
import pytest
import zarr
from typer.testing import CliRunner

from catalog.occupancy import OccupancyStore
from catalog.sql import query
from catalog.store import Store
from pipeline.cli import app
from schemas import taxonomy
from schemas.configs import DatasetConfig
from schemas.grid import GridSpec

RES = 0.4
cli = CliRunner()


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    root = tmp_path_factory.mktemp("e2e") / "data"
    r = cli.invoke(app, ["run", "--res", str(RES), "--root", str(root), "--scheduler", "synchronous"])
    assert r.exit_code == 0, r.output
    return Store(str(root))


def _snapshot(store: Store) -> dict[str, tuple[int, bytes]]:
    """Every file's modification time (ns) and bytes."""
    import os

    return {p: (os.stat(p).st_mtime_ns, store.fs.cat_file(p)) for p in store.fs.find(store.root)}


def test_occupancy_arrays(built):
    grid = GridSpec(voxel_size=RES)
    seq = query(built, "SELECT min(sequence_id) FROM sequences")[1][0][0]
    occ = OccupancyStore(built)
    sem_arr = occ.open(seq, grid, "semantic")
    inst_arr = occ.open(seq, grid, "instance")
    frames = DatasetConfig().scenes.frame_count
    # region and attributes
    assert sem_arr.shape == inst_arr.shape == (frames, *grid.shape)
    assert sem_arr.dtype == np.uint8 and inst_arr.dtype == np.uint32
    attrs = dict(sem_arr.attrs)
    assert attrs["origin"] == [-25.6, -25.6, -3.0] and attrs["voxel_size"] == RES
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
    # instances are distinct objects: one class per id, several cars
    ids, first = np.unique(inst[things], return_index=True)
    cls_of = sem[things][first]
    for i in ids:
        assert np.unique(sem[things][inst[things] == i]).size == 1, f"instance {i} spans classes"
    car = taxonomy.by_name("Car").id
    assert (cls_of == car).sum() >= 3
    # the road lies under the LiDAR at about -1.73 m
    road = taxonomy.by_name("Road").id
    k = np.flatnonzero((sem == road).any(axis=(0, 1)))
    z_road = -3.0 + (k.mean() + 0.5) * RES
    assert -2.4 < z_road < -1.2


def test_instances_are_stable_across_frames(built):
    grid = GridSpec(voxel_size=RES)
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
    scenes = DatasetConfig().scenes
    n_seq = sum(len(t.traffic_levels) * t.sequences_per_level for t in scenes.towns)
    _, rows = query(built, "SELECT count(*) FROM frames")
    assert rows[0][0] == scenes.frame_count * n_seq
    _, rows = query(built, "SELECT value FROM quality WHERE frame_index IS NULL AND metric = 'spatial_continuity'")
    assert len(rows) == n_seq and all(0.9 < r[0] <= 1.0 for r in rows)
    _, rows = query(built, "SELECT DISTINCT stage FROM runs WHERE status = 'completed' ORDER BY 1")
    assert [r[0] for r in rows] == ["ingest", "metrics", "scenes", "voxelize"]
    _, rows = query(built, "SELECT count(*) FROM quality_classes q JOIN classes c ON q.semantic_id = c.id WHERE c.name = 'Car'")
    assert rows[0][0] > 0


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
    from catalog.panoptic import load_panoptic_glb

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


def test_rerun_with_nothing_changed_writes_nothing(built):
    before = _snapshot(built)
    r = cli.invoke(app, ["run", "--res", str(RES), "--root", built.url, "--scheduler", "synchronous"])
    assert r.exit_code == 0 and "nothing to do" in r.output
    assert _snapshot(built) == before
    r = cli.invoke(app, ["status", "--res", str(RES), "--root", built.url])
    assert r.exit_code == 0 and "stale" not in r.output


def test_local_cluster_output_is_byte_identical(built, tmp_path):
    """The same graph on a distributed LocalCluster writes the same bytes as the synchronous run."""
    root = tmp_path / "dist"
    r = cli.invoke(app, ["run", "--res", str(RES), "--root", str(root), "--workers", "2"])
    assert r.exit_code == 0, r.output
    a, b = _snapshot(built), _snapshot(Store(str(root)))
    strip = lambda snap, base: {k[len(base):]: v[1] for k, v in snap.items() if "/catalog/runs/" not in k}
    sa, sb = strip(a, built.root), strip(b, str(root))
    assert sa.keys() == sb.keys()
    assert [k for k in sa if sa[k] != sb[k]] == []


def test_tampered_frame_is_detected_and_rebuilt(built, tmp_path):
    """Deleting one chunk of one frame makes exactly that frame stale; a run rebuilds it."""
    import shutil

    copy = Store(str(tmp_path / "copy"))
    shutil.copytree(built.root, copy.root)
    grid = GridSpec(voxel_size=RES)
    seq = query(copy, "SELECT min(sequence_id) FROM sequences")[1][0][0]
    chunk_dir = f"{copy.root}/occupancy.zarr/{seq}/{grid.key}/semantic/c/3"
    victim = sorted(copy.fs.find(chunk_dir))[0]
    copy.fs.rm(victim)
    r = cli.invoke(app, ["status", "--res", str(RES), "--root", copy.url, "-v"])
    assert "voxelize  stale 1/" in r.output and f"{seq}/{grid.key}/0003: outputs missing or modified" in r.output
    r = cli.invoke(app, ["run", "--res", str(RES), "--root", copy.url, "--scheduler", "synchronous"])
    # the rebuilt frame is byte-identical, so what metrics read is unchanged: it stays up to date
    assert r.exit_code == 0 and "voxelize: ran 1," in r.output and "metrics: 3 up to date" in r.output
    np.testing.assert_array_equal(OccupancyStore(copy).read_frame(seq, grid, 3)["semantic"],
                                  OccupancyStore(built).read_frame(seq, grid, 3)["semantic"])


def test_swap_makes_a_sequence_that_voxelizes(built, tmp_path):
    """``scenes swap`` on a copy: the edited sequence keeps the trajectories (same instances in
    the same places) with other car models, and the pipeline voxelizes it."""
    import shutil

    copy = Store(str(tmp_path / "copy"))
    shutil.copytree(built.root, copy.root)
    seq = query(copy, "SELECT min(sequence_id) FROM sequences")[1][0][0]
    r = cli.invoke(app, ["scenes", "swap", "--class", "Car", "--seed", "5", "--sequence", seq, "--root", copy.url])
    assert r.exit_code == 0 and "Car instance(s) swapped" in r.output, r.output
    new = query(copy, f"SELECT sequence_id FROM sequences WHERE parent_sequence_id = '{seq}'")[1][0][0]
    r = cli.invoke(app, ["run", "--res", str(RES), "--root", copy.url, "--scheduler", "synchronous"])
    assert r.exit_code == 0, r.output
    grid = GridSpec(voxel_size=RES)
    a, b = OccupancyStore(copy).read_frame(seq, grid, 0), OccupancyStore(copy).read_frame(new, grid, 0)
    car = taxonomy.by_name("Car").id
    cars_a = set(np.unique(a["instance"][a["semantic"] == car]))
    cars_b = set(np.unique(b["instance"][b["semantic"] == car]))
    assert cars_a and cars_a == cars_b
    assert not np.array_equal(a["semantic"], b["semantic"])  # other models, other voxels
