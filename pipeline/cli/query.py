"""``carlaocc catalog query``: read-only SQL over the dataset catalog (DuckDB views)."""

from __future__ import annotations

import csv
import io
import json
import math
from typing import Annotated

import typer

from carlaocc.catalog.store import StoreError
from carlaocc.pipeline.cli.app import catalog_app
from carlaocc.pipeline.cli.common import RootOpt, open_store, fail


def _format_value(v) -> str:
    if isinstance(v, float):
        return "NaN" if math.isnan(v) else f"{v:.6g}"
    return "NULL" if v is None else str(v)


@catalog_app.command("query")
def catalog_query(
    sql: Annotated[str, typer.Argument(help="a read-only SQL query over the catalog views")],
    root: RootOpt = "data",
    fmt: Annotated[str, typer.Option("--format", help="table, csv or json")] = "table",
) -> None:
    """Run read-only SQL. Views: assets, parts, quarantine, towns, placements, sequences, frames,
    actors, ego_states, skeletons, sensor_poses, runs, quality, quality_classes, statistics_frames,
    statistics_classes, statistics_assets, rectification, lidar_agreement, classes, label_tables
    (`SELECT table_name FROM information_schema.tables` lists them)."""
    from carlaocc.catalog.sql import QueryError, QueryRefused, query

    if fmt not in ("table", "csv", "json"):
        fail(f"--format {fmt!r}: choose table, csv or json")
    store = open_store(root, writable=False)
    try:
        cols, rows = query(store, sql)
    except QueryRefused as exc:
        fail(str(exc))
    except QueryError as exc:
        fail(f"SQL: {exc}")
    except StoreError as exc:
        fail(str(exc))
    if fmt == "json":
        clean = lambda v: None if isinstance(v, float) and not math.isfinite(v) else v  # JSON has no NaN
        typer.echo(json.dumps([{c: clean(v) for c, v in zip(cols, r)} for r in rows], default=str, indent=1))
    elif fmt == "csv":
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(cols)
        w.writerows(rows)
        typer.echo(buf.getvalue().rstrip("\n"))
    else:
        cells = [[_format_value(v) for v in r] for r in rows]
        widths = [max([len(c)] + [min(len(r[i]), 60) for r in cells]) for i, c in enumerate(cols)]
        typer.echo("  ".join(c.ljust(w) for c, w in zip(cols, widths)))
        typer.echo("  ".join("-" * w for w in widths))
        for r in cells:
            typer.echo("  ".join(v[:60].ljust(w) for v, w in zip(r, widths)))
        typer.echo(f"({len(rows)} rows)")
