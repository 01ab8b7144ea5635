"""The quality stage (map): the dataset-quality scores and class statistics of a run of
consecutive frames of one (sequence, voxel size) per task -- spatial continuity per frame and
class, temporal consistency per frame pair (paper 4.2), and voxels and instance ids per class --
into ``metrics/quality/<seq>/<voxel_size>/<first>.parquet``, ``metrics/quality_classes/...`` and
``metrics/statistics_frames/...``. A task scores ``quality.frames_per_task`` frames and reads the
next task's first frame for its last pair, so no task grows with the sequence; the aggregate
stage sums the counts per sequence (:mod:`carlaocc.pipeline.tasks.aggregate`).
"""

from __future__ import annotations

import numpy as np

from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.store import Store, StoreError
from carlaocc.pipeline.engine.spec import Context, Partition, Prepared, StageSpec
from carlaocc.pipeline.tasks.partitions import sequences
from carlaocc.schemas.configs import QualityConfig
from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.records import ClassQualityRecord, FrameRecord, FrameStatisticsRecord, QualityRecord
from carlaocc.stages.quality import continuity_and_ranges, temporal_consistency_counts
from carlaocc.stages.quality.blocks import BitGrid, BlockedGrid
from carlaocc.stages.quality.statistics import N_CLASSES, block_pairs, split_pairs
from carlaocc.stages.scratch import scratch

FRAME_TABLES = (QualityRecord, ClassQualityRecord, FrameStatisticsRecord)  # one file of each per task


def frame_blocks(frame_count: int, frames_per_task: int) -> list[tuple[int, int]]:
    """``[first, stop)`` frame ranges of the quality tasks of a sequence."""
    return [(t, min(t + frames_per_task, frame_count)) for t in range(0, frame_count, frames_per_task)]


def quality_partitions(ctx: Context) -> list[Partition]:
    out = []
    vcfg, per_task = ctx.config.voxelize, ctx.config.quality.frames_per_task
    for seq in sequences(ctx):
        for voxel_size in ctx.voxel_sizes:
            grid = vcfg.grid(voxel_size)
            for first, stop in frame_blocks(seq.frame_count, per_task):
                # its frames' occupancy, the next one's (the last pair), and the town's scenes
                # partition (the frames' LiDAR poses)
                reads = range(first, min(stop + 1, seq.frame_count))
                needs = tuple(("voxelize", f"{seq.sequence_id}/{grid.key}/{t:04d}") for t in reads)
                out.append(Partition(
                    f"{seq.sequence_id}/{grid.key}/{first:04d}",
                    {"sequence_id": seq.sequence_id, "voxel_size": voxel_size, "grid": grid.model_dump(mode="json"),
                     "first": first, "stop": stop},
                    needs=needs + (("scenes", seq.town),),
                ))
    return out


def _quality_prepare(ctx: Context, to_run: list[Partition], partitions: list[Partition]) -> Prepared:
    """Remove the per-task files of the (sequence, voxel size) groups about to be scored that no
    partition owns any more (another ``frames_per_task``, fewer frames) and the whole-sequence
    files an earlier layout wrote there, so the tables hold each frame's rows once; the runner
    retires the lineage of the partitions that recorded them."""
    groups = {f"{p.params['sequence_id']}/{GridSpec.model_validate(p.params['grid']).key}" for p in to_run}
    owned = {p.key for p in partitions}
    removed = set()
    for model in FRAME_TABLES:
        table = ParquetTable(ctx.store, model)
        for group in sorted(groups):
            for rel in ctx.store.glob(f"{table.dir}/{group}", ".parquet"):
                if rel[len(table.dir) + 1:-len(".parquet")] not in owned:
                    ctx.store.remove(rel)
                    removed.add(rel)
    # an earlier layout's whole-sequence class rows (the sequence rows of quality/ are the
    # aggregate stage's)
    legacy = ParquetTable(ctx.store, ClassQualityRecord)
    for group in sorted(groups):
        if legacy.exists(group):
            ctx.store.remove(legacy.path(group))
            removed.add(legacy.path(group))
    return Prepared(removed=frozenset(removed))


def _frame_statistics(occ: OccupancyStore, seq_id: str, grid: GridSpec, t: int, sem: BlockedGrid,
                      ranges: tuple[np.ndarray, np.ndarray], occupied: np.ndarray,
                      with_instances: bool) -> tuple[np.ndarray, np.ndarray]:
    """Voxels per class and the (instance, class) pair keys of frame ``t``: the voxels from the
    continuity counts (``occupied``, per class id), the pairs from the frame's stored instance
    chunks only (an instance chunk that is not stored is all zero: most of a frame, and never
    decoded), each read with its block of ``sem`` within the columns' occupied ``ranges``."""

    if occupied[N_CLASSES:].any():
        bad = N_CLASSES + int(np.flatnonzero(occupied[N_CLASSES:])[0])
        raise ValueError(f"frame {t} of {seq_id} holds class id {bad}, outside the taxonomy's 0..{N_CLASSES - 1}")
    voxels = occupied[:N_CLASSES].astype(np.int64)
    X, Y, Z = sem.shape
    voxels[0] = X * Y * Z - int(occupied[1:].sum())
    found = [np.zeros(0, np.uint64)]
    if with_instances:
        cx, cy = occ.chunk_edges(seq_id, grid, "instance")
        if (cx, cy) != sem.block:
            raise StoreError(f"{seq_id} at {grid.voxel_size} m: instance chunks of {cx} x {cy} voxels, "
                             f"semantic chunks of {sem.block}: re-run voxelize")
        lo, hi = ranges
        for ci in range(sem.blocks.shape[0]):
            for cj in range(sem.blocks.shape[1]):
                # the stored chunk, decoded into a reused buffer and read at once
                inst = occ.read_chunk(seq_id, grid, t, "instance", ci, cj, scratch=True)
                if inst is not None:
                    bx, by = inst.shape[:2]
                    cols = np.s_[ci * cx:ci * cx + bx, cj * cy:cj * cy + by]
                    found.append(block_pairs(sem.blocks[ci, cj, :bx, :by], inst, lo[cols], hi[cols]))
    return voxels, np.unique(np.concatenate(found))


def _frame_buffer(name: str, shape: tuple[int, int, int], block: tuple[int, int]) -> BlockedGrid:
    """A uint8 block-major frame buffer of the calling thread (:func:`carlaocc.stages.scratch.scratch`,
    contents left from its last use: :meth:`OccupancyStore.read_blocks` writes every block)."""

    X, Y, Z = shape
    layout = (-(-X // block[0]), -(-Y // block[1]), block[0], block[1], Z)
    return BlockedGrid(scratch(name, int(np.prod(layout)), np.uint8).reshape(layout), shape)


def quality_task(store: Store, cfg: QualityConfig, part: Partition) -> dict[str, str]:
    """Spatial continuity per frame and class, temporal consistency per frame pair, and voxels
    and instances per class per frame, of frames ``[first, stop)`` of one sequence.

    Temporal consistency warps each frame t+1 into frame t with the frames' LiDAR poses (the grids
    are in the LiDAR frame; ``scenes/frames``): the pair (t, t+1) is this task's for t in
    ``[first, stop)`` (frame ``stop`` is read for the last one). Its visibility mask is
    ``mask_camera | mask_lidar`` (observed by any sensor of the rig), read as voxelize kept it in
    bits (``observed_bits``), or from whichever of the two masks the sequence has without them;
    no mask when it has neither."""

    seq_id, voxel_size = part.params["sequence_id"], part.params["voxel_size"]
    first, stop = part.params["first"], part.params["stop"]
    grid = GridSpec.model_validate(part.params["grid"])
    occ = OccupancyStore(store)
    arr = occ.open(seq_id, grid, "semantic")
    n_frames = arr.shape[0]
    last = min(stop + 1, n_frames)  # one past the last frame read
    # LiDAR-to-world pose of every frame read
    poses = {f.frame_index: np.asarray(f.lidar_pose, dtype=np.float64).reshape(4, 4)
             for f in ParquetTable(store, FrameRecord).load([seq_id]) if first <= f.frame_index < last}
    missing = [t for t in range(first, last) if t not in poses]
    if missing and n_frames > 1:
        raise StoreError(f"sequence {seq_id}: no LiDAR pose for frame(s) {missing[:5]} in scenes/frames; "
                         f"re-run the scenes stage")
    # visibility: the masks' union as voxelize kept it in bits (one eighth of a mask's bytes to
    # decode); a root voxelized without it (an older voxelize) gives its masks, OR-ed here
    bits = occ.exists(seq_id, grid, "observed_bits")
    masks = [] if bits else [n for n in ("mask_camera", "mask_lidar") if occ.exists(seq_id, grid, n)]
    with_instances = occ.exists(seq_id, grid, "instance")
    shape = tuple(arr.shape[1:])
    # two block-major buffers per array (frames t - 1 and t are held; t + 1 goes where t - 1
    # was), each chunk decoded straight into its block; the worker thread keeps them for its
    # next task (first touches of fresh pages cost more than the decoding)
    buffers = {name: [_frame_buffer(f"quality.{name}.{slot}", shape, occ.chunk_edges(seq_id, grid, name))
                      for slot in range(2)] for name in ("semantic", *masks)}

    bit_buffers = [BitGrid(scratch(f"quality.observed_bits.{slot}", int(np.prod(layout)), np.uint8).reshape(layout),
                           shape)
                   for slot in range(2)
                   for layout in [occ.block_layout(seq_id, grid, "observed_bits")]] if bits else []
    range_buffers = [tuple(scratch(f"quality.{end}.{slot}", shape[0] * shape[1], np.int32).reshape(shape[:2])
                           for end in ("lo", "hi")) for slot in range(2)]

    def read(name: str, t: int) -> BlockedGrid:
        grid_t = buffers[name][t % 2]
        occ.read_blocks(seq_id, grid, t, name, out=grid_t.blocks)
        return grid_t

    def observed(t: int) -> BitGrid | tuple[BlockedGrid, ...] | None:
        if bits:  # observed by any sensor, as bits
            grid_t = bit_buffers[t % 2]
            occ.read_blocks(seq_id, grid, t, "observed_bits", out=grid_t.blocks)
            return grid_t
        # the stored masks are uint8 0/1; the scores OR them (observed by any sensor)
        return tuple(read(name, t) for name in masks) or None

    quality: list[QualityRecord] = []
    classes: list[ClassQualityRecord] = []
    statistics: list[FrameStatisticsRecord] = []
    prev = None  # (semantic, observed mask, column ranges) of frame t - 1
    for t in range(first, last):
        sem = read("semantic", t)
        # the frame's continuity counts and its columns' occupied z ranges, in one pass
        counts, ranges = continuity_and_ranges(sem, out=range_buffers[t % 2])
        if t < stop:
            # 1. spatial continuity of the frame, per class
            occupied, isolated = int(counts.occupied[1:].sum()), int(counts.isolated[1:].sum())
            quality.append(QualityRecord(sequence_id=seq_id, voxel_size=voxel_size, frame_index=t,
                                         metric="spatial_continuity", value=counts.score, occupied=occupied,
                                         isolated=isolated, numerator=occupied - isolated, denominator=occupied))
            classes += [ClassQualityRecord(sequence_id=seq_id, voxel_size=voxel_size, frame_index=t, semantic_id=int(c),
                                           occupied=int(counts.occupied[c]), isolated=int(counts.isolated[c]))
                        for c in np.flatnonzero(counts.occupied)]
            # 2. voxels and instances per class
            voxels, pairs = _frame_statistics(occ, seq_id, grid, t, sem, ranges, counts.occupied, with_instances)
            ids, cls = split_pairs(pairs)
            statistics += [FrameStatisticsRecord(sequence_id=seq_id, voxel_size=voxel_size, frame_index=t,
                                                 semantic_id=int(c), voxels=int(voxels[c]),
                                                 instance_ids=ids[cls == c].astype(np.int64).tolist())
                           for c in range(len(voxels)) if voxels[c] or (cls == c).any()]
        if n_frames < 2:
            continue
        # 3. temporal consistency of the pair (t - 1, t): frame t warped into frame t - 1; each
        #    frame's mask and column ranges serve both pairs it belongs to
        cur = (sem, observed(t), ranges)
        if prev is not None:
            tc = temporal_consistency_counts(prev[0], sem, poses[t - 1], poses[t], grid.voxel_size, grid.origin,
                                             mask_t=prev[1], mask_t1=cur[1], ranges_t=prev[2], ranges_t1=cur[2])
            quality.append(QualityRecord(sequence_id=seq_id, voxel_size=voxel_size, frame_index=t - 1,
                                         metric="temporal_consistency", value=tc.score,
                                         numerator=tc.total_intersection, denominator=tc.total_union))
        prev = cur
    key = part.key
    out = {}
    for model, rows in ((QualityRecord, quality), (ClassQualityRecord, classes), (FrameStatisticsRecord, statistics)):
        table = ParquetTable(store, model)
        out[table.path(key)] = table.save(key, rows)
    return out


SPEC = StageSpec(
    name="quality",
    description="spatial continuity per frame and class, temporal consistency per frame pair, voxels and "
                "instances per class per frame (runs of frames_per_task frames per task)",
    upstream=("voxelize", "scenes"),
    reads=("occupancy.zarr/", "scenes/frames/"),
    writes=("metrics/quality/<seq>/<voxel_size>/", "metrics/quality_classes/<seq>/<voxel_size>/",
            "metrics/statistics_frames/<seq>/<voxel_size>/"),
    partitions=quality_partitions,
    task=quality_task,
    prepare=_quality_prepare,
)
