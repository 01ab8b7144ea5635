"""Dataset statistics for the report: the ADMesh asset distribution, the static/dynamic
instance share and per-voxel-size totals of the sequences' class statistics (the paper's
statistics figure). The per-frame counts behind them are
:mod:`carlaocc.stages.quality.statistics`'s. Nothing here reads a file."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from carlaocc.schemas import taxonomy
from carlaocc.schemas.records import AssetRecord, AssetStatisticsRecord, ClassStatisticsRecord
from carlaocc.stages.quality.statistics import N_CLASSES


def asset_distribution(assets: Sequence[AssetRecord]) -> list[AssetStatisticsRecord]:
    """Assets per (source, category), sorted by category id then source. Each record counts once
    (deduplicate the library first: duplicates are aliases of one asset)."""
    counts: dict[tuple[str, int, str], int] = {}
    for a in assets:
        key = (a.source, a.category_id, a.category)
        counts[key] = counts.get(key, 0) + 1
    return [AssetStatisticsRecord(source=s, category_id=cid, category=c, assets=n)
            for (s, cid, c), n in sorted(counts.items(), key=lambda kv: (kv[0][1], kv[0][0]))]


@dataclass(frozen=True)
class MotionShare:
    """Instances and voxels split by motion.

    ``moving_instances`` / ``static_instances``: per class, the instances that are dynamic actors
    of their sequence (they have actor states) and the others (placed objects: buildings, parked
    cars...). ``dynamic_voxels`` / ``static_voxels``: voxels of the classes the taxonomy marks
    dynamic (the road users) and static (everything else occupied).
    """

    moving_instances: np.ndarray  # (N_CLASSES,)
    static_instances: np.ndarray  # (N_CLASSES,)
    dynamic_voxels: int
    static_voxels: int

    @property
    def moving_fraction(self) -> float:
        """Share of instances that are dynamic actors (NaN without instances)."""
        total = int(self.moving_instances.sum() + self.static_instances.sum())
        return float(self.moving_instances.sum()) / total if total else float("nan")


def motion_share(voxels: np.ndarray, instances: np.ndarray, moving: np.ndarray) -> MotionShare:
    """Split per-class counts (``(N_CLASSES,)`` each: voxels, instances, instances that are
    actors) by motion; ValueError if an actor count exceeds its class's instances."""
    voxels, instances, moving = (np.asarray(a, dtype=np.int64) for a in (voxels, instances, moving))
    for name, a in (("voxels", voxels), ("instances", instances), ("moving", moving)):
        if a.shape != (N_CLASSES,):
            raise ValueError(f"{name} must have shape ({N_CLASSES},), got {a.shape}")
    if (moving > instances).any():
        c = int(np.flatnonzero(moving > instances)[0])
        raise ValueError(f"class {taxonomy.by_id(c).name}: {moving[c]} moving instances > {instances[c]} instances")
    dyn = np.zeros(N_CLASSES, bool)
    dyn[list(taxonomy.dynamic_ids())] = True
    occupied = voxels.copy()
    occupied[0] = 0  # free space is no class
    return MotionShare(moving, instances - moving, int(occupied[dyn].sum()), int(occupied[~dyn].sum()))


@dataclass
class VoxelSizeStats:
    """Per-class totals of one voxel size over every sequence."""

    voxels: np.ndarray
    instances: np.ndarray
    moving: np.ndarray
    frames: int = 0


def voxel_size_totals(rows: Sequence[ClassStatisticsRecord]) -> dict[float, VoxelSizeStats]:
    """Per-voxel-size sums over sequences (instances of different sequences are different
    tracks, so they add up)."""
    out: dict[float, VoxelSizeStats] = {}
    frames: dict[float, dict[str, int]] = defaultdict(dict)
    for r in rows:
        s = out.setdefault(r.voxel_size, VoxelSizeStats(*(np.zeros(N_CLASSES, np.int64) for _ in range(3))))
        s.voxels[r.semantic_id] += r.voxels
        s.instances[r.semantic_id] += r.instances
        s.moving[r.semantic_id] += r.moving_instances
        frames[r.voxel_size][r.sequence_id] = r.frames
    for voxel_size, s in out.items():
        s.frames = sum(frames[voxel_size].values())
    return out
