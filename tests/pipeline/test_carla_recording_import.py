"""A CARLA recording in, occupancy out: tools/make_carla_recording.py writes a recording in the
release layout, `carlaocc ingest carla-recording` takes its models and writes the dataset's
config, `carlaocc run` builds it. Checked against the recording's own files: every vehicle's
voxels inside its recorded box in the LiDAR frame (left stays left), distinct instances, leg-bone
origins on the walker's voxels, the walk-cycle phase matched, odd items quarantined."""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from carlaocc.catalog import carla_recording as cr
from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.sql import query
from carlaocc.catalog.store import Store
from carlaocc.pipeline.cli import app
from carlaocc.schemas.configs import DatasetConfig
from carlaocc.stages.geometry import invert_pose, pose_from_list, transform_points

ROOT = Path(__file__).resolve().parents[2]
TOOL = ROOT / "tools" / "make_carla_recording.py"
SEQ = "Town99_Opt_Seq00"
VOXEL_SIZE = 0.1
cli = CliRunner()


def _tool():
    spec = importlib.util.spec_from_file_location("make_carla_recording", TOOL)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("carla") / "rec"
    subprocess.run([sys.executable, str(TOOL), str(out)], check=True, capture_output=True)
    return out


def _ingest_and_run(recording: Path, root: Path, stages: str | None = None) -> Store:
    r = cli.invoke(app, ["ingest", "carla-recording", str(recording), "--root", str(root), "--scheduler", "synchronous"])
    assert r.exit_code == 0, r.output
    assert "wrote" in r.output and (root / "dataset.yaml").is_file()
    # no --config: the root's own dataset.yaml is the config; every stage by default
    r = cli.invoke(app, ["run", "--root", str(root), "--res", str(VOXEL_SIZE), "--scheduler", "synchronous"]
                   + (["--stages", stages] if stages else []))  # fmt: skip
    assert r.exit_code == 0, r.output
    return Store(str(root))


@pytest.fixture(scope="module")
def built(recording, tmp_path_factory):
    root = tmp_path_factory.mktemp("rec_root") / "data"
    return _ingest_and_run(recording, root)


def _frame(store: Store, seq: str, f: int):
    cfg = DatasetConfig.model_validate(yaml.safe_load((Path(store.root) / "dataset.yaml").read_text()))
    grid = cfg.voxelize.grid(VOXEL_SIZE)
    arrays = OccupancyStore(store).read_frame(seq, grid, f, ("semantic", "instance"))
    return grid, arrays["semantic"], arrays["instance"]


def _centres(grid, ijk: np.ndarray) -> np.ndarray:
    return np.asarray(grid.origin) + (ijk + 0.5) * grid.voxel_size


def test_every_stage_runs_on_the_recording(built):
    seq = f"town00_{SEQ}"
    grid, _, _ = _frame(built, seq, 0)
    _, metrics = query(built, f"SELECT DISTINCT metric FROM quality WHERE sequence_id = '{seq}' ORDER BY 1")
    assert {m for (m,) in metrics} >= {"spatial_continuity", "temporal_consistency"}
    flow = OccupancyStore(built).read_frame(seq, grid, 3, ("flow", "mask_camera", "mask_lidar"))
    # the cars move at 6 and 7 m/s: occupancy flow; the masks from the recording's rig
    assert np.abs(flow["flow"]).max() > 1.0 and flow["mask_camera"].any() and flow["mask_lidar"].any()


def test_the_recording_becomes_a_town_and_a_sequence(built):
    _, towns = query(built, "SELECT style, source, placement_count FROM towns")
    assert towns[0][0] == "carla-recording" and towns[0][2] == 15
    _, seqs = query(built, "SELECT sequence_id, frame_count, traffic_level, rate_hz FROM sequences")
    assert seqs == [(f"town00_{SEQ}", 6, "none", 10.0)]
    _, ids = query(built, "SELECT DISTINCT instance_id, semantic_id FROM actors ORDER BY 1")
    assert [s for _, s in ids] == [14, 14, 12] and len({i for i, _ in ids}) == 3  # two cars, one walker


def test_vehicle_voxels_lie_in_their_recorded_boxes(built, recording):
    seq = f"town00_{SEQ}"
    poses, _ = cr.read_poses(recording / SEQ / "poses" / "lidar.txt")
    _, rows = query(built, f"SELECT frame_index, instance_id, box_center FROM actors WHERE sequence_id = '{seq}' "
                           "AND semantic_id = 14")  # fmt: skip
    for f in (0, 3, 5):
        grid, _, instance = _frame(built, seq, f)
        lidar = poses[f]
        traffic = cr.read_traffic(recording / SEQ / "traffic_info" / f"{f:04d}.yaml")
        seen = set()
        for v in traffic.vehicles:
            # our instance of this vehicle: the one whose box centre is the recorded box's
            box = v.transform @ v.bbox_transform
            (inst,) = [i for fr, i, c in rows if fr == f and np.allclose(c, box[:3, 3], atol=1e-6)]
            seen.add(inst)
            ijk = np.argwhere(instance == inst)
            assert len(ijk) > 500
            world = transform_points(lidar, _centres(grid, ijk))
            local = transform_points(invert_pose(box), world)
            # every voxel centre within the recorded box, give or take half a voxel diagonal
            assert (np.abs(local) <= v.extent + VOXEL_SIZE * 0.87).all()
            # left stays left: car 246 drives on the ego's left, car 245 ahead in its lane
            centre = _centres(grid, ijk).mean(axis=0)
            assert (centre[1] > 2.5) if v.id == 246 else (abs(centre[1]) < 1.0 and centre[0] > 0)
        assert len(seen) == 2


def test_knees_on_the_walkers_voxels_and_phase_matched(built, recording):
    seq = f"town00_{SEQ}"
    tool = _tool()
    poses, _ = cr.read_poses(recording / SEQ / "poses" / "lidar.txt")
    _, rows = query(built, f"SELECT frame_index, instance_id, gait_phase FROM actors WHERE sequence_id = '{seq}' "
                           "AND semantic_id = 12 ORDER BY frame_index")  # fmt: skip
    errors = []
    for f, inst, phase in rows:
        grid, _, instance = _frame(built, seq, f)
        (ped,) = cr.read_traffic(recording / SEQ / "traffic_info" / f"{f:04d}.yaml").pedestrians
        # the recorded lower-leg bones' origins (the knees), actor frame -> world -> LiDAR
        knees = transform_points(ped.transform, np.array([b[:3, 3] for b in ped.bones.values()]))
        knees_lidar = transform_points(invert_pose(poses[f]), knees)
        vox = _centres(grid, np.argwhere(instance == inst))
        gap = np.linalg.norm(vox[None] - knees_lidar[:, None], axis=2).min(axis=1)
        assert (gap <= VOXEL_SIZE).all(), f"frame {f}: a knee is {gap.max():.3f} m from the walker's voxels"
        true = tool.walker_phase(f / 10.0)
        errors.append(abs((phase - true + 0.5) % 1.0 - 0.5))
    # the matched walk-cycle frame (the cycle's bones are in the mesh axes and centimetres, the
    # recording's in the actor frame and metres) is the true phase to within one frame of the 36
    assert max(errors) <= 1.0 / 36 + 1e-9, errors


def test_skeletons_are_the_recorded_knees(built, recording):
    _, rows = query(built, "SELECT joint, world FROM skeletons WHERE frame_index = 0 ORDER BY joint")
    assert [j for j, _ in rows] == ["crl_leg__L", "crl_leg__R"]
    (ped,) = cr.read_traffic(recording / SEQ / "traffic_info" / "0000.yaml").pedestrians
    want = transform_points(ped.transform, np.array([ped.bones[b][:3, 3] for b in ("crl_leg__L", "crl_leg__R")]))
    assert np.allclose([w for _, w in rows], want)
    # the walker heads +x: its left knee on +y, about knee height above the sidewalk
    (lw, rw) = (np.asarray(w) for _, w in rows)
    assert lw[1] > rw[1] and 0.15 + 0.3 < lw[2] < 0.15 + 0.6


def test_rotations_are_the_recorded_ones(built, recording):
    from carlaocc.stages.geometry import yaw_pitch_roll

    seq = f"town00_{SEQ}"
    _, rows = query(built, f"SELECT frame_index, box_center, yaw, pitch, roll FROM actors WHERE sequence_id = '{seq}'")
    poses, _ = cr.read_poses(recording / SEQ / "poses" / "lidar.txt")
    _, frames = query(built, f"SELECT frame_index, lidar_pose FROM frames WHERE sequence_id = '{seq}'")
    for f, lidar in frames:
        assert np.allclose(np.asarray(lidar).reshape(4, 4), poses[f], atol=1e-6)
    for f, centre, yaw, pitch, roll in rows:
        tf = cr.read_traffic(recording / SEQ / "traffic_info" / f"{f:04d}.yaml")
        actors = [(v.transform @ v.bbox_transform, v.transform) for v in tf.vehicles] + [
            (p.transform, p.transform) for p in tf.pedestrians]
        box, T = next((b, T) for b, T in actors if np.allclose(b[:3, 3], centre, atol=1e-6))
        assert np.allclose((yaw, pitch, roll), yaw_pitch_roll(T), atol=1e-9)
    assert {round(y, 2) for _, _, y, _, _ in rows} >= {0.05, round(np.pi - 0.08, 2), 0.03}


def test_the_ego_keeps_its_recorded_velocity(built, recording):
    """Issue 38: the ego's velocity and acceleration as traffic_info records them (world frame),
    one row per frame, agreeing with the ego's own poses (central differences of its origin)."""
    seq = f"town00_{SEQ}"
    _, rows = query(built, f"SELECT frame_index, velocity, acceleration FROM ego_states WHERE sequence_id = '{seq}' "
                           f"ORDER BY frame_index")
    _, frames = query(built, f"SELECT frame_index, timestamp, ego_pose FROM frames WHERE sequence_id = '{seq}' "
                             f"ORDER BY frame_index")
    assert [r[0] for r in rows] == [f[0] for f in frames] and len(rows) >= 3
    for f, vel, acc in rows:
        tf = cr.read_traffic(recording / SEQ / "traffic_info" / f"{f:04d}.yaml")
        np.testing.assert_allclose(vel, tf.ego.velocity, atol=1e-12)
        np.testing.assert_allclose(acc, tf.ego.acceleration, atol=1e-12)
    # the recorded velocity is the motion of the ego origin our poses hold
    t = np.array([ts for _, ts, _ in frames])
    pos = np.array([np.asarray(e).reshape(4, 4)[:3, 3] for _, _, e in frames])
    np.testing.assert_allclose(np.gradient(pos, t, axis=0), np.array([v for _, v, _ in rows]), atol=1e-4)
    # a simulated sequence has no recorded ego motion: no rows, not zeros
    _, other = query(built, f"SELECT count(*) FROM ego_states WHERE sequence_id <> '{seq}'")
    assert other[0][0] == 0


def test_recorded_lidar_is_kept_and_agrees_with_our_scene(built, recording):
    """Issue 38: both recorded scans of every frame in lidar_recorded/ (the PLYs' points, our
    axes), our range along each recorded beam beside them, and the agreement in
    metrics/lidar_agreement: the static scene's ranges agree (the fixture's scans were cast
    through the same meshes: what is measured is the chain of poses, frames and axes)."""
    from carlaocc.catalog.sensors import RecordedLidarStore

    seq = f"town00_{SEQ}"
    lidar = RecordedLidarStore(built)
    assert lidar.frames(seq) == list(range(6))
    for f in (0, 5):
        pts = lidar.load(seq, f)
        plain, sem = (cr.read_ply(recording / SEQ / d / f"{f:04d}.ply") for d in ("lidar", "semantic_lidar"))
        assert (pts["scan"] == 0).sum() == len(plain["x"]) and (pts["scan"] == 1).sum() == len(sem["x"])
        np.testing.assert_allclose(pts["y"][pts["scan"] == 1], sem["y"], atol=1e-6)
        assert lidar.metadata(seq, f)["recorded_frame"] == f
        # the building's returns: on the left, and our ray along those beams hits it at the same range
        building = (pts["semantic"] == 3)
        assert building.sum() > 20 and (pts["y"][building] > 0).all()
        np.testing.assert_allclose(pts["raycast_distance"][building], pts["distance"][building], atol=1e-3)
    _, rows = query(built, f"SELECT frame_index, points, static_points, missed, median_m, p95_m, within "
                           f"FROM lidar_agreement WHERE sequence_id = '{seq}' ORDER BY 1")  # fmt: skip
    assert [r[0] for r in rows] == list(range(6))
    for _, n, static, missed, median, p95, within in rows:
        assert static > 0.95 * n and missed == 0 and median < 1e-3 and p95 < 1e-3 and within == 1.0


@pytest.mark.slow  # 26 s (the export pools every grid); tests/pipeline/test_release_export.py covers it fast
def test_the_recorded_scan_goes_back_out_in_the_release_layout(built, recording, tmp_path):
    """The release export writes a recorded frame's own LiDAR scan (CARLA's ray_cast: points and
    intensities as recorded) as lidar/<frame>.ply, and the release loader reads it back."""
    from carlaocc.data import CarlaOccDataset

    out = tmp_path / "CarlaOcc"
    r = cli.invoke(app, ["export", "carlaocc-release", "--root", built.url, "--out", str(out)])
    assert r.exit_code == 0, r.output
    (folder,) = [p for p in out.iterdir() if p.is_dir() and "_Seq" in p.name]
    for f in (0, 4):
        mine, theirs = cr.read_ply(folder / "lidar" / f"{f:04d}.ply"), cr.read_ply(recording / SEQ / "lidar" / f"{f:04d}.ply")
        assert list(mine) == list(theirs) == ["x", "y", "z", "I"]
        for c in theirs:
            np.testing.assert_allclose(mine[c], theirs[c], atol=1e-4, err_msg=c)
    sample = CarlaOccDataset(str(out), cameras=False)[4]
    np.testing.assert_allclose(sample["points"][:, :3], np.column_stack([theirs["x"], theirs["y"], theirs["z"]]),
                               atol=1e-4)


def test_ego_motion_absent_or_malformed(recording, tmp_path):
    path = recording / SEQ / "traffic_info" / "0000.yaml"
    doc = yaml.safe_load(path.read_text())
    del doc["ego_vehicles"]["velocity"]
    (tmp_path / "a.yaml").write_text(yaml.safe_dump(doc))
    assert cr.read_traffic(tmp_path / "a.yaml").ego.velocity is None  # absent: none kept, never 0
    doc["ego_vehicles"]["acceleration"] = [1.0, "x"]
    (tmp_path / "b.yaml").write_text(yaml.safe_dump(doc))
    with pytest.raises(cr.RecordingError, match=r"b\.yaml: ego_vehicles\.acceleration"):
        cr.read_traffic(tmp_path / "b.yaml")


def test_show_skeletons_draws_the_recorded_knees(built, tmp_path):
    out = tmp_path / "sk.png"
    r = cli.invoke(app, ["show", "sensors", "--root", built.root, "--seq", f"town00_{SEQ}", "--frame", "2",
                         "--skeletons", "--out", str(out)])  # fmt: skip
    assert r.exit_code == 0, r.output


def test_odd_recordings_are_quarantined_not_fatal(recording, tmp_path):
    odd = tmp_path / "rec"
    shutil.copytree(recording, odd)
    seq = odd / SEQ
    (odd / "SceneMeshes" / "Town99_Opt" / "bg_actors" / "BP_StreetLight_1.obj").unlink()  # a missing mesh
    lines = (seq / "poses" / "lidar.txt").read_text().splitlines()
    (seq / "poses" / "lidar.txt").write_text("\n".join(lines[:5]) + "\n")  # shorter than the frames
    t = (seq / "traffic_info" / "0001.yaml").read_text().replace("- 4.6", "- .nan", 1)  # a NaN transform
    (seq / "traffic_info" / "0001.yaml").write_text(t)
    (odd / "SceneMeshes" / "fg_actors" / "Car" / "vehicle_mini_cooper.obj").unlink()  # a model missing
    store = _ingest_and_run(odd, tmp_path / "data", stages="ingest,scenes")
    _, seqs = query(store, "SELECT frame_count FROM sequences")
    assert seqs == [(5,)]
    _, q = query(store, "SELECT source_path, reason FROM quarantine WHERE stage = 'scenes' ORDER BY 1")
    text = " ".join(f"{a} {b}" for a, b in q)
    assert "BP_StreetLight_1.obj" in text and "non-finite" in text and "vehicle.mini.cooper" in text
    _, actors = query(store, "SELECT count(*) FROM actors WHERE frame_index = 1 AND semantic_id = 14")
    assert actors == [(0,)]  # car 245 (NaN) and car 246 (no model) left out of frame 1


def test_a_missing_recording_is_a_clear_error(tmp_path):
    r = cli.invoke(app, ["ingest", "carla-recording", str(tmp_path / "nope"), "--root", str(tmp_path / "d"),
                         "--scheduler", "synchronous"])  # fmt: skip
    assert r.exit_code != 0 and "nope" in r.output


def test_recorded_camera_maps_are_stored_and_rectified(built, recording):
    from PIL import Image

    from carlaocc.catalog.sensors import SensorStore

    seq = f"town00_{SEQ}"
    sensors = SensorStore(built)
    assert sensors.cameras(seq) == [f"camera_0{i}" for i in range(6)]
    # the recorded RGB and raw maps as the PNGs hold them (saturated depth: no surface)
    png = np.asarray(Image.open(recording / SEQ / "rgb" / "image_03" / "0004.png").convert("RGB"))
    assert np.array_equal(sensors.read_image(seq, "camera_03", 4, "rgb"), png)
    depth = cr.decode_depth(np.asarray(Image.open(recording / SEQ / "depth_carla" / "image_03" / "0004.png")))
    assert np.array_equal(sensors.read_image(seq, "camera_03", 4, "depth_raw"), np.where(depth >= 80, 0, depth))
    # CARLA left the terrain unlabelled; the rectification labels it from the recorded meshes
    raw = sensors.read_image(seq, "camera_03", 4, "semantic_raw")
    rect = sensors.read_image(seq, "camera_03", 4, "semantic")
    hole = raw == 0
    assert hole.sum() > 100 and (rect[hole] == 10).mean() > 0.95
    assert np.array_equal(rect[~hole], raw[~hole])
    _, rows = query(built, f"SELECT source, omission, relabelled FROM rectification WHERE sequence_id = '{seq}'")
    assert len(rows) == 36 and {r[0] for r in rows} == {"recorded"} and all(o > 0 and r == o for _, o, r in rows)


def test_show_sensors_puts_the_recorded_rgb_first(built, tmp_path):
    out = tmp_path / "sheet.png"
    r = cli.invoke(app, ["show", "sensors", "--root", built.root, "--seq", f"town00_{SEQ}", "--frame", "2", "--step", "1",
                         "--out", str(out)])  # fmt: skip
    assert r.exit_code == 0, r.output
    from PIL import Image

    from carlaocc.catalog.sensors import SensorStore

    sheet = np.asarray(Image.open(out).convert("RGB"))
    rgb = SensorStore(built).read_image(f"town00_{SEQ}", "camera_00", 2, "rgb")
    # the sheet's first tile (top left) is camera_00's recorded RGB, pixel for pixel
    hits = [(r, c) for r in range(sheet.shape[0] - rgb.shape[0])
            for c in [sheet[r].tobytes().find(rgb[0].tobytes())] if c >= 0 and c % 3 == 0]
    r, c = hits[0]
    assert np.array_equal(sheet[r : r + rgb.shape[0], c // 3 : c // 3 + rgb.shape[1]], rgb)
    assert r < 60 and c // 3 < sheet.shape[1] // 6  # the first row, the first of six columns


def test_rig_from_calib_and_the_rear_cameras():
    from carlaocc.catalog.store import StoreError
    from carlaocc.pipeline.tasks.recording import check_rig, rig_from_calib
    from carlaocc.schemas.rig import RigConfig

    rig = RigConfig()
    lidar = np.asarray(rig.lidar.sensor_to_ego())
    # the reference rig's cameras as a calibration would hold them: body-to-LiDAR, exact matrices
    # (a rear camera's rotation has -0.0 or 1e-16 entries: either way it is yaw 180)
    cams = {}
    for c in rig.cameras:
        T = invert_pose(lidar) @ np.asarray(c.sensor_to_ego())
        T[np.abs(T) < 1e-12] = -0.0
        cams[c.name.replace("camera_", "cam_")] = T
    calib = cr.Calib(width=1408, height=376, fov_deg=103.744808, intrinsics=np.eye(3), cam_to_lidar=cams)
    rebuilt = rig_from_calib(calib, rig)
    for a, b in zip(rebuilt.cameras, rig.cameras):
        assert a.name == b.name and (a.x, a.y, a.z) == pytest.approx((b.x, b.y, b.z)) and a.yaw_deg == pytest.approx(b.yaw_deg)
    check_rig(rig, calib, "test")  # the default rig is the calibration's
    turned = dict(cams, cam_00=cams["cam_00"] @ np.asarray(rig.cameras[0].model_copy(update={"yaw_deg": 5.0, "x": 0, "y": 0, "z": 0}).sensor_to_ego()))
    with pytest.raises(StoreError, match="camera_00 differs"):
        check_rig(rig, cr.Calib(1408, 376, 103.744808, np.eye(3), turned), "test")


def test_dataset_config_merge_keeps_town_positions(recording, tmp_path):
    from carlaocc.catalog.store import StoreError
    from carlaocc.pipeline.tasks.recording import recording_config

    cfg = recording_config(str(recording))
    assert [t.style for t in cfg.scenes.towns] == ["carla-recording"] and cfg.scenes.rig.cameras[0].width == 176
    # a dataset with the recording first and a simulated town after it: re-ingesting keeps both in place
    both = cfg.model_copy(update={"scenes": cfg.scenes.model_copy(update={"towns": cfg.scenes.towns + (
        cfg.scenes.towns[0].model_copy(update={"style": "downtown", "recording": None, "map": None}),)})})
    again = recording_config(str(recording), both)
    assert [t.style for t in again.scenes.towns] == ["carla-recording", "downtown"]
    assert again.scenes.asset_sources == both.scenes.asset_sources
    # a recording with another calibration does not join
    other = tmp_path / "rec"
    shutil.copytree(recording, other, ignore=shutil.ignore_patterns("rgb", "depth_carla", "semantics_carla", "*lidar"))
    calib = other / "calib" / "calib.yaml"
    data = yaml.safe_load(calib.read_text())  # twice as wide, with its own (consistent) intrinsics
    cs = data["cam_settings"]
    cs["width"], cs["intrinsics"] = 352, cr.pinhole(352, cs["height"], cs["fov"]).tolist()
    calib.write_text(yaml.dump(data))
    with pytest.raises(StoreError, match="differs from the recording"):
        recording_config(str(other), cfg)


def test_a_release_layout_without_the_raw_maps(recording, tmp_path):
    """The release ships the rectified depth/ and semantics/ (no *_carla folders): those are read."""
    from carlaocc.catalog.sensors import SensorStore

    rel = tmp_path / "rec"
    shutil.copytree(recording, rel)
    for raw, release in (("depth_carla", "depth"), ("semantics_carla", "semantics")):
        (rel / SEQ / raw).rename(rel / SEQ / release)
    store = _ingest_and_run(rel, tmp_path / "data", stages="ingest,scenes,sensors")
    from PIL import Image

    depth = cr.decode_depth(np.asarray(Image.open(rel / SEQ / "depth" / "image_00" / "0001.png")))
    got = SensorStore(store).read_image(f"town00_{SEQ}", "camera_00", 1, "depth_raw")
    assert np.array_equal(got, np.where(depth >= 80, 0, depth))


def test_intrinsics_disagreeing_with_the_fov_are_refused(recording, tmp_path):
    """A calibration whose intrinsics are not the pinhole of its size and fov: exit 2, one line
    naming calib.yaml, nothing written."""
    rec = tmp_path / "rec"
    shutil.copytree(recording, rec)
    calib = rec / "calib" / "calib.yaml"
    data = yaml.safe_load(calib.read_text())
    data["cam_settings"]["fov"] = 90.0
    calib.write_text(yaml.dump(data))
    root = tmp_path / "d"
    r = cli.invoke(app, ["ingest", "carla-recording", str(rec), "--root", str(root), "--scheduler", "synchronous"])
    assert r.exit_code == 2, r.output
    assert "calib.yaml: cam_settings.intrinsics" in r.output and "fov 90 deg" in r.output
    assert len(r.output.strip().splitlines()) == 1
    assert not root.exists() or not any(root.iterdir())


def test_a_swapped_copy_of_a_recorded_sequence_is_cast_not_read(built, tmp_path):
    """An edited copy of a recorded sequence (``scenes swap``; the fixture's actors have no
    compatible other asset, so the copy's record is written as swap writes it): the recording
    shows the original actors, so the copy's sensors are cast like a simulated sequence's (they
    used to fail: the copy's name is not a folder of the recording); the original still reads its
    recorded files."""
    from carlaocc.catalog.parquet import ParquetTable
    from carlaocc.pipeline.commands.scene_editing import swap_id
    from carlaocc.pipeline.engine.spec import Context
    from carlaocc.pipeline.tasks.sensors import sensors_partitions
    from carlaocc.schemas.records import FrameRecord, SequenceRecord

    root = tmp_path / "data"
    shutil.copytree(built.root, root)
    store = Store(str(root))
    parent_id = f"town00_{SEQ}"
    child_id = swap_id(parent_id, "Car", 1)
    for model in (SequenceRecord, FrameRecord):
        t = ParquetTable(store, model)
        t.save(child_id, [r.model_copy(update={"sequence_id": child_id} | (
            {"parent_sequence_id": parent_id, "edit": "swap Car seed=1"} if model is SequenceRecord else {}))
            for r in t.load([parent_id])])
    cfg = DatasetConfig.model_validate(yaml.safe_load((root / "dataset.yaml").read_text()))
    by_seq = {}
    for p in sensors_partitions(Context(store=store, config=cfg, voxel_sizes=(VOXEL_SIZE,))):
        by_seq.setdefault(p.key.split("/")[0], []).append(p)
    assert by_seq[parent_id] and all("recorded" in p.params and p.files for p in by_seq[parent_id])
    assert by_seq[child_id] and not any("recorded" in p.params or p.files for p in by_seq[child_id])
