"""Read-only SQL over the catalog with DuckDB.

Every table of the store is loaded (it is small metadata: assets, parts, placements, sequences,
frames, actors, runs, quality...) and registered as a DuckDB view, plus ``classes`` (the taxonomy
table the dataset was built under) and ``label_tables`` (every label table). Then external access is switched off and the configuration locked, so a query can read
those views and nothing else. Before running, each statement's type is checked: anything but a
query (INSERT, UPDATE, DELETE, COPY, CREATE, DROP, ATTACH, INSTALL, LOAD, SET, writing PRAGMAs...)
is refused with :class:`QueryRefused`; a syntax error raises :class:`QueryError` with DuckDB's
message.
"""

from __future__ import annotations

import duckdb
import pyarrow as pa

from carlaocc.catalog.admesh import dedupe_assets, dedupe_parts
from carlaocc.catalog.parquet import ParquetTable, from_table, to_table
from carlaocc.catalog.store import Store
from carlaocc.schemas import records, taxonomy

# statement types that only read
_READ_TYPES = {duckdb.StatementType.SELECT, duckdb.StatementType.EXPLAIN}
# PRAGMAs that only describe (everything else, e.g. enable_profiling or memory_limit, is refused)
_READ_PRAGMAS = {"table_info", "show_tables", "show_tables_expanded", "show", "database_list",
                 "functions", "version", "platform", "storage_info"}


class QueryError(Exception):
    """The SQL is malformed or failed (DuckDB's message)."""


class QueryRefused(QueryError):
    """The SQL would write or reach outside the catalog."""


def _model_tables() -> dict[str, type[records.Record]]:
    return {m.TABLE: m for m in records.PERSISTED}


def catalog_tables(store: Store) -> dict[str, pa.Table]:
    """Every catalog table of the store as Arrow (empty tables keep their schema); ``assets`` and
    ``parts`` list each asset once (duplicates become aliases)."""
    out = {name: ParquetTable(store, model).load_arrow() for name, model in _model_tables().items()}
    out["assets"] = to_table(records.AssetRecord, dedupe_assets(from_table(records.AssetRecord, out["assets"])))
    out["parts"] = to_table(records.PartRecord, dedupe_parts(from_table(records.PartRecord, out["parts"])))
    # classes: the dataset's label table (the one its towns were built under; the default before
    # any town), label_tables: every table, long form, to compare them
    built = set(out["towns"].column("label_table").to_pylist()) if out["towns"].num_rows else set()
    out["classes"] = pa.Table.from_pylist(taxonomy.table_rows(built.pop() if len(built) == 1 else None))
    out["label_tables"] = pa.Table.from_pylist([{"label_table": name, **row} for name in taxonomy.LABEL_TABLES
                                                for row in taxonomy.table_rows(name)])
    return out


def check_read_only(sql: str) -> list[duckdb.Statement]:
    """Parse ``sql`` and refuse any statement that is not a read; returns the statements."""
    try:
        statements = duckdb.extract_statements(sql)
    except duckdb.Error as exc:
        raise QueryError(str(exc)) from None
    if not statements:
        raise QueryError("empty query")
    for st in statements:
        if st.type in _READ_TYPES:
            continue
        if st.type == duckdb.StatementType.PRAGMA:
            name = st.query.strip().split(None, 1)[1].split("(")[0].split("=")[0].strip().lower()
            if name in _READ_PRAGMAS:
                continue
        kind = str(st.type).split(".")[-1]
        raise QueryRefused(
            f"refused: {kind} statements are not allowed; the catalog is read-only "
            f"(use SELECT ... FROM one of the catalog views)"
        )
    return statements


def connect(store: Store) -> duckdb.DuckDBPyConnection:
    """An in-memory DuckDB connection with every catalog table as a view, sealed for reading."""
    con = duckdb.connect(":memory:")
    for name, table in catalog_tables(store).items():
        con.register(name, table)
    # bounded resources, no spilling to disk, nothing outside the registered views
    con.execute("SET memory_limit = '4GB'")
    con.execute("SET threads = 2")
    con.execute("SET max_temp_directory_size = '0B'")
    con.execute("SET enable_external_access = false")
    con.execute("SET lock_configuration = true")
    return con


def query(store: Store, sql: str) -> tuple[list[str], list[tuple]]:
    """Run a read-only query; returns (column names, rows)."""
    check_read_only(sql)
    con = connect(store)
    try:
        # through Arrow: timestamps with time zones need no pytz
        rel = con.sql(sql)
        if rel is None:
            return [], []
        table = rel.to_arrow_table()
        cols = table.column_names
        # column-wise: duplicate column names (a.name, c.name) must not collapse
        return cols, list(zip(*(c.to_pylist() for c in table.columns))) if cols else []
    except duckdb.Error as exc:
        raise QueryError(str(exc).strip()) from None
    except Exception as exc:  # a result Arrow cannot turn into Python values
        raise QueryError(f"{type(exc).__name__}: {exc}") from None
    finally:
        con.close()
