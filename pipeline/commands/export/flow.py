"""``carlaocc export openocc-v2`` and ``carlaocc export uniocc``: occupancy with instances and flow
in the layouts of the occupancy-and-flow models (``../shared/reference/training-formats.md``
sections 2 and 3 give the layouts, keys and units with their sources).

* ``openocc-v2``: ``<sequence>/<token>/labels.npz`` with ``semantics`` (200, 200, 16) uint8
  (OpenOcc v2 ids, free = 16), ``instances`` (200, 200, 16) uint32 (our instance ids: stable
  within a sequence, 0 for stuff and free) and ``flow`` (200, 200, 16, 2) float32: the voxel's
  velocity along the ego x and y axes, m/s (world motion; 0 for static voxels).
* ``uniocc``: ``scene_infos.pkl`` (a list of ``{"scene_name", "occ_in_scene_paths"}``, paths
  relative to OUT) and ``<sequence>/<frame>.npz`` with ``occ_label`` (UniOcc ids, free = 10),
  ``occ_mask_camera``, ``occ_flow_forward`` / ``occ_flow_backward`` (200, 200, 16, 3) float32 in
  **voxels**: where each labelled voxel's material is in the next (previous) frame's ego grid,
  minus where it is now (static voxels move by the ego motion, moving ones by their velocity
  times the frame interval: first order), 0 in the last (first) frame;
  ``ego_to_world_transformation`` (4, 4); ``cameras`` (name, ``filename`` =
  ``samples/<camera>/<token>.jpg`` as ``export mmdet3d-infos`` writes the images, intrinsics,
  extrinsics camera -> LiDAR) and ``annotations`` (``token`` = our instance id, ``agent_to_ego``,
  ``agent_to_world``, ``size`` l w h, ``category_id`` UniOcc) as pickled object arrays
  (``np.load(..., allow_pickle=True)``, as UniOcc's loader reads them).

Both use the Occ3D grid: ego frame, origin (-40, -40, -1) m, 0.4 m, and write ``grid.json``.
``token`` is ``<sequence>_<frame:06d>`` (the mmdet3d-infos tokens).
"""

from __future__ import annotations

import numpy as np

from carlaocc.catalog.formats.openocc import save_openocc_v2, save_scene_infos, save_uniocc_frame
from carlaocc.catalog.formats.manifest import save_grid_manifest
from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.sensors import SensorStore
from carlaocc.catalog.store import Store
from carlaocc.pipeline.commands.export.grids import target_manifest
from carlaocc.pipeline.commands.export.spec import (Coverage, ExportFormat, ExportJob, frame_samples, one_label_table,
                                                    sample_with_boxes, save_sequence_splits, split_assignment)
from carlaocc.schemas import taxonomy
from carlaocc.stages.export.flow import uniocc_flow
from carlaocc.stages.export.resample import OPENOCC_V2, UNIOCC, resample, resample_panoptic

GRIDS = {"openocc-v2": OPENOCC_V2, "uniocc": UNIOCC}
NOTES = {"openocc-v2": {"flow": "flow[..., 0:2]: vx, vy along the ego axes, m/s (world motion; 0 static)"},
         "uniocc": {"flow": "occ_flow_forward/backward: (next/previous ego-grid position - current) / voxel_size, voxels"}}


def write_flow(job: ExportJob) -> tuple[int, int, int]:
    """Write ``job.format`` (openocc-v2 | uniocc) for every frame built at ``job.voxel_size``;
    returns (sequences, frames, files)."""
    store, out, fmt = job.store, job.out, job.format
    target = GRIDS[fmt]
    ds = frame_samples(store, job.voxel_size, job.sequences, lidar=False, cameras=False)
    seqs = sorted({s for s, _ in ds.samples})
    label_table = one_label_table(store, {s: ds.grid(s) for s in seqs})
    occ = OccupancyStore(store)
    cats = taxonomy.mapping("uniocc", label_table)
    n_files = 0
    scene_infos = []
    cover = Coverage(target, fmt)

    for seq in seqs:
        grid = ds.grid(seq)
        idx = [k for k, (s, _) in enumerate(ds.samples) if s == seq]
        names = tuple(n for n in ("semantic", "instance", "flow", "mask_lidar", "mask_camera") if occ.exists(seq, grid, n))
        paths = []
        samples = {k: sample_with_boxes(ds, k) for k in idx} if fmt == "uniocc" else {}
        for pos, k in enumerate(idx):
            smp = samples.get(k) or sample_with_boxes(ds, k)
            frame = smp["frame_index"]
            token = f"{seq}_{frame:06d}"
            data = occ.read_frame(seq, grid, frame, names)
            masks = {n: data[n] for n in ("mask_lidar", "mask_camera") if n in data}
            to_ego = smp["lidar_to_ego"]
            labels, m = resample(data["semantic"], grid, target, to_ego, masks, label_table=label_table)
            # outside our region nothing is observed (without visibility masks: inside it everything)
            inside = cover.inside(seq, grid, to_ego)
            m = {k: (m[k].astype(bool) & inside) if k in m else inside for k in ("mask_lidar", "mask_camera")}
            inst, flow = resample_panoptic(data["semantic"], data.get("instance", np.zeros_like(data["semantic"], np.uint32)),
                                           data.get("flow"), grid, target, to_ego, label_table=label_table)
            if flow is None:
                flow = np.zeros((*target.shape, 3), np.float32)
            if fmt == "openocc-v2":
                rel = f"{seq}/{token}/labels.npz"
                save_openocc_v2(out / rel, labels, inst, flow[..., :2].copy())
            else:
                rel = f"{seq}/{frame}.npz"
                save_uniocc_frame(out / rel, uniocc_frame(store, smp, labels, m, flow, target, cats,
                                                          samples[idx[pos - 1]] if pos else None,
                                                          samples[idx[pos + 1]] if pos + 1 < len(idx) else None))
            paths.append(rel)
            n_files += 1
            job.advance()
        scene_infos.append({"scene_name": seq, "occ_in_scene_paths": paths})
    if fmt == "uniocc":
        save_scene_infos(out / "scene_infos.pkl", scene_infos)
        n_files += 1
    n_files += save_grid_manifest(out, target_manifest(target, label_table, fmt, NOTES[fmt] | cover.notes()))
    n_files += save_sequence_splits(out, seqs, split_assignment(store))
    return len(seqs), len(ds.samples), n_files


def uniocc_frame(store: Store, sample: dict, labels: np.ndarray, masks: dict, flow: np.ndarray, target, cats: dict,
                 prev: dict | None, nxt: dict | None) -> dict:
    """The arrays of one UniOcc frame (see the module doc) from a loader sample with its boxes,
    its labels, masks and velocity resampled onto ``target``, and its neighbours' samples."""
    ego = sample["ego_pose"]
    fwd = uniocc_flow(labels, flow, ego, nxt["ego_pose"] if nxt else None,
                      (nxt["timestamp"] - sample["timestamp"]) if nxt else 0.0, target)
    bwd = uniocc_flow(labels, flow, ego, prev["ego_pose"] if prev else None,
                      (prev["timestamp"] - sample["timestamp"]) if prev else 0.0, target)
    seq = sample["sequence_id"]
    cams = camera_list(store, seq, f"{seq}_{sample['frame_index']:06d}")
    world_to_ego = np.linalg.inv(ego)
    annotations = [{"token": int(i), "agent_to_ego": world_to_ego @ sample["lidar_pose"] @ p,
                    "agent_to_world": sample["lidar_pose"] @ p, "size": b[3:6].astype(np.float64),
                    "category_id": int(cats[int(c)])}
                   for b, p, i, c in zip(sample["boxes"], sample["box_pose"], sample["box_instance"], sample["box_semantic"])]
    return {"occ_label": labels.astype(np.uint8),
            "occ_mask_camera": masks.get("mask_camera", np.ones(target.shape, bool)).astype(np.uint8),
            "occ_flow_forward": fwd, "occ_flow_backward": bwd, "ego_to_world_transformation": ego,
            "cameras": cams, "annotations": annotations}


def camera_list(store: Store, seq: str, token: str) -> list[dict]:
    """UniOcc's camera list of a frame: name, image file (as export mmdet3d-infos names it),
    intrinsics, camera -> LiDAR."""
    sensors = SensorStore(store)
    out = []
    for cam in sensors.cameras(seq):
        a = sensors.attrs(seq, cam, "depth")
        out.append({"name": cam, "filename": f"samples/{cam}/{token}.jpg",
                    "intrinsics": np.asarray(a["intrinsics"], np.float64),
                    "extrinsics": np.asarray(a["camera_to_lidar"], np.float64)})
    return out


FORMATS = (
    ExportFormat("openocc-v2", "<seq>/<token>/labels.npz: semantics, instances, flow vx vy m/s, ego frame 0.4 m",
                 write_flow),
    ExportFormat("uniocc", "scene_infos.pkl, <seq>/<frame>.npz: occ_label, occ_mask_camera, occ_flow_forward / "
                 "backward in voxels, ego pose, cameras, annotations", write_flow),
)
