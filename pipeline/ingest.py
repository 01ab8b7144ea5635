"""``carlaocc ingest KIND PATH``: one Dask task per source item, unchanged items skipped.

Each item's partition carries the item's files (and the category map) as external inputs, so a
re-run re-ingests exactly the items whose bytes changed. Items that vanished from the source have
their records pruned after the run.
"""

from __future__ import annotations

import os
from collections import Counter
from dataclasses import dataclass, field

from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.sources.base import SourceError
from carlaocc.catalog.sources.registry import adapter
from carlaocc.catalog.store import ADMESH_MESHES, Store
from carlaocc.pipeline import tasks
from carlaocc.pipeline.registry import Partition, StageSpec
from carlaocc.pipeline.runner import Progress, StageOutcome, run
from carlaocc.pipeline.stages import SHARED_CODE
from carlaocc.schemas.configs import DatasetConfig, SourceIngestConfig
from carlaocc.schemas.records import AssetRecord, PartRecord, QuarantineRecord

STAGE = "ingest"


class IngestError(Exception):
    """The source as a whole is unusable (missing root, unknown kind, bad category map): exit 2."""


def partition_key(cfg: SourceIngestConfig, item_key: str) -> str:
    return f"{cfg.kind}:{tasks.root_digest(cfg.root)}/{item_key}"


def source_partitions(cfg: SourceIngestConfig) -> list[Partition]:
    """One partition per item of the source; raises IngestError when the source is unusable."""
    if not os.path.isdir(cfg.root):
        raise IngestError(f"{cfg.kind} source {cfg.root} is not a directory")
    if cfg.category_map and not os.path.isfile(cfg.category_map):
        raise IngestError(f"category map {cfg.category_map} does not exist")
    try:
        items = adapter(cfg.kind, category_map=cfg.category_map).list_items(cfg.root)
    except ValueError as exc:  # an option this kind does not take (e.g. a category map)
        raise IngestError(f"{cfg.kind} source: {exc}") from None
    except SourceError as exc:
        raise IngestError(f"{cfg.kind} source {cfg.root}: {exc.reason}" + (f" ({exc.hint})" if exc.hint else "")) from None
    return [
        Partition(partition_key(cfg, it.key), {"item_key": it.key, "meta": _stable_meta(it.meta)},
                  files=tuple(it.files))
        for it in items
    ]


def _stable_meta(meta: dict) -> dict:
    """Item metadata as it enters the cache key: the category-map row an item matched counts,
    its line number does not (editing another row, or adding a comment, re-ingests nothing)."""
    row = meta.get("row")
    if isinstance(row, dict) and "line" in row:
        meta = {**meta, "row": {k: v for k, v in row.items() if k != "line"}}
    return meta


def source_spec(cfg: SourceIngestConfig) -> StageSpec:
    """An ingest stage over one external source, run by the ordinary runner."""
    parts = source_partitions(cfg)
    return StageSpec(
        name=STAGE,
        description=f"ingest the {cfg.kind} source {cfg.root}",
        upstream=(),
        code_modules=("carlaocc.stages.ingest", "carlaocc.catalog.sources", *SHARED_CODE),
        reads=(cfg.root,),
        writes=("admesh/meshes/<id>.glb", "admesh/assets/", "admesh/parts/", "admesh/quarantine/"),
        partitions=lambda ctx: parts,
        task=tasks.ingest_source_task,
        config_of=lambda _: cfg,
    )


@dataclass
class IngestSummary:
    items: int
    ran: int
    skipped: int
    failed: list = field(default_factory=list)
    ingested: int = 0
    quarantined: Counter = field(default_factory=Counter)
    pruned: int = 0


def prune_vanished(store: Store, cfg: SourceIngestConfig, keys: set[str]) -> int:
    """Remove the table files of items of this source root that are no longer listed."""
    prefix = f"source={cfg.kind}/{tasks.root_digest(cfg.root)}-"
    live = {tasks.source_table_key(cfg, k) for k in keys}
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
    """Remove standardized meshes no asset row references any more (an item that changed,
    turned bad or vanished leaves its old GLB behind)."""
    referenced = {a.mesh_path for a in ParquetTable(store, AssetRecord).load()}
    orphans = [rel for rel in store.glob(ADMESH_MESHES, ".glb") if rel not in referenced]
    for rel in orphans:
        store.remove(rel)
    return len(orphans)


def ingest_source(store: Store, cfg: SourceIngestConfig, scheduler: str | None = None, force: bool = False,
                  progress: Progress | None = None, workers: int | None = None, log=lambda s: None) -> IngestSummary:
    """Ingest one source into the store's ADMesh library."""
    spec = source_spec(cfg)
    parts = spec.partitions(None)
    outcomes: list[StageOutcome] = run(store, DatasetConfig(), (), None, scheduler, force, progress, workers,
                                       log, registry={STAGE: spec})
    (o,) = outcomes
    summary = IngestSummary(items=len(parts), ran=o.ran, skipped=o.skipped, failed=o.failed)
    summary.pruned = prune_vanished(store, cfg, {p.params["item_key"] for p in parts})
    prune_orphan_meshes(store)
    # what the library now holds of this source
    prefix = f"source={cfg.kind}/{tasks.root_digest(cfg.root)}-"
    for model in (AssetRecord, QuarantineRecord):
        table = ParquetTable(store, model)
        keys = [rel[len(table.dir) + 1 : -len(".parquet")] for rel in table.paths()]
        rows = table.load([k for k in keys if k.startswith(prefix)])
        if model is AssetRecord:
            summary.ingested = len({r.asset_id for r in rows})  # duplicates are one asset
        else:
            summary.quarantined = Counter(r.reason for r in rows)
    return summary
