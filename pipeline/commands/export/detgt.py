"""``carlaocc export det-gt``: the ground-truth boxes of a built root in the nuScenes detection
result layout, so ``carlaocc eval det`` (and nuScenes-style tools) score detectors on our data.

``OUT/det_gt.json``: ``{"results": {token: [box, ...]}, "meta": {...}}`` with, per box (global
frame, as the devkit's EvalBox): ``sample_token``, ``translation`` [3] m, ``size`` [w, l, h] m,
``rotation`` [w, x, y, z], ``velocity`` [vx, vy] m/s, ``detection_name``, ``attribute_name``,
``num_lidar_pts`` (our LiDAR's points inside the box), ``ego_translation`` (the box centre minus
the ego position, global axes: its norm is the devkit's range), ``instance_id`` (ours) and
``detection_score`` 1. Tokens are ``<sequence>_<frame:06d>`` (those of ``export mmdet3d-infos``);
``meta.splits`` maps each sequence to its split.

Classes: our road users with a nuScenes detection name (Car car, Truck truck, Bus bus,
Pedestrian pedestrian, Motorcycle motorcycle, Bicycle bicycle); the others have no box class
there and are left out (``meta.classes`` says which). Attributes from motion, with
mmdetection3d's 0.2 m/s threshold: vehicles ``vehicle.moving`` or ``vehicle.parked``,
pedestrians ``pedestrian.moving`` or ``pedestrian.standing``, two-wheelers ``cycle.with_rider``
(ours are always ridden). ``meta.ego_positions`` gives each sample's ego position (global), so
``eval det --nuscenes-filters`` measures predictions' ranges from the ego.
"""

from __future__ import annotations

import json
import math

import numpy as np

from carlaocc.catalog.formats import atomic_write
from carlaocc.pipeline.commands.export.spec import (ExportFormat, ExportJob, frame_samples, sample_with_boxes,
                                                    split_assignment)
from carlaocc.schemas import taxonomy
from carlaocc.stages.export.boxes import points_in_boxes
from carlaocc.stages.geometry import quaternion_wxyz

DET_NAMES = {"Car": "car", "Truck": "truck", "Bus": "bus", "Pedestrian": "pedestrian", "Motorcycle": "motorcycle",
             "Bicycle": "bicycle"}


MOVING = 0.2  # m/s: mmdetection3d's threshold for the motion attributes


def attribute(det_name: str, speed: float) -> str:
    """The nuScenes attribute a box's motion implies (see the module doc)."""
    if det_name == "pedestrian":
        return "pedestrian.moving" if speed > MOVING else "pedestrian.standing"
    if det_name in ("bicycle", "motorcycle"):
        return "cycle.with_rider"  # ours are always ridden
    return "vehicle.moving" if speed > MOVING else "vehicle.parked"


def sample_boxes(sample: dict, token: str) -> list[dict]:
    """The nuScenes boxes of one loader sample (:class:`carlaocc.data.CarlaOccDataset`)."""
    lidar, ego = sample["lidar_pose"], sample["ego_pose"]
    pts = sample["points"].astype(np.float64) if "points" in sample else np.zeros((0, 3))
    n_pts = points_in_boxes(pts, sample["box_pose"], sample["boxes"])
    out = []
    for b, pose, v, iid, sid, n in zip(sample["boxes"], sample["box_pose"], sample["box_velocity"],
                                       sample["box_instance"], sample["box_semantic"], n_pts):
        name = DET_NAMES.get(taxonomy.by_id(int(sid)).name)
        if name is None:
            continue
        world = lidar @ pose  # box -> world
        vw = lidar[:3, :3] @ v.astype(np.float64)  # velocity in world axes
        out.append({
            "sample_token": token, "translation": world[:3, 3].tolist(),
            "size": [float(b[4]), float(b[3]), float(b[5])],  # w, l, h
            "rotation": quaternion_wxyz(world[:3, :3]), "velocity": [float(vw[0]), float(vw[1])],
            "detection_name": name, "detection_score": 1.0,
            "attribute_name": attribute(name, math.hypot(vw[0], vw[1])), "num_lidar_pts": int(n),
            "ego_translation": (world[:3, 3] - ego[:3, 3]).tolist(), "instance_id": int(iid),
        })  # fmt: skip
    return out


def write_det_gt(job: ExportJob) -> tuple[int, int, int]:
    """Write ``OUT/det_gt.json``; returns (sequences, frames, files)."""
    ds = frame_samples(job.store, job.voxel_size, job.sequences, cameras=False)
    results: dict[str, list] = {}
    egos: dict[str, list] = {}
    for k, (seq, frame) in enumerate(ds.samples):
        token = f"{seq}_{frame:06d}"
        sample = sample_with_boxes(ds, k)
        results[token] = sample_boxes(sample, token)
        egos[token] = sample["ego_pose"][:3, 3].tolist()
        job.advance()
    splits = split_assignment(job.store)
    seqs = sorted({s for s, _ in ds.samples})
    doc = {"results": results, "meta": {
        "use_camera": True, "use_lidar": True, "use_radar": False, "use_map": False, "use_external": False,
        "classes": sorted(set(DET_NAMES.values())), "frame": "global (the dataset's world frame)",
        "splits": {s: splits.get(s, "") for s in seqs}, "source": "carlaocc export det-gt", "ego_positions": egos,
    }}  # fmt: skip
    atomic_write(job.out / "det_gt.json", lambda fh: fh.write(json.dumps(doc).encode()))
    return len(seqs), len(ds.samples), 1


FORMATS = (
    ExportFormat("det-gt", "det_gt.json: the boxes in the nuScenes detection result layout with velocities, "
                 "attributes and LiDAR point counts, for carlaocc eval det", write_det_gt, finest_by_default=True),
)
