"""What every per-frame task reads (``carlaocc.pipeline.tasks.frame``): the mesh library's tables
are validated once per worker and content, and read again when a file of them changes."""

from __future__ import annotations

from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.store import Store
from carlaocc.pipeline.tasks.frame import library_rows
from carlaocc.schemas.records import PartRecord


def _part(asset: str, k: int, semantic: int) -> PartRecord:
    return PartRecord(asset_id=asset, part_index=k, name=f"p{k}", material="m", transparent=False,
                      semantic_id=semantic, face_count=12, watertight=True)


def test_library_rows_are_cached_by_content(tmp_path):
    store = Store(str(tmp_path))
    table = ParquetTable(store, PartRecord)
    table.save("a", [_part("a", 0, 3), _part("a", 1, 4)])
    table.save("b", [_part("b", 0, 5)])
    first = library_rows(store, PartRecord)
    assert sorted((p.asset_id, p.part_index, p.semantic_id) for p in first) == [("a", 0, 3), ("a", 1, 4), ("b", 0, 5)]
    assert library_rows(store, PartRecord) is first  # unchanged files: the same rows, not validated again
    # a file rewritten with other rows, a file added, a file removed: the rows read again each time
    table.save("b", [_part("b", 0, 6)])
    assert sorted(p.semantic_id for p in library_rows(store, PartRecord)) == [3, 4, 6]
    table.save("c", [_part("c", 0, 7)])
    assert sorted(p.semantic_id for p in library_rows(store, PartRecord)) == [3, 4, 6, 7]
    store.remove(table.path("a"))
    assert sorted(p.semantic_id for p in library_rows(store, PartRecord)) == [6, 7]
    # another store with the same content is another key
    other = Store(str(tmp_path / "other"))
    ParquetTable(other, PartRecord).save("b", [_part("b", 0, 6)])
    assert [p.semantic_id for p in library_rows(other, PartRecord)] == [6]
