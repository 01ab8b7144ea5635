"""The ingest stage: the procedural ADMesh library (``carlaocc run``), and the stage over one
external mesh source (``carlaocc ingest KIND PATH``, :mod:`carlaocc.pipeline.commands.ingest`)
as one task per source item.

Each source item's partition carries the item's files (and the category map) as external inputs,
so a re-run re-ingests exactly the items whose bytes changed. Items that vanished from the source
have their records pruned after the run. A bad item is quarantined with its reason; the batch
goes on. A dataset root placed inside the source folder is skipped when the source is listed (its
own meshes are not source meshes); the summary says so.
"""

from __future__ import annotations

import hashlib
import os

from carlaocc.catalog.meshes import MeshStore
from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.sources.base import SourceError, SourceItem
from carlaocc.catalog.sources.registry import adapter
from carlaocc.catalog.store import Store
from carlaocc.catalog.textures import TextureStore, has_texture
from carlaocc.pipeline.engine.spec import Context, Partition, StageSpec
from carlaocc.pipeline.tasks.partitions import INGEST_PARTITION, PROCEDURAL_SOURCE
from carlaocc.schemas.configs import IngestConfig, SourceIngestConfig
from carlaocc.schemas.records import AssetRecord, PartRecord, QuarantineRecord
from carlaocc.stages.ingest import ingest_procedural
from carlaocc.stages.ingest.checks import Rejection
from carlaocc.stages.ingest.standardize import standardize

STAGE = "ingest"


class IngestError(Exception):
    """The source as a whole is unusable (missing root, unknown kind, bad category map): exit 2."""


# -- the procedural library ---------------------------------------------------------------------
def _ingest_partitions(ctx: Context) -> list[Partition]:
    return [Partition(INGEST_PARTITION, {"source": INGEST_PARTITION})]


def ingest_task(store: Store, cfg: IngestConfig, part: Partition) -> dict[str, str]:
    """Generate the procedural ADMesh library; write meshes, assets and parts."""

    result = ingest_procedural(cfg)
    meshes = MeshStore(store)
    outputs: dict[str, str] = {}
    assets = []
    for rec in result.assets:
        rel = store.asset_mesh_path(rec.asset_id)
        outputs[rel] = meshes.save(rel, result.geometry[rec.asset_id].parts)
        assets.append(rec.model_copy(update={"mesh_path": rel}))
    t_assets = ParquetTable(store, AssetRecord)
    t_parts = ParquetTable(store, PartRecord)
    key = f"source={PROCEDURAL_SOURCE}/{PROCEDURAL_SOURCE}"
    outputs[t_assets.path(key)] = t_assets.save(key, assets)
    outputs[t_parts.path(key)] = t_parts.save(key, result.parts)
    return outputs


SPEC = StageSpec(
    name=STAGE,
    description="procedural ADMesh library: closed metric meshes of every thing class",
    upstream=(),
    reads=(),
    writes=("admesh/meshes/<id>.glb", "admesh/assets/", "admesh/parts/"),
    partitions=_ingest_partitions,
    task=ingest_task,
)


# -- an external source, one item per task ------------------------------------------------------
def source_table_key(cfg: SourceIngestConfig, item_key: str) -> str:
    """Table file key of one source item: ``source=<kind>/<root hash>-<item hash>`` (so the
    items of one source root can be listed, and pruned when they disappear)."""
    return f"source={cfg.kind}/{root_digest(cfg.root)}-{hashlib.sha256(item_key.encode()).hexdigest()[:16]}"


def root_digest(root: str) -> str:
    return hashlib.sha256(root.encode()).hexdigest()[:10]


def ingest_source_task(store: Store, cfg: SourceIngestConfig, part: Partition) -> dict[str, str]:
    """Read one source item, standardize it, and write its mesh and records — or its quarantine
    row. The other outcome's files of the same item are removed, so an item that turned bad (or
    good) is never listed twice."""

    item = SourceItem(key=part.params["item_key"], files=tuple(part.files), meta=part.params.get("meta", {}))
    key = source_table_key(cfg, item.key)
    t_assets, t_parts = ParquetTable(store, AssetRecord), ParquetTable(store, PartRecord)
    t_quarantine = ParquetTable(store, QuarantineRecord)
    source_path = item.files[0] if item.files else item.key
    try:
        src = adapter(cfg.kind, category_map=cfg.category_map).read(cfg.root, item)
        source_path = src.source_path
        result = standardize(src)
    except SourceError as exc:
        result = Rejection(exc.reason, exc.hint)
    except Exception as exc:  # whatever else one bad file does, the batch goes on
        result = Rejection("unreadable file", f"{type(exc).__name__}: {exc}; check or re-export {source_path}")
    if isinstance(result, Rejection):
        for t in (t_assets, t_parts):
            store.remove(t.path(key))
        row = QuarantineRecord(stage="ingest", source=cfg.kind, source_path=source_path,
                               reason=result.reason, hint=result.hint)
        return {t_quarantine.path(key): t_quarantine.save(key, [row])}
    store.remove(t_quarantine.path(key))
    rel = store.asset_mesh_path(result.asset.asset_id)
    outputs = {rel: MeshStore(store).save(rel, result.geometry.parts)}
    update = {"mesh_path": rel}
    if has_texture(result.geometry.parts):  # the parts' textures, beside the GLB
        tex = store.asset_texture_path(result.asset.asset_id)
        outputs[tex] = TextureStore(store).save(tex, result.geometry.parts)
        update["texture_path"] = tex
    asset = result.asset.model_copy(update=update)
    outputs[t_assets.path(key)] = t_assets.save(key, [asset])
    outputs[t_parts.path(key)] = t_parts.save(key, result.parts)
    return outputs

def partition_key(cfg: SourceIngestConfig, item_key: str) -> str:
    return f"{cfg.kind}:{root_digest(cfg.root)}/{item_key}"


def dataset_roots_inside(store: Store, cfg: SourceIngestConfig) -> tuple[str, ...]:
    """The store's own directory when it is the source root or lies inside it (a local store
    only): the listing of the source must skip it."""
    if not store.is_local:
        return ()
    mine, src = os.path.realpath(store.root), os.path.realpath(cfg.root)
    if mine == src or mine.startswith(src.rstrip(os.sep) + os.sep):
        return (mine,)
    return ()


def source_partitions(cfg: SourceIngestConfig, exclude: tuple[str, ...] = ()) -> list[Partition]:
    """One partition per item of the source, items inside the directories ``exclude`` left out;
    raises IngestError when the source is unusable."""
    if not os.path.isdir(cfg.root):
        raise IngestError(f"{cfg.kind} source {cfg.root} is not a directory")
    if cfg.category_map and not os.path.isfile(cfg.category_map):
        raise IngestError(f"category map {cfg.category_map} does not exist")
    try:
        items = adapter(cfg.kind, category_map=cfg.category_map).list_items(cfg.root, exclude=exclude)
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


def source_spec(cfg: SourceIngestConfig, exclude: tuple[str, ...] = ()) -> StageSpec:
    """An ingest stage over one external source (``exclude``: directories of it not listed), run
    by the ordinary runner."""
    parts = source_partitions(cfg, exclude)
    return StageSpec(
        name=STAGE,
        description=f"ingest the {cfg.kind} source {cfg.root}",
        upstream=(),
        reads=(cfg.root,),
        writes=("admesh/meshes/<id>.glb", "admesh/textures/<id>.npz", "admesh/assets/", "admesh/parts/",
                "admesh/quarantine/"),
        partitions=lambda ctx: parts,
        task=ingest_source_task,
        config_of=lambda _: cfg,
    )
