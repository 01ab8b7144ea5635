"""``carlaocc ingest KIND PATH``: one external mesh source into the ADMesh library, run by the
engine as the ingest stage over the source's items (:func:`carlaocc.pipeline.tasks.ingest.source_spec`),
then the items that vanished from the source pruned, with the meshes no asset references."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

from carlaocc.catalog.lock import RootBusy, root_lock
from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.store import ADMESH_MESHES, ADMESH_TEXTURES, Store
from carlaocc.pipeline.engine.runner import PlanError, Progress, StageOutcome, run
from carlaocc.pipeline.tasks.ingest import (STAGE, IngestError, dataset_roots_inside, root_digest, source_spec,
                                            source_table_key)
from carlaocc.schemas.configs import DatasetConfig, SourceIngestConfig
from carlaocc.schemas.records import AssetRecord, PartRecord, QuarantineRecord

__all__ = ["IngestError", "IngestSummary", "ingest_source", "prune_orphan_meshes", "prune_vanished"]


@dataclass
class IngestSummary:
    items: int
    ran: int
    skipped: int
    failed: list = field(default_factory=list)
    ingested: int = 0
    quarantined: Counter = field(default_factory=Counter)
    pruned: int = 0
    excluded: tuple[str, ...] = ()  # directories of the source skipped (the dataset root inside it)


def prune_vanished(store: Store, cfg: SourceIngestConfig, keys: set[str]) -> int:
    """Remove the table files of items of this source root that are no longer listed."""
    prefix = f"source={cfg.kind}/{root_digest(cfg.root)}-"
    live = {source_table_key(cfg, k) for k in keys}
    removed = 0
    for model in (AssetRecord, PartRecord, QuarantineRecord):
        table = ParquetTable(store, model)
        for rel in table.paths():
            key = rel[len(table.dir) + 1 : -len(".parquet")]
            if key.startswith(prefix) and key not in live:
                store.remove(rel)
                removed += model is AssetRecord or model is QuarantineRecord
    return removed


def prune_orphan_meshes(store: Store) -> int:
    """Remove standardized meshes (and their textures) no asset row references any more (an item
    that changed, turned bad or vanished leaves its old GLB behind)."""
    assets = ParquetTable(store, AssetRecord).load()
    referenced = {a.mesh_path for a in assets} | {a.texture_path for a in assets if a.texture_path}
    orphans = [rel for rel in store.glob(ADMESH_MESHES, ".glb") + store.glob(ADMESH_TEXTURES, ".npz")
               if rel not in referenced]
    for rel in orphans:
        store.remove(rel)
    return len(orphans)


def ingest_source(store: Store, cfg: SourceIngestConfig, scheduler: str | None = None, force: bool = False,
                  progress: Progress | None = None, workers: int | None = None, log=lambda s: None,
                  wait: bool = True) -> IngestSummary:
    """Ingest one source into the store's ADMesh library, holding the root's writer lock from
    the listing of the source to the last clean-up (:mod:`carlaocc.catalog.lock`: another
    command's meshes are never taken for orphans); ``wait=False`` refuses (PlanError) when
    another command holds it."""
    try:
        with root_lock(store, wait=wait, on_wait=log):
            return _ingest_locked(store, cfg, scheduler, force, progress, workers, log)
    except RootBusy as exc:
        raise PlanError(str(exc)) from None


def _ingest_locked(store, cfg, scheduler, force, progress, workers, log) -> IngestSummary:
    excluded = dataset_roots_inside(store, cfg)
    spec = source_spec(cfg, excluded)
    parts = spec.partitions(None)
    outcomes: list[StageOutcome] = run(store, DatasetConfig(), (), None, scheduler, force, progress, workers,
                                       log, registry={STAGE: spec})
    (o,) = outcomes
    summary = IngestSummary(items=len(parts), ran=o.ran, skipped=o.skipped, failed=o.failed, excluded=excluded)
    summary.pruned = prune_vanished(store, cfg, {p.params["item_key"] for p in parts})
    prune_orphan_meshes(store)
    # what the library now holds of this source
    prefix = f"source={cfg.kind}/{root_digest(cfg.root)}-"
    for model in (AssetRecord, QuarantineRecord):
        table = ParquetTable(store, model)
        keys = [rel[len(table.dir) + 1 : -len(".parquet")] for rel in table.paths()]
        rows = table.load([k for k in keys if k.startswith(prefix)])
        if model is AssetRecord:
            summary.ingested = len({r.asset_id for r in rows})  # duplicates are one asset
        else:
            summary.quarantined = Counter(r.reason for r in rows)
    return summary
