"""Parquet tables of pydantic records: Arrow schemas derived from the models, atomic writes.

A table is a directory of Parquet files, one per producing partition (``<dir>/<key>.parquet``), so
no two tasks write the same file and a re-run of one partition replaces exactly its file. A file
that cannot be read as the table's (truncated, garbage bytes, another schema) is a
:class:`StoreError` naming it (:func:`read_parquet`), never an Arrow traceback. A file that lacks
only columns whose fields have a default (written before they were added) loads with those defaults.

Column names: in memory (:func:`arrow_schema`, :func:`to_table`, :meth:`ParquetTable.load_arrow`,
hence the SQL views) a column is named as its field; in the stored files a field listed in
``Record.STORED_NAMES`` keeps its stored name (``voxel_size`` is the column ``resolution``).
:func:`stored_schema`, :func:`to_stored` and :func:`from_stored` are the only translation, applied
by :class:`ParquetTable` when it writes and reads a file.
"""

from __future__ import annotations

import io
import types
import typing
from datetime import datetime
from typing import Generic, Literal, TypeVar, get_args, get_origin

import pyarrow as pa
import pyarrow.parquet as pq

from carlaocc.catalog.store import Store, StoreError
from carlaocc.schemas.records import Record

R = TypeVar("R", bound=Record)

_SCALARS: dict[type, pa.DataType] = {
    str: pa.string(),
    int: pa.int64(),
    float: pa.float64(),
    bool: pa.bool_(),
    datetime: pa.timestamp("us", tz="UTC"),
}


def arrow_type(annotation) -> tuple[pa.DataType, bool]:
    """Arrow type of a record field annotation and whether it is nullable."""
    origin = get_origin(annotation)
    # X | None and Optional[X]
    if origin in (typing.Union, types.UnionType):
        args = [a for a in get_args(annotation) if a is not type(None)]
        if len(args) != 1:
            raise TypeError(f"unsupported union {annotation!r}")
        return arrow_type(args[0])[0], True
    if origin is Literal:
        return pa.string(), False
    if origin is list:
        (item,) = get_args(annotation)
        return pa.list_(arrow_type(item)[0]), False
    if annotation in _SCALARS:
        return _SCALARS[annotation], False
    raise TypeError(f"no Arrow type for field annotation {annotation!r}")


def arrow_schema(model: type[Record]) -> pa.Schema:
    """Arrow schema of a record model, field order as declared."""
    fields = []
    for name, info in model.model_fields.items():
        typ, nullable = arrow_type(info.annotation)
        fields.append(pa.field(name, typ, nullable=nullable))
    return pa.schema(fields, metadata={b"carlaocc.record": model.__name__.encode()})


def stored_name(model: type[Record], name: str) -> str:
    """Column name of field ``name`` in the stored files (``Record.STORED_NAMES``, else itself)."""
    return model.STORED_NAMES.get(name, name)


def stored_schema(model: type[Record]) -> pa.Schema:
    """:func:`arrow_schema` with the stored column names (what the Parquet files hold)."""
    schema = arrow_schema(model)
    return pa.schema([f.with_name(stored_name(model, f.name)) for f in schema], metadata=schema.metadata)


def to_stored(model: type[Record], table: pa.Table) -> pa.Table:
    """A table of the model's :func:`arrow_schema` with its columns renamed as stored."""
    renamed = table.rename_columns([stored_name(model, n) for n in table.column_names])
    return renamed.replace_schema_metadata(table.schema.metadata)  # rename_columns drops it


def from_stored(model: type[Record], table: pa.Table) -> pa.Table:
    """A table of the model's :func:`stored_schema` with its columns renamed as the fields."""
    back = {stored_name(model, name): name for name in model.model_fields}
    renamed = table.rename_columns([back.get(n, n) for n in table.column_names])
    return renamed.replace_schema_metadata(table.schema.metadata)  # rename_columns drops it


def to_table(model: type[R], records: typing.Sequence[R]) -> pa.Table:
    """Records -> Arrow table with the model's schema (an empty list gives an empty table)."""
    schema = arrow_schema(model)
    columns = [
        pa.array([getattr(r, f.name) for r in records], type=f.type) for f in schema
    ]
    return pa.Table.from_arrays(columns, schema=schema)


def from_table(model: type[R], table: pa.Table) -> list[R]:
    """Arrow table -> validated records (unknown columns are an error, as in the models)."""
    return [model(**row) for row in table.to_pylist()]


def table_bytes(table: pa.Table) -> bytes:
    """Serialize a table to Parquet bytes (zstd); deterministic for the same table and version."""
    buf = io.BytesIO()
    pq.write_table(table, buf, compression="zstd")
    return buf.getvalue()


def field_defaults(model: type[Record]) -> dict[str, object]:
    """Name -> default of the model's fields that have a plain default (not required)."""
    return {name: info.default for name, info in model.model_fields.items()
            if not info.is_required() and info.default_factory is None}


def _add_defaulted(table: pa.Table, schema: pa.Schema, defaults: typing.Mapping[str, object]) -> pa.Table:
    """``table`` with the columns of ``schema`` it lacks that have a default (fields added to a
    model after the file was written) filled with that default, in ``schema``'s column order;
    unchanged when another column is missing or an unknown one is present (cast refuses it)."""
    missing = [f for f in schema if f.name not in table.column_names]
    if not missing or any(f.name not in defaults for f in missing):
        return table
    for f in missing:
        table = table.append_column(f, pa.array([defaults[f.name]] * table.num_rows, type=f.type))
    if set(table.column_names) != set(schema.names):
        return table
    return table.select(schema.names)


def read_parquet(store: Store, rel: str, schema: pa.Schema | None = None,
                 defaults: typing.Mapping[str, object] | None = None) -> pa.Table:
    """A stored Parquet file (store-relative path) as an Arrow table, cast to ``schema`` when
    given; StoreError naming the file when it is missing or cannot be read as such. Columns of
    ``schema`` the file lacks are filled from ``defaults`` (name -> value) when all have one:
    files written before a field with a default was added still load."""
    data = store.read_bytes(rel)
    try:
        table = pq.read_table(io.BytesIO(data))
    except (pa.ArrowException, OSError, ValueError):  # truncated, garbage bytes
        raise StoreError(f"damaged in the store {store.url}: {rel} is not a readable Parquet file "
                         f"(truncated or overwritten)") from None
    if schema is None:
        return table
    if defaults:
        table = _add_defaulted(table, schema, defaults)
    try:
        return table.cast(schema)
    except (pa.ArrowException, ValueError, KeyError):  # other columns or types
        raise StoreError(f"damaged in the store {store.url}: {rel} does not have its table's columns") from None


def parquet_problem(store: Store, rel: str) -> str | None:
    """``"missing"``, ``"unreadable"`` (not a whole Parquet file: its footer and every column
    chunk are read) or None for a stored file."""
    try:
        data = store.fs.cat_file(store.path(rel))
    except FileNotFoundError:
        return "missing"
    except OSError:
        return "unreadable"
    try:
        pq.read_table(io.BytesIO(data))
    except (pa.ArrowException, OSError, ValueError):
        return "unreadable"
    return None


class ParquetTable(Generic[R]):
    """One store table of one record model: save a partition's file, load all, check existence."""

    def __init__(self, store: Store, model: type[R]):
        self.store = store
        self.model = model
        self.dir = store.table_dir(model.TABLE)

    def path(self, key: str) -> str:
        """Store-relative path of a partition's file; ``key`` may hold ``/`` (hive-style dirs)."""
        return f"{self.dir}/{key}.parquet"

    def exists(self, key: str) -> bool:
        return self.store.exists(self.path(key))

    def save(self, key: str, records: typing.Sequence[R]) -> str:
        """Atomically write a partition's records (columns named as stored); returns the file's
        fingerprint."""
        table = to_stored(self.model, to_table(self.model, records))
        return self.store.write_bytes(self.path(key), table_bytes(table))

    def paths(self) -> list[str]:
        return self.store.glob(self.dir, ".parquet")

    def load_arrow(self, keys: typing.Iterable[str] | None = None) -> pa.Table:
        """All partitions (or the given ones) as one Arrow table with the model's schema (columns
        named as the fields); StoreError naming a file that is missing (a given key) or cannot be
        read."""
        schema = stored_schema(self.model)
        paths = self.paths() if keys is None else [self.path(k) for k in keys]
        defaults = {stored_name(self.model, n): v for n, v in field_defaults(self.model).items()}
        tables = [read_parquet(self.store, p, schema, defaults) for p in paths]
        return from_stored(self.model, pa.concat_tables(tables) if tables else schema.empty_table())

    def load(self, keys: typing.Iterable[str] | None = None) -> list[R]:
        return from_table(self.model, self.load_arrow(keys))
