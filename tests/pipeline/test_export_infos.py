"""`carlaocc export mmdet3d-infos` on the shared built root (0.1 m, two frames a sequence,
camera_00): the infos load with pickle, every path in them exists, each box centre projected
through the info's own intrinsics and camera-to-LiDAR transform lands on that instance's pixels
(or behind something nearer), the Occ3D ground truth reads back, and the JSON says the same."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from carlaocc.catalog.sensors import SensorStore
from carlaocc.pipeline.cli import app
from carlaocc.stages.geometry import quaternion_wxyz, rotation_from_quaternion

cli = CliRunner()


@pytest.fixture(scope="module")
def exported(infos_01) -> Path:
    return infos_01


def _infos(out: Path) -> list[dict]:
    infos = []
    for split in ("train", "val", "test"):
        with open(out / f"carlaocc_infos_{split}.pkl", "rb") as fh:
            doc = pickle.load(fh)
        assert doc["metadata"]["version"] == "carlaocc-infos-1"
        infos += doc["infos"]
    return infos


def test_infos_load_and_every_path_exists(exported, default_01):
    infos = _infos(exported)
    n_frames = 6
    assert len(infos) == n_frames and len({i["token"] for i in infos}) == n_frames
    for info in infos:
        assert (exported / info["lidar_path"]).is_file()
        pts = np.fromfile(exported / info["lidar_path"], np.float32).reshape(-1, 5)
        assert len(pts) > 100 and np.isfinite(pts).all()
        for cam in info["cams"].values():
            assert (exported / cam["data_path"]).is_file() and not Path(cam["data_path"]).is_absolute()
        z = np.load(exported / info["occ_path"] / "labels.npz")
        assert sorted(z.files) == ["mask_camera", "mask_lidar", "semantics"]
        assert z["semantics"].shape == (200, 200, 16) and z["semantics"].max() <= 17
        assert (z["semantics"] == 17).any() and (z["semantics"] < 17).any() and z["mask_camera"].any()
    # prev / next chain each scene in time order
    by_token = {i["token"]: i for i in infos}
    for info in infos:
        if info["next"]:
            nxt = by_token[info["next"]]
            assert nxt["prev"] == info["token"] and nxt["timestamp"] > info["timestamp"]
            assert nxt["scene_name"] == info["scene_name"]
    # sorted by time (as BEVDet / FlashOcc sort them), every frame's neighbour in its scene is its prev
    timeline = sorted(infos, key=lambda i: i["timestamp"])
    assert len({i["timestamp"] for i in infos}) == len(infos)
    for a, b in zip(timeline, timeline[1:]):
        assert (b["prev"] == a["token"]) == (b["scene_name"] == a["scene_name"])
    beams = np.fromfile(exported / infos[0]["lidar_path"], np.float32).reshape(-1, 5)[:, 4]
    assert beams.min() == 0 and beams.max() == 31  # the 32-beam LiDAR's channels
    splits = {s: set((exported / "splits" / f"{s}.txt").read_text().split()) for s in ("train", "val", "test")}
    assert set.union(*splits.values()) == {i["scene_name"] for i in infos}
    grid = json.loads((exported / "grid.json").read_text())
    assert grid["voxel_size"] == 0.4 and grid["origin"] == [-40.0, -40.0, -1.0]
    assert "+ 0.5" in grid["index_to_metre"] and grid["frame"].startswith("ego")


def test_box_centres_project_onto_their_instance(exported, default_01):
    sensors = SensorStore(default_01)
    on_pixels = checked = 0
    for info in _infos(exported):
        seq, frame = info["scene_name"], info["frame_idx"]
        for cam, c in info["cams"].items():
            inst = sensors.read_image(seq, cam, frame, "instance")
            depth = sensors.read_image(seq, cam, frame, "depth")
            H, W = inst.shape
            R, t, K = np.asarray(c["sensor2lidar_rotation"]), np.asarray(c["sensor2lidar_translation"]), c["cam_intrinsic"]
            for box, iid in zip(info["gt_boxes"], info["instance_inds"]):
                p = R.T @ (box[:3] - t)  # LiDAR -> camera, inverting p_lidar = R p_cam + t
                if p[2] < 1.0:
                    continue
                u, v = (K @ p)[:2] / p[2]
                if not (3 <= u < W - 3 and 3 <= v < H - 3):
                    continue
                ui, vi = int(u), int(v)
                patch = inst[vi - 3:vi + 4, ui - 3:ui + 4]
                checked += 1
                if iid in patch:
                    on_pixels += 1
                else:  # hidden: something nearer than the box's near side fills the pixel
                    assert depth[vi, ui] < p[2] - 0.25 * min(box[3], box[4]), (seq, frame, iid)
    assert checked >= 3 and on_pixels >= 2, (checked, on_pixels)


def test_ego_frame_annotations_and_json_agree(exported):
    for split in ("train", "val", "test"):
        doc = pickle.load(open(exported / f"carlaocc_infos_{split}.pkl", "rb"))
        js = json.loads((exported / f"carlaocc_infos_{split}.json").read_text())
        assert [i["token"] for i in js["infos"]] == [i["token"] for i in doc["infos"]]
        for info, jinfo in zip(doc["infos"], js["infos"]):
            np.testing.assert_allclose(jinfo["gt_boxes"], info["gt_boxes"])
            R = rotation_from_quaternion(info["lidar2ego_rotation"])
            t = np.asarray(info["lidar2ego_translation"])
            boxes, labels = info["ann_infos"]
            valid = info["valid_flag"] & np.isin(info["gt_names"], ["car", "truck", "bus", "motorcycle", "bicycle",
                                                                   "pedestrian"])
            assert len(boxes) == valid.sum() == len(labels)
            np.testing.assert_allclose(boxes[:, :3], info["gt_boxes"][valid, :3] @ R.T + t, atol=1e-4)


def test_quaternions_round_trip():
    rng = np.random.default_rng(0)
    from carlaocc.stages.geometry import rotation_matrix

    for _ in range(200):
        R = rotation_matrix(*rng.uniform(-np.pi, np.pi, 3))
        q = quaternion_wxyz(R)
        assert q[0] >= 0 and abs(np.linalg.norm(q) - 1) < 1e-12
        np.testing.assert_allclose(rotation_from_quaternion(q), R, atol=1e-12)
    # half turns (trace -1) too
    for R in (np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1])):
        np.testing.assert_allclose(rotation_from_quaternion(quaternion_wxyz(R)), R, atol=1e-12)


def test_occ3d_and_infos_ground_truth_share_one_token_scheme(exported, default_01, tmp_path):
    """`export occ3d` names frames `gts/<seq>/<seq>_<frame:06d>/labels.npz` like the infos' occ_path:
    the two trees hold the same tokens and the same arrays, so `eval ssc` of one against the other
    scores 1.0."""
    out = tmp_path / "occ3d"
    r = cli.invoke(app, ["export", "occ3d", "--res", "0.1", "--root", default_01.url, "--out", str(out)])
    assert r.exit_code == 0, r.output
    ours = {p.relative_to(out) for p in out.glob("gts/*/*/labels.npz")}
    theirs = {p.relative_to(exported) for p in exported.glob("gts/*/*/labels.npz")}
    assert ours == theirs and len(ours) == 6
    assert {p.parent.name for p in ours} == {info["token"] for info in _infos(exported)}
    for rel in ours:
        a, b = np.load(out / rel), np.load(exported / rel)
        assert all(np.array_equal(a[k], b[k]) for k in ("semantics", "mask_lidar", "mask_camera"))
    js = tmp_path / "ssc.json"
    r = cli.invoke(app, ["eval", "ssc", "--pred", str(out / "gts"), "--gt", str(exported / "gts"), "--map", "occ3d",
                         "--mask", "camera", "--json", str(js)])
    assert r.exit_code == 0, r.output
    assert json.loads(js.read_text())["miou"] == pytest.approx(1.0)
