"""``carlaocc export``: a dataset's occupancy in the formats models already train on.

Layouts written under ``OUT``:

* ``occ3d``: ``gts/<sequence>/<frame:06d>/labels.npz`` -- Occ3D-nuScenes grid (200 x 200 x 16,
  0.4 m, ego frame, range [-40, -40, -1, 40, 40, 5.4] m), Occ3D labels (free = 17), with
  ``mask_lidar`` and ``mask_camera`` resampled from ours (observed when any observed voxel of ours
  falls in the target voxel).
* ``semantickitti``: ``sequences/<sequence>/voxels/<frame:06d>.{bin,label,invalid,occluded}`` --
  256 x 256 x 32 at 0.2 m, LiDAR frame, forward only (x [0, 51.2], y [-25.6, 25.6], z [-2, 4.4]);
  raw SemanticKITTI label ids (``learning_map_inv``); ``.occluded`` = not observed by the LiDAR,
  ``.invalid`` = observed by neither the LiDAR nor a camera. Without masks (``voxelize.masks:
  false``) every target voxel inside our region counts as observed, the others as not.
* ``surroundocc``: ``<sequence>/<frame:06d>.npy`` -- sparse (x, y, z, label) rows of the
  200 x 200 x 16 grid at 0.5 m (LiDAR frame, [-50, -50, -5, 50, 50, 3] m), Occ3D/nuScenes
  class ids 0-16.
* ``carlaocc-npz``: ``<sequence>/<frame:06d>.npz`` -- our own grid at ``--res``, rows
  (x, y, z, sem << 11 | inst) with the published id layout, stable across the sequence: static
  things numbered 1..999 in id order, simulated actors at 1000 + (id mod 1000)
  (``<sequence>/instances.json`` maps them back). More than 999 static things, two actors equal
  modulo 1000, or a class id above 31 is refused (clear error) rather than wrapped.

The grids of the other datasets are filled from ours by class-priority binning
(:func:`carlaocc.stages.voxelize.resample.resample`); export from the finest resolution you built.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from carlaocc.catalog.formats import atomic_write
from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.store import Store, StoreError
from carlaocc.schemas.configs import DatasetConfig
from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.records import SequenceRecord
from carlaocc.stages.voxelize.resample import OCC3D_NUSCENES, SSCBENCH_KITTI360, TargetGrid, resample

FORMATS: tuple[str, ...] = ("occ3d", "semantickitti", "surroundocc", "carlaocc-npz")

SEMANTICKITTI_GRID = TargetGrid("semantickitti", SSCBENCH_KITTI360.shape, SSCBENCH_KITTI360.voxel_size,
                                SSCBENCH_KITTI360.range_min, "lidar", "semantickitti", 0)
SURROUNDOCC_GRID = TargetGrid("surroundocc", (200, 200, 16), 0.5, (-50.0, -50.0, -5.0), "lidar", "occ3d_nuscenes", 17)


@dataclass(frozen=True)
class ExportSummary:
    format: str
    sequences: int
    frames: int
    files: int
    out: Path


def _coverage(target: TargetGrid, grid: GridSpec, grid_to_target: np.ndarray) -> np.ndarray:
    """bool target.shape: target voxels whose centre lies inside our grid's region (what an
    export without visibility masks can claim as known)."""
    idx = np.indices(target.shape).reshape(3, -1).T
    centres = np.asarray(target.range_min) + (idx + 0.5) * target.voxel_size
    inv = np.linalg.inv(grid_to_target)
    p = centres @ inv[:3, :3].T + inv[:3, 3]
    inside = np.all((p >= np.asarray(grid.origin)) & (p < np.asarray(grid.effective_max)), axis=1)
    return inside.reshape(target.shape)


def _actor_ids(store: Store, seq: str) -> np.ndarray:
    """Instance ids of the sequence's simulated actors (the actors table)."""
    from carlaocc.schemas.records import ActorStateRecord

    t = ParquetTable(store, ActorStateRecord)
    if not t.exists(seq):
        return np.zeros(0, dtype=np.uint32)
    return np.unique(np.asarray(t.load_arrow([seq])["instance_id"].to_numpy(), dtype=np.uint32))


def voxelized_sequences(store: Store, voxel_size: float, sequences: list[str] | None) -> Iterator[tuple[str, GridSpec, int]]:
    """(sequence, the grid it was voxelized on at ``voxel_size``, frames) of every voxelized
    sequence (or of ``sequences``, refusing those not voxelized)."""
    from carlaocc.schemas.grid import resolution_key

    seqs = sorted(ParquetTable(store, SequenceRecord).load(), key=lambda s: s.sequence_id)
    known = {s.sequence_id for s in seqs}
    for s in sequences or []:
        if s not in known:
            raise StoreError(f"sequence {s!r} is not in {store.url}")
    occ = OccupancyStore(store)
    for s in seqs:
        if sequences and s.sequence_id not in sequences:
            continue
        grid = occ.stored_grid(s.sequence_id, voxel_size)
        if grid is None:
            if sequences:
                key = resolution_key(voxel_size)
                raise StoreError(f"{s.sequence_id} has no occupancy at {key} m: run "
                                 f"`carlaocc run --stages voxelize --res {key}` first")
            continue
        yield s.sequence_id, grid, occ.open(s.sequence_id, grid, "semantic").shape[0]


def export(store: Store, config: DatasetConfig, fmt: str, resolution: float, out: Path,
           sequences: list[str] | None = None, progress: Callable[[int], None] | None = None) -> ExportSummary:
    """Write every frame of every voxelized sequence (or ``sequences``) at ``resolution`` in
    ``fmt`` under ``out``. Files are written atomically, one frame at a time."""
    from carlaocc.catalog.formats import (
        Occ3DFrame,
        SemanticKittiVoxels,
        dense_to_surroundocc,
        published_instance_ids,
        remap_instances,
        save_carlaocc_npz,
        save_occ3d,
        save_semantickitti,
        save_surroundocc,
        to_raw,
    )

    if fmt not in FORMATS:
        raise ValueError(f"unknown format {fmt!r}; formats: {', '.join(FORMATS)}")
    from carlaocc.schemas.grid import resolution_key

    occ = OccupancyStore(store)
    n_seq = n_frames = n_files = 0
    todo = list(voxelized_sequences(store, resolution, sequences))
    if not todo:
        key = resolution_key(resolution)
        raise StoreError(f"no voxelized sequence at {key} m in {store.url}: run `carlaocc run --res {key}` first")
    for seq, grid, frame_count in todo:
        n_seq += 1
        # the LiDAR mount the sequence was recorded with (older arrays: the configured rig)
        lidar_to_ego = np.asarray(occ.attrs(seq, grid).get("lidar_to_ego", config.scenes.rig.lidar.sensor_to_ego()),
                                  dtype=np.float64)
        has_masks = occ.exists(seq, grid, "mask_lidar") and occ.exists(seq, grid, "mask_camera")
        if fmt == "carlaocc-npz":
            # the published id layout, stable across the sequence (a first pass collects the ids
            # frame by frame: one dense frame in memory at a time)
            inst, sem = occ.open(seq, grid, "instance"), occ.open(seq, grid, "semantic")
            present = [np.unique(f[f != 0]) for f in (inst[t] for t in range(frame_count))]
            ids = np.unique(np.concatenate(present)) if present else np.zeros(0, np.uint32)
            new = published_instance_ids(ids, _actor_ids(store, seq), seq)
            table = {int(o): int(n) for o, n in zip(ids.tolist(), new.tolist())}
            atomic_write(out / seq / "instances.json",
                         lambda fh: fh.write(json.dumps({str(k): v for k, v in table.items()}, indent=1).encode()))
            for t in range(frame_count):
                compact = remap_instances(inst[t], ids, new)
                save_carlaocc_npz(out / seq / f"{t:06d}.npz", sem[t], compact, grid.voxel_size, grid.origin)
                n_files += 1
                n_frames += 1
                if progress:
                    progress(1)
            continue
        # the target grid, and how our LiDAR frame maps into its frame
        target, to_target = {"occ3d": (OCC3D_NUSCENES, lidar_to_ego), "semantickitti": (SEMANTICKITTI_GRID, np.eye(4)),
                             "surroundocc": (SURROUNDOCC_GRID, np.eye(4))}[fmt]
        names = ("semantic", "mask_lidar", "mask_camera") if has_masks else ("semantic",)
        # without visibility masks, "observed" = inside our region: the same for every frame
        coverage = None if has_masks or fmt == "surroundocc" else _coverage(target, grid, to_target)
        for t in range(frame_count):
            data = occ.read_frame(seq, grid, t, names)
            labels, m = resample(data["semantic"], grid, target, to_target, {k: data[k] for k in names[1:]})
            if coverage is not None:
                m = dict.fromkeys(("mask_lidar", "mask_camera"), coverage)
            if fmt == "occ3d":
                frame = Occ3DFrame(labels, m["mask_lidar"].astype(np.uint8), m["mask_camera"].astype(np.uint8))
                save_occ3d(out / "gts" / seq / f"{t:06d}" / "labels.npz", frame)
                n_files += 1
            elif fmt == "semantickitti":
                lidar_seen = m["mask_lidar"]
                vox = SemanticKittiVoxels(occupied=labels != 0, invalid=~(lidar_seen | m["mask_camera"]),
                                          occluded=~lidar_seen, labels=to_raw(labels))
                save_semantickitti(out / "sequences" / seq / "voxels", f"{t:06d}", vox)
                n_files += 4
            else:  # surroundocc
                save_surroundocc(out / seq / f"{t:06d}.npy", dense_to_surroundocc(labels, target.free_label))
                n_files += 1
            n_frames += 1
            if progress:
                progress(1)
    return ExportSummary(fmt, n_seq, n_frames, n_files, out)


def frame_count(store: Store, config: DatasetConfig, resolution: float, sequences: list[str] | None) -> int:
    """Frames an export would write (for a progress bar)."""
    return sum(n for _, _, n in voxelized_sequences(store, resolution, sequences))
