"""``carlaocc eval``: input formats, pairing, JSON content, tables, and one-line errors (exit 2)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from carlaocc.catalog.formats import save_carlaocc_npz
from carlaocc.pipeline.cli import app
from carlaocc.stages.evaluation import SSCAccumulator, label_map

cli = CliRunner()


def _run(*args):
    return cli.invoke(app, ["eval", *map(str, args)])


@pytest.fixture
def occ_dirs(tmp_path):
    """Two Occ3D-like frames in nested directories: gt .npz with masks, pred as .npy and .npz."""
    rng = np.random.default_rng(0)
    gt_dir, pred_dir = tmp_path / "gt", tmp_path / "pred"
    frames = []
    for i, rel in enumerate(["scene-1/a", "scene-2/b"]):
        gt = rng.integers(0, 18, (8, 6, 4)).astype(np.uint8)
        pred = np.where(rng.random(gt.shape) < 0.3, rng.integers(0, 18, gt.shape), gt).astype(np.uint8)
        cam = (rng.random(gt.shape) < 0.7).astype(np.uint8)
        (gt_dir / rel).parent.mkdir(parents=True, exist_ok=True)
        (pred_dir / rel).parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(gt_dir / f"{rel}.npz", semantics=gt, mask_lidar=np.ones_like(gt), mask_camera=cam)
        if i == 0:
            np.save(pred_dir / f"{rel}.npy", pred)
        else:
            np.savez(pred_dir / f"{rel}.npz", semantics=pred)
        frames.append((pred, gt, cam.astype(bool)))
    return pred_dir, gt_dir, frames


def test_ssc_directories_json_and_table(occ_dirs, tmp_path):
    pred_dir, gt_dir, frames = occ_dirs
    out = tmp_path / "res" / "ssc.json"
    r = _run("ssc", "--pred", pred_dir, "--gt", gt_dir, "--map", "occ3d", "--mask", "camera", "--json", out)
    assert r.exit_code == 0, r.output
    data = json.loads(out.read_text())
    acc = SSCAccumulator(label_map("occ3d"))
    for pred, gt, cam in frames:
        acc.update(pred, gt, cam)
    want = acc.result()
    assert data["frames"] == 2 and data["label_map"] == "occ3d" and data["mask"] == "camera"
    assert data["miou"] == pytest.approx(want.miou)
    assert data["geometry"]["iou"] == pytest.approx(want.geometry_iou)
    assert [c["name"] for c in data["classes"]][:2] == ["others", "barrier"] and len(data["classes"]) == 17
    assert np.array(data["confusion"]).sum() == sum(int(c.sum()) for _, _, c in frames)
    assert "mIoU" in r.output and "geometry IoU" in r.output and f"{100 * want.miou:6.2f}" in r.output


def test_missing_counterpart_and_shape_mismatch_are_one_line_errors(occ_dirs):
    pred_dir, gt_dir, _ = occ_dirs
    (pred_dir / "scene-1" / "a.npy").unlink()
    r = _run("ssc", "--pred", pred_dir, "--gt", gt_dir, "--map", "occ3d")
    assert r.exit_code == 2
    assert r.output.startswith("error: no prediction for ") and "scene-1/a.npz" in r.output
    assert len(r.output.strip().splitlines()) == 1
    np.save(pred_dir / "scene-1" / "a.npy", np.zeros((3, 3, 3), np.uint8))
    r = _run("ssc", "--pred", pred_dir, "--gt", gt_dir, "--map", "occ3d")
    assert r.exit_code == 2 and "a.npy: shape (3, 3, 3) differs" in r.output
    np.save(pred_dir / "extra.npy", np.zeros((3, 3, 3), np.uint8))
    r = _run("ssc", "--pred", pred_dir, "--gt", gt_dir, "--map", "occ3d")
    assert r.exit_code == 2 and "extra.npy has no ground truth" in r.output


@pytest.mark.parametrize("args, message", [
    (["--map", "kitti"], "--map: unknown label map 'kitti'"),
    (["--mask", "radar"], "--mask must be none, camera or lidar"),
    (["--ignore", "x"], "--ignore 'x'"),
])
def test_bad_options(occ_dirs, args, message):
    pred_dir, gt_dir, _ = occ_dirs
    r = _run("ssc", "--pred", pred_dir, "--gt", gt_dir, *args)
    assert r.exit_code == 2 and message in r.output


def test_missing_path_mask_and_label_errors(tmp_path, occ_dirs):
    pred_dir, gt_dir, _ = occ_dirs
    r = _run("ssc", "--pred", tmp_path / "nope", "--gt", gt_dir)
    assert r.exit_code == 2 and "--pred" in r.output and "does not exist" in r.output
    np.savez(tmp_path / "g.npz", semantics=np.zeros((2, 2, 2), np.uint8))
    np.save(tmp_path / "p.npy", np.full((2, 2, 2), 40, np.uint8))
    r = _run("ssc", "--pred", tmp_path / "p.npy", "--gt", tmp_path / "g.npz", "--mask", "camera")
    assert r.exit_code == 2 and "needs a 'mask_camera' array" in r.output
    r = _run("ssc", "--pred", tmp_path / "p.npy", "--gt", tmp_path / "g.npz")
    assert r.exit_code == 2 and "p.npy" in r.output and "label 40" in r.output


def test_carlaocc_npz_ground_truth_is_mapped_into_the_label_space(tmp_path):
    sem = np.zeros((6, 4, 3), np.uint8)
    inst = np.zeros(sem.shape, np.uint32)
    sem[0:2] = 14  # CarlaOcc Car -> Occ3D car (4)
    inst[0:2] = 3
    sem[3] = 1  # Road -> driveable_surface (11)
    save_carlaocc_npz(tmp_path / "gt.npz", sem, inst, 0.2, (0.0, 0.0, 0.0))
    pred = np.full(sem.shape, 17, np.uint8)
    pred[0:2] = 4
    pred[3, :2] = 11
    np.savez(tmp_path / "pred.npz", semantics=pred, instances=np.where(pred == 4, 9, 0).astype(np.uint32))
    out = tmp_path / "r.json"
    r = _run("ssc", "--pred", tmp_path / "pred.npz", "--gt", tmp_path / "gt.npz", "--map", "occ3d", "--json", out)
    assert r.exit_code == 0, r.output
    iou = {c["name"]: c["iou"] for c in json.loads(out.read_text())["classes"]}
    assert iou["car"] == 1.0 and iou["driveable_surface"] == 0.5 and iou["bus"] is None
    # the same pair scored panoptically: car 3 = pred 9 (IoU 1), road half covered (IoU 0.5, no match)
    r = _run("panoptic", "--pred", tmp_path / "pred.npz", "--gt", tmp_path / "gt.npz", "--map", "occ3d", "--json", out)
    assert r.exit_code == 0, r.output
    d = json.loads(out.read_text())
    rows = {c["name"]: c for c in d["classes"]}
    assert rows["car"]["pq"] == 1.0 and rows["car"]["thing"] is True
    assert (rows["driveable_surface"]["tp"], rows["driveable_surface"]["fn"]) == (0, 1)
    assert d["pq"] == pytest.approx(0.5) and d["pq_things"] == 1.0 and d["pq_stuff"] == 0.0
    assert "mean things" in r.output


def test_panoptic_needs_instances(tmp_path):
    np.savez(tmp_path / "g.npz", semantics=np.zeros((2, 2, 2), np.uint8), instances=np.zeros((2, 2, 2), np.uint32))
    np.savez(tmp_path / "p.npz", semantics=np.zeros((2, 2, 2), np.uint8))
    r = _run("panoptic", "--pred", tmp_path / "p.npz", "--gt", tmp_path / "g.npz")
    assert r.exit_code == 2 and "p.npz: no 'instances' array" in r.output
    r = _run("panoptic", "--pred", tmp_path / "g.npz", "--gt", tmp_path / "g.npz", "--things", "0")
    assert r.exit_code == 2 and "--things" in r.output


def test_depth(tmp_path):
    (tmp_path / "p").mkdir()
    (tmp_path / "g").mkdir()
    np.save(tmp_path / "p" / "000.npy", np.array([[2.0, 2.0, 3.0, 5.0]], np.float32))
    np.savez(tmp_path / "g" / "000.npz", depth=np.array([[1.0, 2.0, 4.0, 0.0]], np.float32))
    out = tmp_path / "d.json"
    r = _run("depth", "--pred", tmp_path / "p", "--gt", tmp_path / "g", "--json", out)
    assert r.exit_code == 0, r.output
    d = json.loads(out.read_text())
    assert d["pixels"] == 3 and d["pixel"]["abs_rel"] == pytest.approx(1.25 / 3)
    assert d["pixel"]["rmse"] == pytest.approx(math.sqrt(2 / 3)) and d["image"]["a2"] == pytest.approx(2 / 3)
    assert "AbsRel" in r.output
    np.save(tmp_path / "p" / "000.npy", np.zeros((3, 3, 3)))
    r = _run("depth", "--pred", tmp_path / "p", "--gt", tmp_path / "g")
    assert r.exit_code == 2 and "000.npy: depth must be a 2-D" in r.output


def test_det_both_box_forms(tmp_path):
    gt = {"s0": [{"center": [0, 0, 0], "size": [4, 2, 1.5], "yaw": 0.5, "label": "car"}],
          "s1": [{"center": [10, 0, 0], "size": [4, 2, 1.5], "yaw": 0.0, "label": "car"}]}
    # nuScenes form: size (w, l, h), rotation quaternion (w, x, y, z) for yaw 0.5 + 0.2
    q = [math.cos(0.35), 0, 0, math.sin(0.35)]
    pred = {"results": {
        "s0": [{"translation": [0.3, 0.4, 0], "size": [2, 4, 1.5], "rotation": q, "detection_name": "car", "detection_score": 0.8}],
        "s1": []}}
    (tmp_path / "gt.json").write_text(json.dumps(gt))
    (tmp_path / "pred.json").write_text(json.dumps(pred))
    out = tmp_path / "det.json"
    r = _run("det", "--pred", tmp_path / "pred.json", "--gt", tmp_path / "gt.json", "--json", out)
    assert r.exit_code == 0, r.output
    d = json.loads(out.read_text())
    car = d["classes"][0]
    # one of two cars found 0.5 m away: AP 0 at 0.5 m (not < 0.5), recall 1/2 elsewhere
    assert car["ap_by_distance"]["0.5"] == 0.0 and car["ate"] == pytest.approx(0.5)
    assert car["aoe"] == pytest.approx(0.2) and car["ase"] == pytest.approx(0.0, abs=1e-12)
    assert d["mAP"] == pytest.approx(0.75 * 40 / 90)  # AP 40/90 (precision 1 up to recall 0.5) at 1, 2, 4 m
    assert "mATE" in r.output
    del pred["results"]["s1"]
    (tmp_path / "pred.json").write_text(json.dumps(pred))
    r = _run("det", "--pred", tmp_path / "pred.json", "--gt", tmp_path / "gt.json")
    assert r.exit_code == 2 and "no entry for sample 's1'" in r.output
    (tmp_path / "pred.json").write_text(json.dumps({"s0": [{"center": [0, 0, 0], "size": [4, 2, 1], "yaw": 0, "label": "car"}], "s1": []}))
    r = _run("det", "--pred", tmp_path / "pred.json", "--gt", tmp_path / "gt.json")
    assert r.exit_code == 2 and "needs a score" in r.output
    # a quaternion that is not unit length is normalised (the devkit's pyquaternion does); a zero
    # one is refused, naming the box
    pred = {"results": {"s0": [{**pred["results"]["s0"][0], "rotation": [3 * v for v in q]}], "s1": []}}
    (tmp_path / "pred.json").write_text(json.dumps(pred))
    r = _run("det", "--pred", tmp_path / "pred.json", "--gt", tmp_path / "gt.json", "--json", out)
    assert r.exit_code == 0, r.output
    assert json.loads(out.read_text())["classes"][0]["aoe"] == pytest.approx(0.2)
    pred["results"]["s0"][0]["rotation"] = [0, 0, 0, 0]
    (tmp_path / "pred.json").write_text(json.dumps(pred))
    r = _run("det", "--pred", tmp_path / "pred.json", "--gt", tmp_path / "gt.json")
    assert r.exit_code == 2 and "is not a rotation quaternion" in r.output
