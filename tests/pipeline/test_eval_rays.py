"""`carlaocc eval rayiou | raypq` end to end on the shared built root's exports: the Occ3D ground
truth against itself with the infos' origins scores 1 everywhere it has rays; a prediction that
loses a class scores 0 there; RayPQ on the OpenOcc v2 export (instances) against itself is 1;
without infos the command says it is not the standard protocol."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from typer.testing import CliRunner

from carlaocc.pipeline.cli import app
from carlaocc.pipeline.cli.evaluate_rays import ray_origins

cli = CliRunner()


def _pkls(infos_dir):
    return [str(p) for p in sorted(infos_dir.glob("carlaocc_infos_*.pkl"))]


def test_rayiou_of_the_ground_truth_against_itself_is_one(infos_01, tmp_path):
    args = ["eval", "rayiou", "--gt", str(infos_01 / "gts"), "--pred", str(infos_01 / "gts"),
            "--json", str(tmp_path / "r.json")]
    for p in _pkls(infos_01):
        args += ["--infos", p]
    r = cli.invoke(app, args)
    assert r.exit_code == 0, r.output
    doc = json.loads((tmp_path / "r.json").read_text())
    assert doc["protocol"] == "sparseocc" and doc["samples"] == 6 and doc["rays"] > 100_000
    assert doc["origins"]["source"] == "infos" and "origins: the LiDAR positions of each scene's frames" in r.output
    assert doc["RayIoU"] == 1.0 and doc["RayIoU@1"] == doc["RayIoU@2"] == doc["RayIoU@4"] == 1.0
    present = [c for c, v in doc["per_class"].items() if v["gt_rays"]]
    assert {"driveable_surface", "manmade", "vegetation"} <= set(present)
    assert "RayIoU" in r.output and "@1" in r.output  # the table


def test_origins_come_from_the_scene_frames(infos_01):
    origins = ray_origins([__import__("pathlib").Path(p) for p in _pkls(infos_01)])
    assert len(origins) == 6
    for o in origins.values():
        # two frames a sequence: the sample's own LiDAR (1.73 m up) and its neighbour's
        assert 1 <= len(o) <= 2 and np.any(np.all(np.isclose(o, [0.0, 0.0, 1.73], atol=1e-6), axis=1))


def test_a_lost_class_scores_zero_and_no_infos_is_flagged(infos_01, tmp_path):
    """Without --infos: one origin a sample at nuScenes' lidar2ego translation (SparseOcc's origin
    for a sample alone in its scene), said in the output; --origin overrides it, flagged as not the
    standard protocol."""
    pred = tmp_path / "pred"
    shutil.copytree(infos_01 / "gts", pred)
    for f in pred.glob("*/*/labels.npz"):
        z = dict(np.load(f))
        z["semantics"] = np.where(z["semantics"] == 16, 17, z["semantics"]).astype(np.uint8)  # vegetation -> free
        np.savez_compressed(f, **z)
    r = cli.invoke(app, ["eval", "rayiou", "--gt", str(infos_01 / "gts"), "--pred", str(pred), "--json",
                         str(tmp_path / "r.json")])
    assert r.exit_code == 0, r.output
    assert "origins: one origin per sample at nuScenes' LIDAR_TOP lidar2ego translation [0.985793, 0.0, 1.84019]" \
        in r.output and "NOT the standard protocol" not in r.output
    doc = json.loads((tmp_path / "r.json").read_text())
    assert doc["per_class"]["vegetation"]["@4"] == 0.0 and doc["per_class"]["driveable_surface"]["@1"] < 1.0 + 1e-9
    assert doc["protocol"].startswith("sparseocc (lone sample")
    assert doc["origins"] == {"source": "lidar2ego", "per_sample": 1, "xyz": [0.985793, 0.0, 1.84019]}
    r = cli.invoke(app, ["eval", "rayiou", "--gt", str(infos_01 / "gts"), "--pred", str(pred), "--origin", "0,0,1.73",
                         "--json", str(tmp_path / "r.json")])
    assert r.exit_code == 0, r.output
    assert "origins: one origin per sample at --origin [0.0, 0.0, 1.73] m: NOT the standard protocol" in r.output
    doc = json.loads((tmp_path / "r.json").read_text())
    assert doc["protocol"].startswith("single origin") and doc["origins"]["source"] == "--origin"
    r = cli.invoke(app, ["eval", "rayiou", "--gt", str(infos_01 / "gts"), "--pred", str(pred), "--origin", "0,0"])
    assert r.exit_code == 2 and "--origin '0,0': x,y,z in metres" in r.output


def test_raypq_on_the_openocc_export_against_itself(openocc_01, infos_01, tmp_path):
    args = ["eval", "raypq", "--classes", "openocc-v2", "--gt", str(openocc_01), "--pred", str(openocc_01),
            "--json", str(tmp_path / "p.json")]
    for p in _pkls(infos_01):
        args += ["--infos", p]
    r = cli.invoke(app, args)
    assert r.exit_code == 0, r.output
    doc = json.loads((tmp_path / "p.json").read_text())
    assert doc["RayPQ"] == 1.0 and doc["RayIoU"] == 1.0 and doc["samples"] == 2
    # the export carries flow: mAVE 0 over the moving classes' rays, occupancy score 1
    assert doc["mAVE"] == 0.0 and doc["occupancy_score"] == 1.0 and doc["AVE_per_class"]["car"] == 0.0
    assert "occupancy score" in r.output
    assert any(v["@1"] == 1.0 for v in doc["per_class"].values())
    # a missing instances array is a clear error
    r = cli.invoke(app, ["eval", "raypq", "--gt", str(infos_01 / "gts"), "--pred", str(infos_01 / "gts")])
    assert r.exit_code == 2 and "instances" in r.output


def test_det_gt_export_scores_itself_perfectly_with_nds(default_01, tmp_path):
    """`export det-gt` writes the nuScenes layout (global boxes, w l h, quaternions, velocities,
    attributes, point counts); `eval det --nuscenes-filters` of it against itself: NDS 1."""
    from carlaocc.data import CarlaOccDataset
    from carlaocc.stages.geometry import rotation_from_quaternion

    out = tmp_path / "det"
    r = cli.invoke(app, ["export", "det-gt", "--root", default_01.url, "--out", str(out)])
    assert r.exit_code == 0, r.output
    doc = json.loads((out / "det_gt.json").read_text())
    ds = CarlaOccDataset(default_01.url, occupancy="none", cameras=False)
    assert sorted(doc["results"]) == sorted(f"{s}_{f:06d}" for s, f in ds.samples)
    boxes = [b for bs in doc["results"].values() for b in bs]
    assert boxes and {b["detection_name"] for b in boxes} <= set(doc["meta"]["classes"])
    assert any(b["attribute_name"] == "vehicle.moving" for b in boxes) and any(b["num_lidar_pts"] > 0 for b in boxes)
    assert sorted(doc["meta"]["ego_positions"]) == sorted(doc["results"])
    # one box against the loader: global centre, yaw, w-l-h order and velocity
    seq, frame = ds.samples[0]
    s = ds[0]
    b = next(x for x in doc["results"][f"{seq}_{frame:06d}"] if x["instance_id"] == int(s["box_instance"][0])) \
        if any(x["instance_id"] == int(s["box_instance"][0]) for x in doc["results"][f"{seq}_{frame:06d}"]) else None
    if b is not None:
        world = s["lidar_pose"] @ s["box_pose"][0]
        np.testing.assert_allclose(b["translation"], world[:3, 3], atol=1e-6)
        np.testing.assert_allclose(rotation_from_quaternion(b["rotation"]), world[:3, :3], atol=1e-6)
        assert b["size"] == [float(s["boxes"][0][4]), float(s["boxes"][0][3]), float(s["boxes"][0][5])]
    # the devkit drops ground truth without LiDAR points, not predictions: a perfect detector
    # reports the boxes it can see
    # (a detector's output carries no ego_translation: the range comes from the ground truth's egos)
    pred = {"results": {t: [{k: v for k, v in x.items() if k not in ("num_lidar_pts", "ego_translation")}
                            for x in bs if x["num_lidar_pts"] > 0]
                        for t, bs in doc["results"].items()}, "meta": {}}
    (tmp_path / "pred.json").write_text(json.dumps(pred))
    assert sum(len(v) for v in pred["results"].values()) < len(boxes)  # some boxes are hidden
    r = cli.invoke(app, ["eval", "det", "--pred", str(tmp_path / "pred.json"), "--gt", str(out / "det_gt.json"),
                         "--nuscenes-filters", "--json", str(tmp_path / "d.json")])
    assert r.exit_code == 0, r.output
    res = json.loads((tmp_path / "d.json").read_text())
    assert res["NDS"] == pytest.approx(1.0) and res["mAP"] == pytest.approx(1.0) and res["mAVE"] == 0.0 and res["mAAE"] == 0.0
    assert "NDS 1.0000" in r.output


def test_a_carlaocc_root_as_ground_truth(default_01, infos_01, tmp_path):
    """--gt a built root: its frames resampled onto the Occ3D grid with origins from its poses;
    the infos export's ground truth as the prediction scores 1 (the same resampling)."""
    r = cli.invoke(app, ["eval", "rayiou", "--gt", default_01.root, "--pred", str(infos_01 / "gts"),
                         "--json", str(tmp_path / "r.json")])
    assert r.exit_code == 0, r.output
    doc = json.loads((tmp_path / "r.json").read_text())
    assert doc["protocol"] == "sparseocc" and doc["samples"] == 6 and doc["RayIoU"] == 1.0
    assert doc["origins"]["source"] == "root poses" and "(the root poses)" in r.output
    # a missing prediction names the frame
    r = cli.invoke(app, ["eval", "rayiou", "--gt", default_01.root, "--pred", str(tmp_path)])
    assert r.exit_code == 2 and "no prediction for" in r.output


def test_a_carlaocc_root_as_prediction(default_01, infos_01, tmp_path):
    """--pred a built root against its own Occ3D export: 1 (the same frames, the same resampling)."""
    args = ["eval", "rayiou", "--gt", str(infos_01 / "gts"), "--pred", default_01.root, "--json", str(tmp_path / "r.json")]
    for p in _pkls(infos_01):
        args += ["--infos", p]
    r = cli.invoke(app, args)
    assert r.exit_code == 0, r.output
    assert json.loads((tmp_path / "r.json").read_text())["RayIoU"] == 1.0


def test_nuscenes_filters_measure_predictions_from_the_ego(tmp_path):
    """World-frame predictions carry no ego_translation: the range is measured from the ego of
    the ground truth (here 300 m from the world origin), not from the origin."""
    gt = {"results": {"s0": [{"translation": [310.0, 0.0, 1.0], "size": [2.0, 4.5, 1.6], "rotation": [1, 0, 0, 0],
                              "velocity": [1.0, 0.0], "detection_name": "car", "attribute_name": "vehicle.moving",
                              "num_lidar_pts": 20, "ego_translation": [10.0, 0.0, 0.0]}]}}
    pred = {"results": {"s0": [{k: v for k, v in gt["results"]["s0"][0].items()
                                if k not in ("num_lidar_pts", "ego_translation")} | {"detection_score": 0.9}]}}
    (tmp_path / "gt.json").write_text(json.dumps(gt))
    (tmp_path / "pred.json").write_text(json.dumps(pred))
    r = cli.invoke(app, ["eval", "det", "--pred", str(tmp_path / "pred.json"), "--gt", str(tmp_path / "gt.json"),
                         "--nuscenes-filters", "--json", str(tmp_path / "d.json")])
    assert r.exit_code == 0, r.output
    assert json.loads((tmp_path / "d.json").read_text())["mAP"] == pytest.approx(1.0)
