"""The quality stage: the dataset-quality scores of one (sequence, voxel size) per task —
spatial continuity per frame, sequence and class, and temporal consistency per frame pair and
sequence (paper 4.2) — into ``metrics/quality/`` and ``metrics/quality_classes/``.
"""

from __future__ import annotations

import numpy as np

from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.store import Store, StoreError
from carlaocc.pipeline.spec import Context, Partition, StageSpec
from carlaocc.pipeline.tasks.partitions import sequences
from carlaocc.schemas.configs import QualityConfig
from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.records import ClassQualityRecord, FrameRecord, QualityRecord


def quality_partitions(ctx: Context) -> list[Partition]:
    out = []
    vcfg = ctx.config.voxelize
    for seq in sequences(ctx):
        for voxel_size in ctx.voxel_sizes:
            grid = vcfg.grid(voxel_size)
            # every frame's occupancy, and the town's scenes partition (the frames' LiDAR poses)
            needs = tuple(("voxelize", f"{seq.sequence_id}/{grid.key}/{t:04d}") for t in range(seq.frame_count))
            needs += (("scenes", seq.town),)
            out.append(Partition(
                f"{seq.sequence_id}/{grid.key}",
                {"sequence_id": seq.sequence_id, "voxel_size": voxel_size, "grid": grid.model_dump(mode="json")},
                needs=needs,
            ))
    return out


def quality_task(store: Store, cfg: QualityConfig, part: Partition) -> dict[str, str]:
    """Spatial continuity per frame and per sequence, per class counts, and temporal consistency
    per frame pair and per sequence, into metrics/.

    Temporal consistency warps each frame t+1 into frame t with the frames' LiDAR poses (the grids
    are in the LiDAR frame; ``scenes/frames``). Its visibility mask is ``mask_camera | mask_lidar``
    (observed by any sensor of the rig): whichever of the two arrays the sequence has; no mask
    when it has neither."""
    from carlaocc.stages.quality import (column_ranges, sequence_continuity, sequence_temporal, spatial_continuity_counts,
                                temporal_consistency_counts)

    seq_id, voxel_size = part.params["sequence_id"], part.params["voxel_size"]
    grid = GridSpec.model_validate(part.params["grid"])
    occ = OccupancyStore(store)
    arr = occ.open(seq_id, grid, "semantic")
    n_frames = arr.shape[0]
    # LiDAR-to-world pose of every frame
    poses = {f.frame_index: np.asarray(f.lidar_pose, dtype=np.float64).reshape(4, 4)
             for f in ParquetTable(store, FrameRecord).load([seq_id])}
    missing = [t for t in range(n_frames) if t not in poses]
    if missing and n_frames > 1:
        raise StoreError(f"sequence {seq_id}: no LiDAR pose for frame(s) {missing[:5]} in scenes/frames; "
                         f"re-run the scenes stage")
    masks = [n for n in ("mask_camera", "mask_lidar") if occ.exists(seq_id, grid, n)]

    def read(name: str, t: int) -> np.ndarray:
        return occ.read_frame(seq_id, grid, t, (name,))[name]

    def observed(t: int) -> np.ndarray | None:
        if not masks:
            return None
        # the stored masks are uint8 0/1: viewed as bool, OR-ed in place (no 0.05 m temporaries)
        out = read(masks[0], t).view(np.bool_)
        for name in masks[1:]:
            np.logical_or(out, read(name, t).view(np.bool_), out=out)
        return out

    def continuity_row(counts, t: int | None) -> QualityRecord:
        occupied, isolated = int(counts.occupied[1:].sum()), int(counts.isolated[1:].sum())
        return QualityRecord(sequence_id=seq_id, resolution=voxel_size, frame_index=t, metric="spatial_continuity",
                             value=counts.score, occupied=occupied, isolated=isolated,
                             numerator=occupied - isolated, denominator=occupied)

    def temporal_row(counts, t: int | None) -> QualityRecord:
        return QualityRecord(sequence_id=seq_id, resolution=voxel_size, frame_index=t, metric="temporal_consistency",
                             value=counts.score, numerator=counts.total_intersection,
                             denominator=counts.total_union)

    per_frame, per_pair = [], []
    quality, classes = [], []
    prev = None  # (semantic, observed mask, column ranges) of frame t - 1
    for t in range(n_frames):
        sem = read("semantic", t)
        counts = spatial_continuity_counts(sem)
        per_frame.append(counts)
        quality.append(continuity_row(counts, t))
        for c in np.flatnonzero(counts.occupied):
            classes.append(ClassQualityRecord(sequence_id=seq_id, resolution=voxel_size, frame_index=t,
                                              semantic_id=int(c), occupied=int(counts.occupied[c]),
                                              isolated=int(counts.isolated[c])))
        if n_frames < 2:
            continue
        # each frame's column ranges serve both pairs it belongs to
        cur = (sem, observed(t), column_ranges(sem))
        if prev is not None:
            # the pair (t - 1, t): frame t warped into frame t - 1
            tc = temporal_consistency_counts(prev[0], sem, poses[t - 1], poses[t], grid.voxel_size, grid.origin,
                                             mask_t=prev[1], mask_t1=cur[1], ranges_t=prev[2], ranges_t1=cur[2])
            per_pair.append(tc)
            quality.append(temporal_row(tc, t - 1))
        prev = cur
    quality.append(continuity_row(sequence_continuity(per_frame), None))
    quality.append(temporal_row(sequence_temporal(per_pair), None))
    key = f"{seq_id}/{grid.key}"
    t_q, t_c = ParquetTable(store, QualityRecord), ParquetTable(store, ClassQualityRecord)
    return {t_q.path(key): t_q.save(key, quality), t_c.path(key): t_c.save(key, classes)}


SPEC = StageSpec(
    name="quality",
    description="spatial continuity per frame, sequence and class; temporal consistency per frame pair "
                "and sequence",
    upstream=("voxelize", "scenes"),
    reads=("occupancy.zarr/", "scenes/frames/"),
    writes=("metrics/quality/", "metrics/quality_classes/"),
    partitions=quality_partitions,
    task=quality_task,
)
