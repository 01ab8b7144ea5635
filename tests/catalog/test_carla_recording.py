"""Reading CARLA recordings in the CarlaOcc release layout, on a recording written by
tools/make_carla_recording.py in the saver's own encodings (not by the pipeline): axes (left
stays left, meshes' y-up axes, the optical frame), encodings and the odd recordings."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from carlaocc.catalog import carla_recording as cr
from carlaocc.stages.geometry import signed_volume, transform_points

ROOT = Path(__file__).resolve().parents[2]
SEQ = "Town99_Opt_Seq00"


@pytest.fixture(scope="session")
def recording(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("carla") / "rec"
    subprocess.run([sys.executable, str(ROOT / "tools" / "make_carla_recording.py"), str(out)], check=True,
                   capture_output=True)  # fmt: skip
    return out


@pytest.fixture
def copy(recording, tmp_path) -> Path:
    """A writable copy of the recording, for the odd ones."""
    out = tmp_path / "rec"
    shutil.copytree(recording, out)
    return out


def test_discover_finds_sequences_meshes_and_models(recording):
    rec = cr.discover(recording)
    assert [s.name for s in rec.sequences] == [SEQ] and rec.sequences[0].town == "Town99_Opt"
    assert list(rec.scene_meshes) == ["Town99_Opt"]
    assert set(rec.vehicle_models) == {"vehicle.lincoln.mkz", "vehicle.mini.cooper", "vehicle.taxi.ford"}
    assert cr.model_key("vehicle.lincoln.mkz") in rec.vehicle_models
    # a sequence directory given alone finds calib and meshes beside it
    assert cr.discover(recording / SEQ).sequences == rec.sequences
    with pytest.raises(cr.RecordingError, match="no sequence directories"):
        cr.discover(recording / "calib")


def test_calib_cameras_look_where_the_rig_says(recording):
    cal = cr.read_calib(recording / "calib" / "calib.yaml")
    assert (cal.width, cal.height) == (176, 48) and list(cal.cam_to_lidar) == [f"cam_0{i}" for i in range(6)]
    fx = cal.intrinsics[0, 0]
    assert fx == pytest.approx(88 / np.tan(np.radians(cal.fov_deg) / 2), rel=1e-5)
    forward = {n: T[:3, 0] for n, T in cal.cam_to_lidar.items()}
    # cam_00 looks ahead from the left (y > 0), cam_02 to the left, cam_03 to the right
    assert forward["cam_00"] == pytest.approx([1, 0, 0]) and cal.cam_to_lidar["cam_00"][1, 3] > 0
    assert forward["cam_02"] == pytest.approx([0, 1, 0], abs=1e-6)
    assert forward["cam_03"] == pytest.approx([0, -1, 0], abs=1e-6)


def test_poses_and_the_odd_lines(copy):
    path = copy / SEQ / "poses" / "lidar.txt"
    poses, bad = cr.read_poses(path)
    assert sorted(poses) == list(range(6)) and not bad
    assert poses[2][:3, 3] == pytest.approx([-9.0, -1.74, 1.73])
    lines = path.read_text().splitlines()
    lines[3] = "0003 " + " ".join(["nan"] * 16)
    path.write_text("\n".join(lines[:5]) + "\n")  # a NaN pose and a file shorter than the frames
    poses, bad = cr.read_poses(path)
    assert sorted(poses) == [0, 1, 2, 4] and bad[0][0] == 3 and "non-finite" in bad[0][1]
    path.write_text(lines[0] + "\n0001 1 2 3\n")
    with pytest.raises(cr.RecordingError, match=r"lidar.txt, line 2: expected a frame number and 16 numbers"):
        cr.read_poses(path)
    with pytest.raises(cr.RecordingError, match="missing"):
        cr.read_poses(copy / SEQ / "poses" / "nope.txt")


def test_traffic_left_stays_left_and_bad_actors_are_skipped(copy):
    tf = cr.read_traffic(copy / SEQ / "traffic_info" / "0000.yaml")
    assert tf.ego.id == 231 and tf.ego.velocity == pytest.approx([5, 0.05, 0])
    cars = {v.id: v for v in tf.vehicles}
    # car 246 comes the other way in the left lane: y > 0, heading -x
    assert cars[246].transform[1, 3] == pytest.approx(1.75) and cars[246].transform[0, 0] == pytest.approx(-1, abs=0.01)
    assert cars[245].transform[1, 3] == pytest.approx(-1.75)
    assert cars[245].extent == pytest.approx([2.4, 1.0, 0.75]) and cars[245].bbox_transform[2, 3] == pytest.approx(0.75)
    (ped,) = tf.pedestrians
    assert set(ped.bones) == {"crl_leg__L", "crl_leg__R"}
    # the lower-leg bones are socket transforms in the actor frame (origin the box centre): the
    # knees lie inside the box, below its centre, the left one on the walker's left (+y)
    knees = np.array([ped.bones[b][:3, 3] for b in ("crl_leg__L", "crl_leg__R")])
    assert (np.abs(knees) <= ped.extent + 1e-6).all() and (knees[:, 2] < 0).all() and knees[0, 1] > knees[1, 1]
    # a NaN transform leaves that actor out, named
    path = copy / SEQ / "traffic_info" / "0001.yaml"
    text = path.read_text().replace("- 4.6", "- .nan", 1)
    path.write_text(text)
    tf = cr.read_traffic(path)
    assert [v.id for v in tf.vehicles] == [246] and tf.skipped[0][0] == 245 and "non-finite" in tf.skipped[0][1]
    path.write_text("- just a list\n")
    with pytest.raises(cr.RecordingError, match="0001.yaml: expected a mapping"):
        cr.read_traffic(path)


def test_static_actors_meshes_in_our_frame(copy):
    scene = copy / "SceneMeshes" / "Town99_Opt"
    actors, skipped = cr.read_actor_info(scene)
    assert not skipped and len(actors) == 15
    by_name = {a.name: a for a in actors}
    building = by_name["BP_Apartment01"]
    assert building.semantic_id == 3 and building.instance_id == 1
    V, F = cr.read_mesh(building.file)
    # the export's bounds are world metres: the mesh axes (y up, z right) convert onto them
    assert V.min(axis=0) == pytest.approx(building.bbox_min) and V.max(axis=0) == pytest.approx(building.bbox_max)
    assert building.bbox_min[1] > 0  # the building stands on the left of the road
    assert signed_volume(V, F) == pytest.approx(10 * 8 * 8)  # closed, wound outwards
    # a missing mesh and an unknown class are left out with their reasons
    (scene / "bg_actors" / "BP_StreetLight_1.obj").unlink()
    info = (scene / "actor_info.json").read_text().replace('"semantic_label": "Building"', '"semantic_label": "Castle"')
    (scene / "actor_info.json").write_text(info)
    actors, skipped = cr.read_actor_info(scene)
    reasons = dict(skipped)
    assert len(actors) == 13 and "missing mesh" in reasons["BP_StreetLight_1"] and "Castle" in reasons["BP_Apartment01"]


def test_camera_maps_decode_onto_the_scene(recording):
    seq = recording / SEQ
    cal = cr.read_calib(recording / "calib" / "calib.yaml")
    lidar, _ = cr.read_poses(seq / "poses" / "lidar.txt")
    depth = cr.decode_depth(np.asarray(Image.open(seq / "depth_carla" / "image_00" / "0002.png")))
    sem, unknown = cr.decode_semantics(np.asarray(Image.open(seq / "semantics_carla" / "image_00" / "0002.png")))
    assert depth.dtype == np.float32 and depth.max() == pytest.approx(80.0) and unknown == 0
    assert {1, 3, 11, 14} <= set(np.unique(sem).tolist())  # road, building, sky, cars
    # road pixels back-projected (planar depth, optical frame -> body -> LiDAR -> world) lie on z = 0
    v, u = np.nonzero(sem == 1)
    K = cal.intrinsics
    d = depth[v, u]
    opt = np.stack([(u + 0.5 - K[0, 2]) / K[0, 0] * d, (v + 0.5 - K[1, 2]) / K[1, 1] * d, d], axis=1)
    cam = lidar[2] @ cal.cam_to_lidar["cam_00"] @ cr.OPTICAL_FROM_BODY
    world = transform_points(cam, opt)
    assert np.abs(world[:, 2]).max() < 0.02
    # building pixels are on the left half of the front camera
    assert np.nonzero(sem == 3)[1].mean() < cal.width / 2
    # an unknown colour is counted and becomes 0
    img = np.asarray(Image.open(seq / "semantics_carla" / "image_00" / "0002.png")).copy()
    img[0, :5] = (1, 2, 3)
    ids, unknown = cr.decode_semantics(img)
    assert unknown == 5 and (ids[0, :5] == 0).all()


def test_lidar_points_in_the_sensor_frame(recording):
    seq = recording / SEQ
    ply = cr.read_ply(seq / "semantic_lidar" / "0000.ply")
    assert set(ply) == {"x", "y", "z", "CosAngle", "ObjIdx", "ObjTag"}
    pts = np.column_stack([ply["x"], ply["y"], ply["z"]])
    # the building's returns are on the left (y > 0), the road's below the sensor
    assert (pts[ply["ObjTag"] == 3][:, 1] > 0).all()
    assert np.median(pts[ply["ObjTag"] == 1][:, 2]) == pytest.approx(-1.73, abs=0.02)
    plain = cr.read_ply(seq / "lidar" / "0000.ply")
    assert list(plain) == ["x", "y", "z", "I"] and len(plain["x"]) == len(pts)
    # a truncated file (fewer rows than the header says) and a header without a count
    lines = (seq / "lidar" / "0000.ply").read_text().splitlines()
    bad = recording.parent / "bad.ply"
    bad.write_text("\n".join(lines[:-10]) + "\n")
    with pytest.raises(cr.RecordingError, match="bad.ply: header says"):
        cr.read_ply(bad)
    bad.write_text("\n".join(line for line in lines if not line.startswith("element")) + "\n")
    with pytest.raises(cr.RecordingError, match="element vertex"):
        cr.read_ply(bad)


def test_both_scans_round_trip_through_the_recorded_lidar_store(recording, tmp_path):
    """read_scans joins a frame's two scans (scan 0: lidar/, scan 1: semantic_lidar/, each
    point kept with its own columns); RecordedLidarStore writes them to
    lidar_recorded/<seq>/<frame>.parquet and reads the same values back."""
    from carlaocc.catalog.sensors import RECORDED_LIDAR_COLUMNS, RecordedLidarStore
    from carlaocc.catalog.store import Store

    seq = recording / SEQ
    plain, sem = cr.read_ply(seq / "lidar" / "0002.ply"), cr.read_ply(seq / "semantic_lidar" / "0002.ply")
    pts = cr.read_scans(seq / "lidar" / "0002.ply", seq / "semantic_lidar" / "0002.ply")
    n0 = len(plain["x"])
    assert len(pts["x"]) == n0 + len(sem["x"]) and (pts["scan"][:n0] == 0).all() and (pts["scan"][n0:] == 1).all()
    np.testing.assert_array_equal(pts["y"][:n0], plain["y"])  # the saver's y-negated frame is ours: kept
    np.testing.assert_array_equal(pts["intensity"][:n0], plain["I"])
    np.testing.assert_array_equal(pts["semantic"][n0:], sem["ObjTag"])
    assert (pts["semantic"][:n0] == cr.NOT_RECORDED).all() and np.isnan(pts["cos_angle"][:n0]).all()
    np.testing.assert_allclose(pts["distance"], np.linalg.norm(np.column_stack([pts["x"], pts["y"], pts["z"]]), axis=1))
    assert len(cr.read_scans(None, seq / "semantic_lidar" / "0002.ply")["x"]) == len(sem["x"])
    assert len(cr.read_scans()["x"]) == 0
    store = Store(str(tmp_path / "data"))
    lidar = RecordedLidarStore(store)
    ours = np.full(len(pts["x"]), np.inf, np.float32)
    lidar.save("s", 2, {**pts, "raycast_distance": ours}, {"recorded_frame": 2})
    assert lidar.path("s", 2) == "lidar_recorded/s/000002.parquet" and lidar.frames("s") == [2]
    back = lidar.load("s", 2)
    assert list(back) == list(RECORDED_LIDAR_COLUMNS)
    for c in pts:
        np.testing.assert_array_equal(back[c], pts[c].astype(RECORDED_LIDAR_COLUMNS[c][0]), err_msg=c)
    assert lidar.metadata("s", 2)["recorded_frame"] == 2
    # a semantic scan without its tags is named
    bad = tmp_path / "0002.ply"
    bad.write_text((seq / "semantic_lidar" / "0002.ply").read_text().replace("ObjTag", "Tag"))
    with pytest.raises(cr.RecordingError, match="0002.ply: no property ObjTag"):
        cr.read_scans(None, bad)


def test_intrinsics_must_match_size_and_fov(copy):
    """The rig is built from the image size and fov; intrinsics saying otherwise are refused
    with one line naming the file and both sides (CARLA's pinhole: f = (W/2) / tan(fov/2))."""
    path = copy / "calib" / "calib.yaml"
    data = yaml.safe_load(path.read_text())
    cs = data["cam_settings"]
    assert np.asarray(cs["intrinsics"]) == pytest.approx(cr.pinhole(cs["width"], cs["height"], cs["fov"]), abs=1e-5)
    for key, value in (("fov", 90.0), ("width", 180), ("height", 50)):
        bad = yaml.safe_load(path.read_text())
        bad["cam_settings"][key] = value
        path.with_name("bad.yaml").write_text(yaml.dump(bad))
        with pytest.raises(cr.RecordingError, match=r"bad.yaml: cam_settings.intrinsics .* disagree with the image size"):
            cr.read_calib(path.with_name("bad.yaml"))
    bad = yaml.safe_load(path.read_text())
    bad["cam_settings"]["intrinsics"][1][2] += 0.4  # within INTRINSICS_TOL: rounding in the saver
    path.with_name("ok.yaml").write_text(yaml.dump(bad))
    assert cr.read_calib(path.with_name("ok.yaml")).width == cs["width"]
    with pytest.raises(cr.RecordingError, match=r"a fov of 90\.000 deg"):
        cr.check_intrinsics(cr.pinhole(200, 100, 90.0), 200, 100, 100.0, "calib.yaml")
