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

import io
import json
import pickle
from collections.abc import Callable
from pathlib import Path

import numpy as np

from carlaocc.catalog.formats import atomic_write
from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.store import Store, StoreError
from carlaocc.schemas import taxonomy
from carlaocc.schemas.configs import DatasetConfig
from carlaocc.stages.export.resample import TargetGrid, resample, resample_panoptic

OPENOCC_V2 = TargetGrid("openocc-v2", (200, 200, 16), 0.4, (-40.0, -40.0, -1.0), "ego", "openocc_v2", 16)
"""OpenOcc v2: the Occ3D grid and frame (OccNet ray_metrics / nuscenes_occ), its own class order."""
UNIOCC = TargetGrid("uniocc", (200, 200, 16), 0.4, (-40.0, -40.0, -1.0), "ego", "uniocc", 10)
"""UniOcc: 0.4 m over [-40, -40, -1, 40, 40, 5.4] m (uniocc_viz.py); we place it in the ego frame."""
GRIDS = {"openocc-v2": OPENOCC_V2, "uniocc": UNIOCC}


def grid_manifest(target: TargetGrid, label_table: str, fmt: str, notes: dict | None = None) -> dict:
    """The ``grid.json`` of an export onto ``target``."""
    return {
        "format": fmt, "frame": f"{target.frame} (x forward, y left, z up)", "origin": list(target.range_min),
        "voxel_size": target.voxel_size, "shape": list(target.shape), "axis_order": ["x", "y", "z"],
        "index_to_metre": "centre = origin + (index + 0.5) * voxel_size",
        "labels": list(taxonomy.TARGETS[target.taxonomy]), "free_label": target.free_label,
        "built_from_label_table": label_table, **(notes or {}),
    }  # fmt: skip


def voxel_centres(target: TargetGrid) -> np.ndarray:
    """(X, Y, Z, 3) float64 centres of the target grid's voxels in its frame (m)."""
    axes = [target.range_min[a] + (np.arange(target.shape[a]) + 0.5) * target.voxel_size for a in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)


def uniocc_flow(labels: np.ndarray, velocity: np.ndarray, ego_now: np.ndarray, ego_other: np.ndarray | None,
                dt: float, free: int, voxel: float) -> np.ndarray:
    """UniOcc flow (X, Y, Z, 3) float32 in voxels towards another frame (``dt`` s later, negative
    for the previous one) whose ego pose is ``ego_other`` (None: zeros). Each labelled voxel's
    centre ``p`` (current ego frame) moves with its velocity (ego axes, m/s) for ``dt``, goes to
    the world by ``ego_now`` and back into the other frame's ego frame; flow = (q - p) / voxel."""
    out = np.zeros((*labels.shape, 3), np.float32)
    if ego_other is None:
        return out
    sel = labels != free
    p = voxel_centres(UNIOCC)[sel]
    moved = p + velocity[sel].astype(np.float64) * dt
    to_other = np.linalg.inv(ego_other) @ ego_now  # current ego -> other ego
    q = moved @ to_other[:3, :3].T + to_other[:3, 3]
    out[sel] = ((q - p) / voxel).astype(np.float32)
    return out


def _npz(arrays: dict) -> bytes:
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    return buf.getvalue()


def export_flow(store: Store, config: DatasetConfig, fmt: str, out: Path, voxel_size: float,
                sequences: list[str] | None = None, progress: Callable[[int], None] | None = None) -> tuple[int, int, int]:
    """Write ``fmt`` (openocc-v2 | uniocc) for every frame built at ``voxel_size``; returns
    (sequences, frames, files)."""
    from carlaocc.catalog.splits import SPLIT_NAMES, SplitStore
    from carlaocc.pipeline.export import loader_and_label_table

    target = GRIDS[fmt]
    ds, seqs, label_table = loader_and_label_table(store, voxel_size, sequences, lidar=False, cameras=False)
    occ = OccupancyStore(store)
    cats = taxonomy.mapping("uniocc", label_table)
    n_files = 0
    scene_infos = []
    for seq in seqs:
        grid = ds._grids[seq]
        idx = [k for k, (s, _) in enumerate(ds.samples) if s == seq]
        names = tuple(n for n in ("semantic", "instance", "flow", "mask_lidar", "mask_camera") if occ.exists(seq, grid, n))
        paths = []
        samples = {k: ds[k] for k in idx} if fmt == "uniocc" else {}
        for pos, k in enumerate(idx):
            sample = samples.get(k) or ds[k]
            frame = sample["frame_index"]
            token = f"{seq}_{frame:06d}"
            data = occ.read_frame(seq, grid, frame, names)
            masks = {n: data[n] for n in ("mask_lidar", "mask_camera") if n in data}
            to_ego = sample["lidar_to_ego"]
            labels, m = resample(data["semantic"], grid, target, to_ego, masks, label_table=label_table)
            inst, flow = resample_panoptic(data["semantic"], data.get("instance", np.zeros_like(data["semantic"], np.uint32)),
                                           data.get("flow"), grid, target, to_ego, label_table=label_table)
            if flow is None:
                flow = np.zeros((*target.shape, 3), np.float32)
            if fmt == "openocc-v2":
                rel = f"{seq}/{token}/labels.npz"
                body = _npz({"semantics": labels.astype(np.uint8), "instances": inst, "flow": flow[..., :2].copy()})
            else:
                ego = sample["ego_pose"]
                prev = samples[idx[pos - 1]] if pos else None
                nxt = samples[idx[pos + 1]] if pos + 1 < len(idx) else None
                fwd = uniocc_flow(labels, flow, ego, nxt["ego_pose"] if nxt else None,
                                  (nxt["timestamp"] - sample["timestamp"]) if nxt else 0.0, target.free_label, target.voxel_size)
                bwd = uniocc_flow(labels, flow, ego, prev["ego_pose"] if prev else None,
                                  (prev["timestamp"] - sample["timestamp"]) if prev else 0.0, target.free_label, target.voxel_size)
                cams = _cameras(store, seq, token)
                world_to_ego = np.linalg.inv(ego)
                annotations = [{"token": int(i), "agent_to_ego": world_to_ego @ sample["lidar_pose"] @ p,
                                "agent_to_world": sample["lidar_pose"] @ p, "size": b[3:6].astype(np.float64),
                                "category_id": int(cats[int(c)])}
                               for b, p, i, c in zip(sample["boxes"], sample["box_pose"], sample["box_instance"],
                                                     sample["box_semantic"])]
                rel = f"{seq}/{frame}.npz"
                body = _npz({"occ_label": labels.astype(np.uint8),
                             "occ_mask_camera": m.get("mask_camera", np.ones(target.shape, bool)).astype(np.uint8),
                             "occ_flow_forward": fwd, "occ_flow_backward": bwd, "ego_to_world_transformation": ego,
                             "cameras": np.array(cams, dtype=object), "annotations": np.array(annotations, dtype=object)})
            atomic_write(out / rel, lambda fh, b=body: fh.write(b))
            paths.append(rel)
            n_files += 1
            if progress:
                progress(1)
        scene_infos.append({"scene_name": seq, "occ_in_scene_paths": paths})
    if fmt == "uniocc":
        atomic_write(out / "scene_infos.pkl", lambda fh: pickle.dump(scene_infos, fh, protocol=4))
        n_files += 1
    notes = {"flow": "flow[..., 0:2]: vx, vy along the ego axes, m/s (world motion; 0 static)"} if fmt == "openocc-v2" else {
        "flow": "occ_flow_forward/backward: (next/previous ego-grid position - current) / voxel_size, voxels"}
    atomic_write(out / "grid.json", lambda fh: fh.write(json.dumps(grid_manifest(target, label_table, fmt, notes), indent=1).encode()))
    try:
        assignment = SplitStore(store).load()
    except StoreError:
        assignment = {}
    for split in SPLIT_NAMES if assignment else ():
        ids = sorted(s for s in seqs if assignment.get(s) == split)
        atomic_write(out / "splits" / f"{split}.txt", lambda fh, b="".join(f"{s}\n" for s in ids).encode(): fh.write(b))
        n_files += 1
    return len(seqs), len(ds.samples), n_files + 1


def _cameras(store: Store, seq: str, token: str) -> list[dict]:
    """UniOcc's camera list of a frame: name, image file (as export mmdet3d-infos names it),
    intrinsics, camera -> LiDAR."""
    from carlaocc.catalog.sensors import SensorStore

    sensors = SensorStore(store)
    out = []
    for cam in sensors.cameras(seq):
        a = sensors.attrs(seq, cam, "depth")
        out.append({"name": cam, "filename": f"samples/{cam}/{token}.jpg",
                    "intrinsics": np.asarray(a["intrinsics"], np.float64),
                    "extrinsics": np.asarray(a["camera_to_lidar"], np.float64)})
    return out
