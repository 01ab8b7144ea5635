"""The aggregate stage (reduce): one task per (sequence, voxel size) sums what the quality tasks
counted per frame -- the spatial continuity and temporal consistency numerators and
denominators into the sequence's scores (``metrics/quality/<seq>/<voxel_size>.parquet``, rows with no
frame index), voxels per class and the union of instance ids per class into the sequence's class
statistics (``metrics/statistics_classes/<seq>/<voxel_size>.parquet``). It reads only those small
tables (and the sequence's actors), never occupancy: a sequence's scores are bit-identical to
scoring all its frames in one pass, because both are sums of the same integers.
"""

from __future__ import annotations

import math

import numpy as np

from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.store import Store, StoreError
from carlaocc.pipeline.engine.spec import Context, Partition, StageSpec
from carlaocc.pipeline.tasks.partitions import sequences
from carlaocc.pipeline.tasks.quality import quality_partitions
from carlaocc.schemas.configs import QualityConfig
from carlaocc.schemas.records import (ActorStateRecord, ClassQualityRecord, ClassStatisticsRecord,
                                      FrameStatisticsRecord, QualityRecord)
from carlaocc.stages.quality import pooled_continuity, pooled_temporal
from carlaocc.stages.quality.statistics import SequenceStatistics, pair_keys


def aggregate_partitions(ctx: Context) -> list[Partition]:
    groups: dict[str, list[str]] = {}
    for p in quality_partitions(ctx):
        groups.setdefault(p.key.rsplit("/", 1)[0], []).append(p.key)
    town = {s.sequence_id: s.town for s in sequences(ctx)}
    out = []
    for group, keys in groups.items():
        seq_id, voxel_size_key = group.split("/")
        params = {"sequence_id": seq_id, "voxel_size_key": voxel_size_key, "quality_keys": keys,
                  "voxel_size": next(v for v in ctx.voxel_sizes if ctx.config.voxelize.grid(v).key == voxel_size_key)}
        # the quality tasks' tables, and the scenes partition of the sequence's actors
        out.append(Partition(group, params, needs=tuple(("quality", k) for k in keys) + (("scenes", town[seq_id]),)))
    return out


def _load(store: Store, model, keys: list[str]):
    table = ParquetTable(store, model)
    missing = [k for k in keys if not table.exists(k)]
    if missing:
        raise StoreError(f"{table.path(missing[0])} is missing from {store.url}: re-run the quality stage")
    return table.load(keys)


def aggregate_task(store: Store, cfg: QualityConfig, part: Partition) -> dict[str, str]:
    """The sequence rows of the quality table and the sequence's class statistics, from the
    per-frame rows of its quality tasks."""

    seq_id, voxel_size, keys = part.params["sequence_id"], part.params["voxel_size"], part.params["quality_keys"]
    frame_rows = [r for r in _load(store, QualityRecord, keys) if r.frame_index is not None]
    cont = [r for r in frame_rows if r.metric == "spatial_continuity"]
    temp = [r for r in frame_rows if r.metric == "temporal_consistency"]
    # 1. the scores: sums of the frames' (pairs') integer counts, one definition of each score
    occupied, isolated = sum(r.occupied for r in cont), sum(r.isolated for r in cont)
    inter, union = sum(r.numerator for r in temp), sum(r.denominator for r in temp)

    def worst(rows: list[QualityRecord]) -> dict:
        # the lowest frame (pair) score and where, for the report (which reads no frame rows)
        scored = [r for r in rows if not math.isnan(r.value)]
        low = min(scored, key=lambda r: (r.value, r.frame_index), default=None)
        return {} if low is None else {"worst_value": low.value, "worst_frame": low.frame_index}

    quality = [
        QualityRecord(sequence_id=seq_id, voxel_size=voxel_size, frame_index=None, metric="spatial_continuity",
                      value=pooled_continuity(occupied, isolated), occupied=occupied, isolated=isolated,
                      numerator=occupied - isolated, denominator=occupied, **worst(cont)),
        QualityRecord(sequence_id=seq_id, voxel_size=voxel_size, frame_index=None, metric="temporal_consistency",
                      value=pooled_temporal(inter, union), numerator=inter, denominator=union, **worst(temp)),
    ]
    # the per-class counts behind the continuity score must add up to the frames' totals
    class_rows = _load(store, ClassQualityRecord, keys)
    if sum(r.occupied for r in class_rows if r.semantic_id) != occupied:
        raise StoreError(f"{seq_id} at {part.params['voxel_size_key']} m: the quality_classes rows do not add up to "
                         f"the quality rows; re-run the quality stage")
    # 2. class statistics: voxels summed, instances as the union of each frame's (id, class) pairs
    stats = SequenceStatistics()
    by_frame: dict[int, list[FrameStatisticsRecord]] = {}
    for r in _load(store, FrameStatisticsRecord, keys):
        by_frame.setdefault(r.frame_index, []).append(r)
    for t in sorted(by_frame):
        rows = by_frame[t]
        voxels = np.zeros(len(stats.voxels), np.int64)
        for r in rows:
            voxels[r.semantic_id] = r.voxels
        ids = np.concatenate([np.asarray(r.instance_ids, np.uint64) for r in rows] + [np.zeros(0, np.uint64)])
        cls = np.concatenate([np.full(len(r.instance_ids), r.semantic_id, np.uint64) for r in rows]
                             + [np.zeros(0, np.uint64)])
        stats.add_counts(voxels, pair_keys(ids, cls))
    actors = ParquetTable(store, ActorStateRecord)
    actor_ids = (np.unique(actors.load_arrow([seq_id]).column("instance_id").to_numpy())
                 if actors.exists(seq_id) else np.zeros(0, np.int64))
    inst, moving = stats.instances(), stats.instances(actor_ids.tolist())
    statistics = [ClassStatisticsRecord(sequence_id=seq_id, voxel_size=float(voxel_size), semantic_id=c,
                                        frames=stats.frames, voxels=int(stats.voxels[c]), instances=int(inst[c]),
                                        moving_instances=int(moving[c]))
                  for c in range(len(stats.voxels)) if stats.voxels[c] or inst[c]]
    out = {}
    for model, rows in ((QualityRecord, quality), (ClassStatisticsRecord, statistics)):
        table = ParquetTable(store, model)
        out[table.path(part.key)] = table.save(part.key, rows)
    return out


SPEC = StageSpec(
    name="aggregate",
    description="the quality scores and class statistics of every sequence, summed from the per-frame tables",
    upstream=("quality", "scenes"),
    reads=("metrics/quality/<seq>/<voxel_size>/", "metrics/quality_classes/<seq>/<voxel_size>/",
           "metrics/statistics_frames/<seq>/<voxel_size>/", "scenes/actors/"),
    writes=("metrics/quality/<seq>/<voxel_size>.parquet", "metrics/statistics_classes/<seq>/<voxel_size>.parquet"),
    partitions=aggregate_partitions,
    task=aggregate_task,
    config_of=lambda config: config.quality,
)
