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
* ``sscbench-kitti360``: ``preprocess/labels/<sequence>/<frame:06d>_1_1.npy`` (256 x 256 x 32
  uint8, SSCBench-KITTI-360 learning ids 0-18, voxels observed by neither the LiDAR nor a camera
  255) and ``_1_8.npy`` (32 x 32 x 4: blocks of 8 mostly empty or unobserved take the more
  frequent of 0 / 255, the others their most frequent class), the same forward grid as
  semantickitti; ``data_2d_raw/<sequence>/image_00/data_rect/<frame:06d>.png`` the first camera.
* ``surroundocc``: ``<sequence>/<frame:06d>.npy`` -- sparse (x, y, z, label) rows of the
  200 x 200 x 16 grid at 0.5 m (LiDAR frame, [-50, -50, -5, 50, 50, 3] m), Occ3D/nuScenes
  class ids 0-16.
* ``carlaocc-npz``: ``<sequence>/<frame:06d>.npz`` -- our own grid at ``--res``, rows
  (x, y, z, label) with the label ``semantic << 11 | instance`` as the release's code writes and
  reads it (``--label-encoding decimal``: ``semantic * 1000 + instance``, the release's
  documentation), instance ids stable across the sequence and unique within a class (placed
  objects 1..999, moving ones ``1000 + id % 1000``, renumbered in id order where those would
  collide; ``<sequence>/instances.json`` maps ``"class:id"`` back to ours). More instances than the
  encoding holds is refused (clear error) rather than wrapped.
* ``carlaocc-release``: the official CarlaOcc release's folder layout
  (:mod:`carlaocc.pipeline.export_release`).
* ``mmdet3d-infos``: per-sample info files (pickle and JSON) of the OpenMMLab occupancy
  pipelines, with images, LiDAR sweeps and Occ3D ground truth as files
  (:mod:`carlaocc.pipeline.export_infos`).
* ``openocc-v2`` / ``uniocc``: semantics, instances and flow in those layouts and units
  (:mod:`carlaocc.pipeline.export_flow`).
* ``det-gt``: the ground-truth boxes in the nuScenes detection result layout, for
  ``carlaocc eval det`` (:mod:`carlaocc.pipeline.export_detgt`).

Every export writes ``grid.json``: the grid its files index (frame, origin, voxel size, shape,
axis order, label names and free label, the label table it was built under) and the formula
``centre = origin + (index + 0.5) * voxel_size``.

Every export writes ``splits/{train,val,test}.txt`` beside its files: the dataset's splits
(``<root>/splits/``) restricted to the exported sequences, one sequence id per line (the release
layout: one frame per line, in its own numbering).

The grids of the other datasets are filled from ours by class-priority binning
(:func:`carlaocc.stages.export.resample.resample`); export from the finest resolution you built.
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
from carlaocc.schemas import taxonomy
from carlaocc.schemas.configs import DatasetConfig
from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.records import SequenceRecord
from carlaocc.stages.export.resample import OCC3D_NUSCENES, SSCBENCH_KITTI360, TargetGrid, downsample_ssc, resample

FORMATS: tuple[str, ...] = ("occ3d", "semantickitti", "sscbench-kitti360", "surroundocc", "carlaocc-npz",
                             "carlaocc-release", "mmdet3d-infos", "openocc-v2", "uniocc", "det-gt")

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


def _write_image_00(store: Store, seq: str, frame: int, folder: Path) -> int:
    """The rig's first camera's RGB as KITTI-360's ``image_00/data_rect/<frame:06d>.png`` (ours are
    1408 x 376 like KITTI-360's); 0 files when the frame has no RGB."""
    import io

    from PIL import Image

    from carlaocc.catalog.sensors import SensorStore

    sensors = SensorStore(store)
    cams = sensors.cameras(seq)
    if not cams or not sensors.exists(seq, cams[0], "rgb"):
        return 0
    buf = io.BytesIO()
    Image.fromarray(sensors.read_image(seq, cams[0], frame, "rgb")).save(buf, format="PNG")
    atomic_write(folder / f"{frame:06d}.png", lambda fh, b=buf.getvalue(): fh.write(b))
    return 1


def actor_ids(store: Store, seq: str) -> set[int]:
    """Instance ids of the sequence's simulated actors (the actors table)."""
    from carlaocc.schemas.records import ActorStateRecord

    t = ParquetTable(store, ActorStateRecord)
    return set(t.load_arrow([seq])["instance_id"].to_pylist()) if t.exists(seq) else set()


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
           sequences: list[str] | None = None, progress: Callable[[int], None] | None = None,
           encoding: str = "bits") -> ExportSummary:
    """Write every frame of every voxelized sequence (or ``sequences``) at ``resolution`` in
    ``fmt`` under ``out`` (CarlaOcc labels in ``encoding``: ``bits`` or ``decimal``). Files are
    written atomically, one frame at a time."""
    from carlaocc.catalog.formats import (
        Occ3DFrame,
        SemanticKittiVoxels,
        dense_to_surroundocc,
        save_carlaocc_npz,
        save_occ3d,
        save_semantickitti,
        save_surroundocc,
        to_raw,
    )
    from carlaocc.catalog.formats.carlaocc_release import instance_lookup
    from carlaocc.catalog.formats.carlaocc_release import remap_instances as remap_release
    from carlaocc.catalog.splits import SPLIT_NAMES

    if fmt not in FORMATS:
        raise ValueError(f"unknown format {fmt!r}; formats: {', '.join(FORMATS)}")
    from carlaocc.catalog.formats.carlaocc_npz import check_encoding

    check_encoding(encoding)
    if fmt == "carlaocc-release":
        from carlaocc.pipeline.export_release import export_release

        n_seq, n_frames, n_files = export_release(store, config, out, resolution, sequences, progress, encoding)
        return ExportSummary(fmt, n_seq, n_frames, n_files, out)
    if fmt == "mmdet3d-infos":
        from carlaocc.pipeline.export_infos import export_infos

        n_seq, n_frames, n_files = export_infos(store, config, out, resolution, sequences, progress)
        return ExportSummary(fmt, n_seq, n_frames, n_files, out)
    if fmt == "det-gt":
        from carlaocc.pipeline.export_detgt import export_det_gt

        n_seq, n_frames, n_files = export_det_gt(store, config, out, resolution, sequences, progress)
        return ExportSummary(fmt, n_seq, n_frames, n_files, out)
    if fmt in ("openocc-v2", "uniocc"):
        from carlaocc.pipeline.export_flow import export_flow

        n_seq, n_frames, n_files = export_flow(store, config, fmt, out, resolution, sequences, progress)
        return ExportSummary(fmt, n_seq, n_frames, n_files, out)
    from carlaocc.schemas.grid import resolution_key

    occ = OccupancyStore(store)
    n_seq = n_frames = n_files = 0
    todo = list(voxelized_sequences(store, resolution, sequences))
    if not todo:
        key = resolution_key(resolution)
        raise StoreError(f"no voxelized sequence at {key} m in {store.url}: run `carlaocc run --res {key}` first")
    splits = sequence_splits(store, [s for s, _, _ in todo], required=False)
    scenes_tables = scenes_label_tables(store)
    tables = {seq: built_label_table(occ, seq, grid, scenes_tables[seq]) for seq, grid, _ in todo}
    if len(set(tables.values())) > 1:
        raise StoreError(f"the sequences to export were built under different label tables "
                         f"({', '.join(sorted(set(tables.values())))}): export them apart, or rebuild them under one "
                         f"taxonomy")
    for seq, grid, frame_count in todo:
        n_seq += 1
        # the LiDAR mount the sequence was recorded with (older arrays: the configured rig)
        lidar_to_ego = np.asarray(occ.attrs(seq, grid).get("lidar_to_ego", config.scenes.rig.lidar.sensor_to_ego()),
                                  dtype=np.float64)
        has_masks = occ.exists(seq, grid, "mask_lidar") and occ.exists(seq, grid, "mask_camera")
        if fmt == "carlaocc-npz":
            # the published id layout, stable across the sequence (a first pass collects the ids
            # frame by frame: one dense frame in memory at a time)
            table = sequence_release_ids(occ, seq, grid, frame_count, actor_ids(store, seq), encoding)
            keys, vals = instance_lookup(table)
            atomic_write(out / seq / "instances.json", lambda fh: fh.write(json.dumps(
                {"encoding": encoding, "instances": {f"{c}:{i}": v for (c, i), v in sorted(table.items())}},
                indent=1).encode()))
            for t in range(frame_count):
                data = occ.read_frame(seq, grid, t, ("semantic", "instance"))
                compact = remap_release(data["semantic"], data["instance"], keys, vals)
                save_carlaocc_npz(out / seq / f"{t:06d}.npz", data["semantic"], compact, grid.voxel_size, grid.origin,
                                  encoding)
                n_files += 1
                n_frames += 1
                if progress:
                    progress(1)
            continue
        # the target grid, and how our LiDAR frame maps into its frame
        target, to_target = {"occ3d": (OCC3D_NUSCENES, lidar_to_ego), "semantickitti": (SEMANTICKITTI_GRID, np.eye(4)),
                             "sscbench-kitti360": (SSCBENCH_KITTI360, np.eye(4)),
                             "surroundocc": (SURROUNDOCC_GRID, np.eye(4))}[fmt]
        names = ("semantic", "mask_lidar", "mask_camera") if has_masks else ("semantic",)
        # without visibility masks, "observed" = inside our region: the same for every frame
        coverage = None if has_masks or fmt == "surroundocc" else _coverage(target, grid, to_target)
        for t in range(frame_count):
            data = occ.read_frame(seq, grid, t, names)
            labels, m = resample(data["semantic"], grid, target, to_target, {k: data[k] for k in names[1:]},
                                 label_table=tables[seq])
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
            elif fmt == "sscbench-kitti360":
                # MonoScene-style targets: learning ids, voxels observed by neither sensor 255
                ssc = labels.astype(np.uint8)
                ssc[~(m["mask_lidar"] | m["mask_camera"])] = 255
                base = out / "preprocess" / "labels" / seq
                for name, arr in ((f"{t:06d}_1_1.npy", ssc), (f"{t:06d}_1_8.npy", downsample_ssc(ssc, 8))):
                    atomic_write(base / name, lambda fh, a=arr: np.save(fh, a))
                n_files += 2 + _write_image_00(store, seq, t, out / "data_2d_raw" / seq / "image_00" / "data_rect")
            else:  # surroundocc
                save_surroundocc(out / seq / f"{t:06d}.npy", dense_to_surroundocc(labels, target.free_label))
                n_files += 1
            n_frames += 1
            if progress:
                progress(1)
    # the grid the files index, and how an index becomes metres
    from carlaocc.pipeline.export_flow import grid_manifest

    if fmt == "carlaocc-npz":
        g = todo[0][1]
        manifest = {"format": fmt, "frame": "lidar (x forward, y left, z up)", "origin": list(g.origin),
                    "voxel_size": g.voxel_size, "shape": list(g.shape), "axis_order": ["x", "y", "z"],
                    "index_to_metre": "centre = origin + (index + 0.5) * voxel_size",
                    "labels": [c.name for c in taxonomy.label_table(tables[todo[0][0]]).classes], "free_label": 0,
                    "label_encoding": encoding, "built_from_label_table": tables[todo[0][0]]}
    else:
        manifest = grid_manifest(target, tables[todo[0][0]], fmt)
    atomic_write(out / "grid.json", lambda fh: fh.write(json.dumps(manifest, indent=1).encode()))
    n_files += 1
    # the dataset's splits, restricted to what was exported (none for a dataset built before splits)
    for split in SPLIT_NAMES if splits else ():
        ids = sorted(s for s, _, _ in todo if splits.get(s) == split)
        atomic_write(out / "splits" / f"{split}.txt", lambda fh, b="".join(f"{s}\n" for s in ids).encode(): fh.write(b))
        n_files += 1
    return ExportSummary(fmt, n_seq, n_frames, n_files, out)


def sequence_release_ids(occ: OccupancyStore, seq: str, grid: GridSpec, frame_count: int, moving=(),
                         encoding: str = "bits") -> dict[tuple[int, int], int]:
    """The exported instance id of every (class, instance) of a sequence's frames
    (:func:`carlaocc.catalog.formats.carlaocc_release.release_instance_ids`; ``moving``: the
    actors' ids), read one frame at a time."""
    from carlaocc.catalog.formats.carlaocc_release import release_instance_ids

    pairs: set[tuple[int, int]] = set()
    for t in range(frame_count):
        data = occ.read_frame(seq, grid, t, ("semantic", "instance"))
        nz = data["instance"] != 0
        if nz.any():
            keys = np.unique((data["semantic"][nz].astype(np.int64) << 32) | data["instance"][nz].astype(np.int64))
            pairs |= {(int(k >> 32), int(k & 0xFFFFFFFF)) for k in keys.tolist()}
    if not pairs:
        return {}
    arr = np.array(sorted(pairs), dtype=np.int64)
    try:
        return release_instance_ids(arr[:, 0], arr[:, 1], moving, encoding, seq)
    except ValueError as exc:
        raise StoreError(str(exc)) from None


def sequence_splits(store: Store, sequences: list[str], required: bool = True) -> dict[str, str]:
    """The dataset's split of each of ``sequences``; StoreError when one is in none (the splits
    were written before it existed: re-run). Not ``required``: ``{}`` for a dataset built before
    splits existed."""
    from carlaocc.catalog.splits import SplitStore

    if not required and not SplitStore(store).exists():
        return {}
    splits = SplitStore(store).load()
    missing = [s for s in sequences if s not in splits]
    if missing:
        raise StoreError(f"{missing[0]} is in no split of {store.url}/splits: re-run `carlaocc run` (the splits stage)")
    return {s: splits[s] for s in sequences}


def built_label_table(occ: OccupancyStore, seq: str, grid: GridSpec, scenes_table: str) -> str:
    """The label table a sequence's arrays were built under (arrays from before the table was
    recorded: ``carlaocc-v1``); StoreError when it is not ``scenes_table``, the one its town's
    scenes (instance ids) were last built under: a dataset never mixes two tables."""
    built = occ.attrs(seq, grid).get("label_table") or "carlaocc-v1"
    if built != scenes_table:
        raise StoreError(f"{seq} at {grid.key} m was voxelized under label table {built!r} but its scenes were rebuilt "
                         f"under {scenes_table!r}: re-run `carlaocc run --res {grid.key}` with that taxonomy")
    return built


def loader_and_label_table(store: Store, voxel_size: float | None, sequences: list[str] | None, **options):
    """``(dataset, sequence ids, label table)`` of the frames an export writes: a
    :class:`carlaocc.data.CarlaOccDataset` over the store (``options`` its keyword options), and
    the one label table its sequences were built under (StoreError for no frames or two tables)."""
    from carlaocc.data import CarlaOccDataset, DatasetError

    try:
        ds = CarlaOccDataset(store.url, voxel_size=voxel_size, occupancy="none", sequences=sequences, **options)
    except DatasetError as exc:
        raise StoreError(str(exc)) from None
    occ = OccupancyStore(store)
    seqs = sorted({s for s, _ in ds.samples})
    scenes_tables = scenes_label_tables(store)
    tables = {built_label_table(occ, s, ds._grids[s], scenes_tables[s]) for s in seqs}
    if len(tables) > 1:
        raise StoreError(f"the sequences were built under different label tables ({', '.join(sorted(tables))}): "
                         "export them apart")
    return ds, seqs, next(iter(tables))


def scenes_label_tables(store: Store) -> dict[str, str]:
    """``{sequence id: label table}``: the table each sequence's town was built under."""
    from carlaocc.schemas.records import TownRecord

    towns = {t.town: t.label_table for t in ParquetTable(store, TownRecord).load()}
    return {s.sequence_id: towns.get(s.town, "carlaocc-v1") for s in ParquetTable(store, SequenceRecord).load()}


def frame_count(store: Store, config: DatasetConfig, resolution: float, sequences: list[str] | None) -> int:
    """Frames an export would write (for a progress bar)."""
    return sum(n for _, _, n in voxelized_sequences(store, resolution, sequences))
