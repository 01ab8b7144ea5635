import pytest

from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.sql import QueryError, QueryRefused, check_read_only, query
from carlaocc.schemas.records import SequenceRecord


def _seed(store):
    ParquetTable(store, SequenceRecord).save("s1", [SequenceRecord(
        sequence_id="town00_seq000", town="town00", seed=1, frame_count=20, rate_hz=20.0,
        traffic_level="low", ego_asset_id="e")])


def test_select_over_views(store):
    _seed(store)
    cols, rows = query(store, "SELECT sequence_id, frame_count FROM sequences")
    assert cols == ["sequence_id", "frame_count"] and rows == [("town00_seq000", 20)]
    # every table is a view even when empty, plus the taxonomy
    _, rows = query(store, "SELECT count(*) FROM assets")
    assert rows == [(0,)]
    _, rows = query(store, "SELECT name FROM classes WHERE id = 14")
    assert rows == [("Car",)]


@pytest.mark.parametrize("sql", [
    "INSERT INTO sequences VALUES (1)",
    "UPDATE sequences SET seed = 2",
    "DELETE FROM sequences",
    "COPY sequences TO '/tmp/x.csv'",
    "CREATE TABLE t AS SELECT 1",
    "DROP VIEW sequences",
    "ATTACH '/tmp/x.db'",
    "INSTALL httpfs",
    "LOAD httpfs",
    "PRAGMA enable_profiling",
    "SET threads = 1",
    "SELECT 1; DELETE FROM sequences",
])
def test_writes_and_escapes_refused(sql):
    with pytest.raises(QueryRefused, match="read-only"):
        check_read_only(sql)


def test_reading_files_outside_the_catalog_is_blocked(store, tmp_path):
    _seed(store)
    secret = tmp_path / "secret.csv"
    secret.write_text("a\n1\n")
    with pytest.raises(QueryError):
        query(store, f"SELECT * FROM read_csv('{secret}')")


def test_syntax_error_is_a_query_error():
    with pytest.raises(QueryError) as err:
        check_read_only("SELEC * FROM assets")
    assert not isinstance(err.value, QueryRefused)
    assert "syntax" in str(err.value).lower()


def test_read_pragma_allowed(store):
    _seed(store)
    check_read_only("PRAGMA table_info('sequences')")
    cols, rows = query(store, "PRAGMA table_info('sequences')")
    assert any("sequence_id" in r for r in rows)


def test_timestamps_and_nan_are_queryable(store):
    from datetime import datetime, timezone

    from carlaocc.schemas.records import QualityRecord, RunRecord

    t = datetime(2026, 5, 1, 12, 0, tzinfo=timezone.utc)
    ParquetTable(store, RunRecord).save("stage=x/r", [RunRecord(
        run_id="r", stage="x", partition="p", code_version="c", config_hash="h", cache_key="k",
        input_fingerprints="{}", output_fingerprints="{}", status="completed", started_at=t, ended_at=t, host="h")])
    ParquetTable(store, QualityRecord).save("q", [QualityRecord(
        sequence_id="s", voxel_size=0.2, frame_index=None, metric="m", value=float("nan"), occupied=0, isolated=0)])
    _, rows = query(store, "SELECT started_at, now() IS NOT NULL FROM runs")
    assert rows[0][0] == t and rows[0][1] is True
    _, rows = query(store, "SELECT value FROM quality")
    assert rows[0][0] != rows[0][0]  # NaN survives


def test_resource_settings_are_locked(store):
    with pytest.raises(QueryError):
        query(store, "SELECT * FROM read_parquet('/etc/passwd')")
    _, rows = query(store, "SELECT current_setting('max_temp_directory_size'), current_setting('enable_external_access')")
    assert rows[0][1] is False


def test_duplicate_column_names_are_kept(store):
    _seed(store)
    cols, rows = query(store, "SELECT s.sequence_id, c.name, c.name FROM sequences s, classes c WHERE c.id = 14")
    assert cols[1:] == ["name", "name"] or len(cols) == 3
    assert rows == [("town00_seq000", "Car", "Car")]


def test_the_query_command_names_every_view():
    """`carlaocc catalog query --help` lists the views: each persisted table and the two label
    tables (a new table is named there too)."""
    import re

    from carlaocc.pipeline.cli.query import catalog_query
    from carlaocc.schemas import records

    named = set(re.findall(r"[a-z_]+", catalog_query.__doc__.split("Views:", 1)[1].split("(", 1)[0]))
    assert named == {m.TABLE for m in records.PERSISTED} | {"classes", "label_tables"}
