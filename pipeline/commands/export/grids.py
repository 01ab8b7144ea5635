"""Ours resampled onto other datasets' grids by class priority
(:func:`carlaocc.stages.export.resample.resample`; export from the finest voxel size built):

* ``occ3d``: ``gts/<sequence>/<token>/labels.npz``, ``token`` = ``<sequence>_<frame:06d>`` (the
  token of ``mmdet3d-infos``, ``openocc-v2`` and ``det-gt``, so their trees score against each
  other) -- Occ3D-nuScenes grid (200 x 200 x 16,
  0.4 m, ego frame, range [-40, -40, -1, 40, 40, 5.4] m), Occ3D labels (free = 17), with
  ``mask_lidar`` and ``mask_camera`` resampled from ours (observed when any observed voxel of ours
  falls in the target voxel).
* ``semantickitti``: ``sequences/<sequence>/voxels/<frame:06d>.{bin,label,invalid,occluded}`` --
  256 x 256 x 32 at 0.2 m, LiDAR frame, forward only (x [0, 51.2], y [-25.6, 25.6], z [-2, 4.4]);
  raw SemanticKITTI label ids (``learning_map_inv``); ``.occluded`` = not observed by the LiDAR,
  ``.invalid`` = observed by neither the LiDAR nor a camera.
* ``sscbench-kitti360``: ``preprocess/labels/<sequence>/<frame:06d>_1_1.npy`` (256 x 256 x 32
  uint8, SSCBench-KITTI-360 learning ids 0-18, voxels observed by neither the LiDAR nor a camera
  255) and ``_1_8.npy`` (32 x 32 x 4: blocks of 8 mostly empty or unobserved take the more
  frequent of 0 / 255, the others their most frequent class), the same forward grid as
  semantickitti; ``data_2d_raw/<sequence>/image_00/data_rect/<frame:06d>.png`` the first camera.
* ``surroundocc``: ``<sequence>/<frame:06d>.npy`` -- sparse (x, y, z, label) rows of the
  200 x 200 x 16 grid at 0.5 m (LiDAR frame, [-50, -50, -5, 50, 50, 3] m), Occ3D/nuScenes
  class ids 0-16.

Our built region rarely covers the target grid (the default region, 51.2 m forward and 25.6 m
back and to the sides, covers about half of Occ3D's 80 x 80 m; ``voxelize.region: occ3d`` covers
it all): ``grid.json`` states ``built_region`` (in the target frame) and ``coverage`` (the share
of target voxels whose centre lies inside it), and the voxels outside it are marked unobserved
in every mask the format has (Occ3D's masks 0; SemanticKITTI ``.invalid`` and ``.occluded`` set;
SSCBench 255, its ignore label). Without visibility masks (``voxelize.masks: false``) every
target voxel inside our region counts as observed, the others as not.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from PIL import Image

from carlaocc.catalog.formats import (Occ3DFrame, SemanticKittiVoxels, atomic_write, dense_to_surroundocc, save_occ3d,
                                      save_semantickitti, save_surroundocc, to_raw)
from carlaocc.catalog.formats.manifest import grid_manifest, save_grid_manifest
from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.sensors import SensorStore
from carlaocc.catalog.store import Store
from carlaocc.pipeline.commands.export.spec import (Coverage, ExportFormat, ExportJob, save_sequence_splits,
                                                    voxelized_export)
from carlaocc.schemas import taxonomy
from carlaocc.stages.export.resample import (OCC3D_NUSCENES, SEMANTICKITTI_GRID, SSCBENCH_KITTI360, SURROUNDOCC_GRID,
                                               TargetGrid, downsample_ssc, resample)


def target_manifest(target: TargetGrid, label_table: str, fmt: str, notes: dict | None = None) -> dict:
    """The ``grid.json`` of an export onto ``target``."""
    grid = {"origin": target.range_min, "voxel_size": target.voxel_size, "shape": target.shape}
    return grid_manifest(fmt, target.frame, [grid], taxonomy.TARGETS[target.taxonomy], target.free_label,
                         label_table, notes=notes)


def write_image_00(store: Store, seq: str, frame: int, folder: Path) -> int:
    """The rig's first camera's RGB as KITTI-360's ``image_00/data_rect/<frame:06d>.png`` (ours are
    1408 x 376 like KITTI-360's); 0 files when the frame has no RGB."""
    sensors = SensorStore(store)
    cams = sensors.cameras(seq)
    if not cams or not sensors.exists(seq, cams[0], "rgb"):
        return 0
    buf = io.BytesIO()
    Image.fromarray(sensors.read_image(seq, cams[0], frame, "rgb")).save(buf, format="PNG")
    atomic_write(folder / f"{frame:06d}.png", lambda fh: fh.write(buf.getvalue()))
    return 1


def write_resampled(job: ExportJob) -> tuple[int, int, int]:
    """Every frame of every voxelized sequence resampled onto the format's grid."""
    fmt, out, store = job.format, job.out, job.store
    target = TARGETS[fmt]
    todo, splits, label_table = voxelized_export(job)
    occ = OccupancyStore(store)
    cover = Coverage(target, fmt)
    n_frames = n_files = 0
    for seq, grid, frame_count in todo:
        # the target grid's frame: Occ3D's is the ego (the LiDAR mount the sequence was recorded
        # with; older arrays: the configured rig), the others are the LiDAR's
        lidar_to_ego = np.asarray(occ.attrs(seq, grid).get("lidar_to_ego", job.config.scenes.rig.lidar.sensor_to_ego()),
                                  dtype=np.float64)
        to_target = lidar_to_ego if fmt == "occ3d" else np.eye(4)
        has_masks = occ.exists(seq, grid, "mask_lidar") and occ.exists(seq, grid, "mask_camera")
        names = ("semantic", "mask_lidar", "mask_camera") if has_masks else ("semantic",)
        # outside our region nothing is observed; without visibility masks, "observed" = inside it
        inside = cover.inside(seq, grid, to_target)
        for t in range(frame_count):
            data = occ.read_frame(seq, grid, t, names)
            labels, m = resample(data["semantic"], grid, target, to_target, {k: data[k] for k in names[1:]},
                                 label_table=label_table)
            m = {k: (m[k].astype(bool) & inside) if has_masks else inside for k in ("mask_lidar", "mask_camera")}
            n_files += WRITERS[fmt](store, out, seq, t, labels, m, target)
            n_frames += 1
            job.advance()
    n_files += save_grid_manifest(out, target_manifest(target, label_table, fmt, cover.notes()))
    n_files += save_sequence_splits(out, [s for s, _, _ in todo], splits)
    return len(todo), n_frames, n_files


def _occ3d(store, out, seq, t, labels, m, target) -> int:
    frame = Occ3DFrame(labels, m["mask_lidar"].astype(np.uint8), m["mask_camera"].astype(np.uint8))
    save_occ3d(out / "gts" / seq / f"{seq}_{t:06d}" / "labels.npz", frame)
    return 1


def _semantickitti(store, out, seq, t, labels, m, target) -> int:
    lidar_seen = m["mask_lidar"]
    vox = SemanticKittiVoxels(occupied=labels != 0, invalid=~(lidar_seen | m["mask_camera"]), occluded=~lidar_seen,
                              labels=to_raw(labels))
    save_semantickitti(out / "sequences" / seq / "voxels", f"{t:06d}", vox)
    return 4


def _sscbench(store, out, seq, t, labels, m, target) -> int:
    # MonoScene-style targets: learning ids, voxels observed by neither sensor 255
    ssc = labels.astype(np.uint8)
    ssc[~(m["mask_lidar"] | m["mask_camera"])] = 255
    base = out / "preprocess" / "labels" / seq
    for name, arr in ((f"{t:06d}_1_1.npy", ssc), (f"{t:06d}_1_8.npy", downsample_ssc(ssc, 8))):
        atomic_write(base / name, lambda fh, a=arr: np.save(fh, a))
    return 2 + write_image_00(store, seq, t, out / "data_2d_raw" / seq / "image_00" / "data_rect")


def _surroundocc(store, out, seq, t, labels, m, target) -> int:
    save_surroundocc(out / seq / f"{t:06d}.npy", dense_to_surroundocc(labels, target.free_label))
    return 1


TARGETS = {"occ3d": OCC3D_NUSCENES, "semantickitti": SEMANTICKITTI_GRID, "sscbench-kitti360": SSCBENCH_KITTI360,
           "surroundocc": SURROUNDOCC_GRID}
WRITERS = {"occ3d": _occ3d, "semantickitti": _semantickitti, "sscbench-kitti360": _sscbench,
           "surroundocc": _surroundocc}

FORMATS = (
    ExportFormat("occ3d", "gts/<seq>/<seq>_<frame>/labels.npz: 200x200x16 at 0.4 m, ego frame, free 17, masks",
                 write_resampled),
    ExportFormat("semantickitti", "sequences/<seq>/voxels/<frame>.bin/.label/.invalid/.occluded: 256x256x32 at "
                 "0.2 m, forward", write_resampled),
    ExportFormat("sscbench-kitti360", "preprocess/labels/<seq>/<frame>_1_1.npy and _1_8.npy (KITTI-360 ids, "
                 "unobserved 255), data_2d_raw/<seq>/image_00/data_rect/<frame>.png", write_resampled),
    ExportFormat("surroundocc", "<seq>/<frame>.npy: sparse rows of 200x200x16 at 0.5 m", write_resampled),
)
