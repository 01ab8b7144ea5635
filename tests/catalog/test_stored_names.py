"""Record.STORED_NAMES: the field ``voxel_size`` is the Parquet column ``resolution``.

Written through ParquetTable, a record's file has the column ``resolution`` (the bytes are those
written before the field was renamed); it reads back as ``.voxel_size``; a file written with the
old column by hand (as every root built before the rename holds) reads too; the Arrow tables in
memory and the SQL views say ``voxel_size``.
"""

from __future__ import annotations

import io

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from carlaocc.catalog.parquet import ParquetTable, arrow_schema, stored_schema, table_bytes, to_table
from carlaocc.catalog.sql import query
from carlaocc.schemas import records as R

VOXEL_SIZE_MODELS = [m for m in R.PERSISTED if "voxel_size" in m.model_fields]


def _quality(frame_index=None, value=0.75):
    return R.QualityRecord(sequence_id="town00_high_seq000", voxel_size=0.2, frame_index=frame_index,
                           metric="spatial_continuity", value=value, occupied=8, isolated=2,
                           numerator=6, denominator=8)


def test_the_records_with_a_voxel_size():
    names = {m.__name__ for m in VOXEL_SIZE_MODELS}
    assert names == {"QualityRecord", "ClassQualityRecord", "FrameStatisticsRecord", "ClassStatisticsRecord"}
    assert not any("resolution" in m.model_fields for m in R.PERSISTED)
    for m in VOXEL_SIZE_MODELS:
        assert "resolution" in stored_schema(m).names and "voxel_size" not in stored_schema(m).names
        assert "voxel_size" in arrow_schema(m).names


def test_written_as_resolution_read_as_voxel_size(store):
    table = ParquetTable(store, R.QualityRecord)
    rows = [_quality(), _quality(frame_index=3, value=0.5)]
    table.save("town00_high_seq000/0.2", rows)
    data = store.read_bytes(table.path("town00_high_seq000/0.2"))
    written = pq.read_table(io.BytesIO(data))
    assert written.column_names[:2] == ["sequence_id", "resolution"]
    assert written.column("resolution").to_pylist() == [0.2, 0.2]
    assert written.schema.metadata == {b"carlaocc.record": b"QualityRecord"}
    # the bytes are those the table of the old column name gives (builds before and after agree)
    old_named = to_table(R.QualityRecord, rows).rename_columns(stored_schema(R.QualityRecord).names)
    assert data == table_bytes(old_named.replace_schema_metadata(written.schema.metadata))
    back = table.load()
    assert back == rows and back[0].voxel_size == 0.2
    assert table.load_arrow().column_names[:2] == ["sequence_id", "voxel_size"]


@pytest.mark.parametrize("model", VOXEL_SIZE_MODELS, ids=lambda m: m.__name__)
def test_an_old_file_with_the_resolution_column_reads(store, model):
    # as a root built before the rename wrote it: pyarrow from plain rows, the old column name
    fields = {"sequence_id": "s", "resolution": 0.05, "frame_index": 2, "semantic_id": 14, "metric": "m",
              "value": 1.0, "occupied": 3, "isolated": 0, "voxels": 7, "instance_ids": [1, 2], "frames": 4,
              "instances": 2, "moving_instances": 1}
    row = {c: fields[c] for c in stored_schema(model).names if c in fields}
    old = pa.Table.from_pylist([row], schema=pa.schema([f for f in stored_schema(model) if f.name in row]))
    table = ParquetTable(model=model, store=store)
    store.write_bytes(table.path("s/0.05"), table_bytes(old))
    (rec,) = table.load()
    assert rec.voxel_size == 0.05 and rec.sequence_id == "s"


def test_sql_views_say_voxel_size(store):
    ParquetTable(store, R.QualityRecord).save("s/0.2", [_quality()])
    cols, rows = query(store, "SELECT voxel_size, value FROM quality")
    assert cols == ["voxel_size", "value"] and rows == [(0.2, 0.75)]
    cols, _ = query(store, "SELECT * FROM statistics_classes")
    assert "voxel_size" in cols and "resolution" not in cols
