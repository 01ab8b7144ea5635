"""``carlaocc export mmdet3d-infos``: per-sample info files of the kind OpenMMLab-based occupancy
pipelines read (BEVDet / FlashOcc / SparseOcc / OccNet: the mmdet3d v1 nuScenes info format with
BEVDet's additions), with the images, LiDAR sweeps and Occ3D-style ground truth as files.

Layout under ``OUT`` (every path inside the infos is relative to ``OUT``)::

    carlaocc_infos_{train,val,test}.pkl   {"infos": [info, ...], "metadata": {...}} (pickle;
                                           carlaocc_infos_all.pkl for a root built before splits)
    carlaocc_infos_{train,val,test}.json  the same for humans (arrays as lists)
    samples/<camera>/<token>.jpg           the rig's RGB (JPEG, quality 95)
    samples/LIDAR_TOP/<token>.bin          float32 (N, 5): x, y, z, intensity (0), beam (0 = top)
    gts/<sequence>/<token>/labels.npz      Occ3D-nuScenes: semantics, mask_lidar, mask_camera
    grid.json                              the Occ3D grid: frame, origin, voxel size, axes, labels
    splits/{train,val,test}.txt            the sequences of each split

``token`` is ``<sequence>_<frame:06d>``; ``scene_name`` / ``scene_token`` the sequence id.
Per info (``../shared/reference/training-formats.md`` section 4 lists the keys and their sources):
``token``, ``timestamp`` (microseconds; increasing over the export, see
:data:`SEQUENCE_SPACING_US`), ``frame_idx``, ``prev`` / ``next`` (``""`` at the ends),
``scene_token``, ``scene_name``, ``lidar_path``, ``sweeps`` (empty), ``lidar2ego_translation`` /
``lidar2ego_rotation`` (quaternion w, x, y, z), ``ego2global_translation`` / ``_rotation``,
``cams[<camera>]`` (``data_path``, ``type``, ``sample_data_token``, ``sensor2ego_*``,
``ego2global_*``, ``timestamp``, ``sensor2lidar_rotation`` (3 x 3) and ``_translation`` with
``p_lidar = R @ p_cam + t``, ``cam_intrinsic`` (3 x 3, OpenCV camera frame)), ``gt_boxes`` (N, 7)
LiDAR frame ``x, y, z, l, w, h, yaw``, ``gt_names`` (nuScenes detection names where a class has
one, else ours in lower case), ``gt_velocity`` (N, 2) LiDAR axes, ``num_lidar_pts``,
``num_radar_pts`` (0), ``valid_flag`` (a LiDAR point inside), ``instance_inds`` (our instance ids:
the ids of the occupancy and the instance maps), ``ann_infos`` (BEVDet: boxes ``x, y, z, l, w, h,
yaw, vx, vy`` in the ego frame and their indices in :data:`DETECTION_CLASSES`, valid boxes of
those classes only) and ``occ_path`` (``gts/<scene>/<token>``, the directory of ``labels.npz``).
"""

from __future__ import annotations

import numpy as np

from carlaocc.catalog.formats import Occ3DFrame, atomic_write, save_occ3d
from carlaocc.catalog.formats.manifest import grid_manifest, save_grid_manifest
from carlaocc.catalog.formats.mmdet3d import jpeg_bytes, save_infos
from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.pipeline.commands.export.spec import (Coverage, ExportFormat, ExportJob, frame_samples, one_label_table,
                                                    sample_with_boxes, save_sequence_splits, split_assignment)
from carlaocc.schemas import taxonomy
from carlaocc.stages.export.boxes import points_in_boxes
from carlaocc.stages.geometry import quaternion_wxyz
from carlaocc.stages.export.resample import OCC3D_NUSCENES, resample

DETECTION_CLASSES = ("car", "truck", "construction_vehicle", "bus", "trailer", "barrier", "motorcycle", "bicycle",
                     "pedestrian", "traffic_cone")
"""BEVDet's detection label order (``ann_infos`` indexes it)."""
NUSCENES_NAMES = {"Car": "car", "Truck": "truck", "Bus": "bus", "Motorcycle": "motorcycle", "Bicycle": "bicycle",
                  "Pedestrian": "pedestrian"}
"""Our classes that have a nuScenes detection name (the others keep their own, and are not in ``ann_infos``)."""
INFO_VERSION = "carlaocc-infos-1"


SEQUENCE_SPACING_US = 10**10
"""Timestamps are the frame's time in its sequence plus the sequence's rank times this (10,000
s): unique and increasing over the whole export, so consumers that sort infos by time (BEVDet /
FlashOcc do, then take a frame's neighbours as its history) keep every sequence's frames together."""


def frame_info(sample: dict, token: str, prev: str, nxt: str, label_table: str,
               sequence_rank: int = 0) -> tuple[dict, dict[str, bytes]]:
    """The info dict of one loader sample (:class:`carlaocc.data.CarlaOccDataset`) and the files it
    names (relative path -> bytes) except the occupancy; ``sequence_rank`` places its sequence on
    the export's time line (:data:`SEQUENCE_SPACING_US`)."""
    seq = sample["sequence_id"]
    ego, lidar = sample["ego_pose"], sample["lidar_pose"]
    lidar_to_ego = sample["lidar_to_ego"]
    t_us = sequence_rank * SEQUENCE_SPACING_US + int(round(sample["timestamp"] * 1e6))
    files: dict[str, bytes] = {}
    lidar_path = f"samples/LIDAR_TOP/{token}.bin"
    pts = sample["points"]
    cloud = np.zeros((len(pts), 5), np.float32)
    cloud[:, :3] = pts
    cloud[:, 4] = sample["points_channel"]
    files[lidar_path] = cloud.tobytes()
    cams = {}
    for k, cam in enumerate(sample["camera_names"]):
        path = f"samples/{cam}/{token}.jpg"
        files[path] = jpeg_bytes(sample["images"][k])
        c2l, c2e = sample["cam_to_lidar"][k], sample["cam_to_ego"][k]
        cams[cam] = {
            "data_path": path, "type": cam, "sample_data_token": f"{token}_{cam}",
            "sensor2ego_translation": c2e[:3, 3].tolist(), "sensor2ego_rotation": quaternion_wxyz(c2e[:3, :3]),
            "ego2global_translation": ego[:3, 3].tolist(), "ego2global_rotation": quaternion_wxyz(ego[:3, :3]),
            "timestamp": t_us, "sensor2lidar_rotation": c2l[:3, :3].copy(), "sensor2lidar_translation": c2l[:3, 3].copy(),
            "cam_intrinsic": np.asarray(sample["cam_intrinsics"][k], np.float64),
        }  # fmt: skip
    boxes, pose, vel = sample["boxes"], sample["box_pose"], sample["box_velocity"]
    names = [taxonomy.by_id(int(s)).name for s in sample["box_semantic"]]
    num_pts = points_in_boxes(pts.astype(np.float64), pose, boxes)
    # BEVDet's ann_infos: valid boxes of the detection classes, in the ego frame, with velocity
    ann_boxes, ann_labels = [], []
    R_le, t_le = lidar_to_ego[:3, :3], lidar_to_ego[:3, 3]
    for b, p, v, name, n in zip(boxes, pose, vel, names, num_pts):
        det = NUSCENES_NAMES.get(name)
        if det is None or n == 0:
            continue
        R = R_le @ p[:3, :3]
        c = R_le @ b[:3] + t_le
        ve = R_le @ v
        ann_boxes.append([*c, *b[3:6], float(np.arctan2(R[1, 0], R[0, 0])), ve[0], ve[1]])
        ann_labels.append(DETECTION_CLASSES.index(det))
    info = {
        "token": token, "timestamp": t_us, "frame_idx": int(sample["frame_index"]), "prev": prev, "next": nxt,
        "scene_token": seq, "scene_name": seq, "lidar_path": lidar_path, "sweeps": [],
        "lidar2ego_translation": lidar_to_ego[:3, 3].tolist(), "lidar2ego_rotation": quaternion_wxyz(lidar_to_ego[:3, :3]),
        "ego2global_translation": ego[:3, 3].tolist(), "ego2global_rotation": quaternion_wxyz(ego[:3, :3]),
        "lidar2global": lidar.copy(), "cams": cams,
        "gt_boxes": boxes.astype(np.float32), "gt_names": np.array([NUSCENES_NAMES.get(n, n.lower()) for n in names]),
        "gt_velocity": vel[:, :2].astype(np.float32), "num_lidar_pts": num_pts, "num_radar_pts": np.zeros(len(boxes), np.int64),
        "valid_flag": num_pts > 0, "instance_inds": sample["box_instance"].astype(np.int64),
        "ann_infos": (np.asarray(ann_boxes, np.float32).reshape(-1, 9), np.asarray(ann_labels, np.int64)),
        "occ_path": f"gts/{seq}/{token}", "label_table": label_table,
    }  # fmt: skip
    return info, files


def occ3d_manifest(label_table: str, notes: dict | None = None) -> dict:
    """``grid.json`` of the Occ3D ground truth the infos point to (``notes``: the built region
    and its coverage, :class:`carlaocc.pipeline.commands.export.spec.Coverage`)."""
    g = OCC3D_NUSCENES
    grid = {"origin": g.range_min, "voxel_size": g.voxel_size, "shape": g.shape}
    return grid_manifest("occ3d-nuscenes (gts/<scene>/<token>/labels.npz)", "ego", [grid],
                         taxonomy.OCC3D_NUSCENES_NAMES, g.free_label, label_table, notes=notes)


def write_infos(job: ExportJob) -> tuple[int, int, int]:
    """Write the infos, images, sweeps and Occ3D ground truth of every frame built at
    ``job.voxel_size`` (or of ``job.sequences``); returns (sequences, frames, files)."""
    store, out = job.store, job.out
    ds = frame_samples(store, job.voxel_size, job.sequences)
    seqs = sorted({s for s, _ in ds.samples})
    label_table = one_label_table(store, {s: ds.grid(s) for s in seqs})
    occ = OccupancyStore(store)
    assignment = split_assignment(store)
    by_split: dict[str, list] = {}
    n_files = 0
    camera_names: list[str] = []
    cover = Coverage(OCC3D_NUSCENES, job.format)
    order = ds.samples
    for idx, (seq, frame) in enumerate(order):
        token = f"{seq}_{frame:06d}"
        prev = f"{seq}_{order[idx - 1][1]:06d}" if idx and order[idx - 1][0] == seq else ""
        nxt = f"{seq}_{order[idx + 1][1]:06d}" if idx + 1 < len(order) and order[idx + 1][0] == seq else ""
        sample = sample_with_boxes(ds, idx)
        info, files = frame_info(sample, token, prev, nxt, label_table, seqs.index(seq))
        camera_names = sample["camera_names"]
        for rel, data in files.items():
            atomic_write(out / rel, lambda fh, b=data: fh.write(b))
        # the Occ3D ground truth: our frame resampled into the ego grid, with its masks
        grid = ds.grid(seq)
        names = tuple(n for n in ("semantic", "mask_lidar", "mask_camera") if occ.exists(seq, grid, n))
        data = occ.read_frame(seq, grid, frame, names)
        labels, m = resample(data["semantic"], grid, OCC3D_NUSCENES, sample["lidar_to_ego"],
                             {k: data[k] for k in names[1:]}, label_table=label_table)
        # outside our region nothing is observed (without visibility masks: inside it everything)
        inside = cover.inside(seq, grid, sample["lidar_to_ego"])
        mask = {k: (m[k].astype(bool) & inside) if k in m else inside for k in ("mask_lidar", "mask_camera")}
        save_occ3d(out / info["occ_path"] / "labels.npz",
                   Occ3DFrame(labels, mask["mask_lidar"].astype(np.uint8), mask["mask_camera"].astype(np.uint8)))
        n_files += len(files) + 1
        by_split.setdefault(assignment.get(seq, "all") if assignment else "all", []).append(info)
        job.advance()
    metadata = {"version": INFO_VERSION, "voxel_size_built": ds.voxel_size, "label_table": label_table,
                "detection_classes": list(DETECTION_CLASSES), "camera_names": camera_names}
    for split, infos in by_split.items():
        n_files += save_infos(out, f"carlaocc_infos_{split}", {"infos": infos, "metadata": metadata})
    n_files += save_grid_manifest(out, occ3d_manifest(label_table, cover.notes()))
    n_files += save_sequence_splits(out, seqs, assignment)
    return len(seqs), len(order), n_files


FORMATS = (
    ExportFormat("mmdet3d-infos", "carlaocc_infos_{train,val,test}.pkl/.json with the keys BEVDet / FlashOcc / "
                 "SparseOcc pipelines read, samples/<camera>/<token>.jpg, samples/LIDAR_TOP/<token>.bin, "
                 "gts/<scene>/<token>/labels.npz as Occ3D, grid.json; every path relative to --out", write_infos),
)
