"""The ADMesh library as users see it: duplicates (same asset id, i.e. same standardized
geometry and labels, ingested from several files) are one asset listing the others as aliases."""

from __future__ import annotations

from carlaocc.schemas.records import AssetRecord, PartRecord


def dedupe_assets(assets: list[AssetRecord]) -> list[AssetRecord]:
    """One record per asset id: the one with the smallest source path, its ``aliases`` the other
    source paths (sorted). Order: by asset id."""
    groups: dict[str, list[AssetRecord]] = {}
    for a in assets:
        groups.setdefault(a.asset_id, []).append(a)
    out = []
    for aid in sorted(groups):
        recs = sorted(groups[aid], key=lambda r: r.source_path)
        aliases = sorted({p for r in recs for p in [r.source_path, *r.aliases]} - {recs[0].source_path})
        out.append(recs[0].model_copy(update={"aliases": aliases}))
    return out


def dedupe_parts(parts: list[PartRecord]) -> list[PartRecord]:
    """One record per (asset id, part index)."""
    seen: dict[tuple[str, int], PartRecord] = {}
    for p in parts:
        seen.setdefault((p.asset_id, p.part_index), p)
    return [seen[k] for k in sorted(seen)]
