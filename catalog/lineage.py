"""Lineage records: one Parquet file per (stage, run) under ``catalog/runs/stage=<stage>/``."""

from __future__ import annotations

import typing

from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.store import Store
from carlaocc.schemas.records import RunRecord


class LineageLog:
    """Read and append lineage records of a store."""

    def __init__(self, store: Store):
        self.table = ParquetTable(store, RunRecord)

    def append(self, stage: str, run_id: str, records: typing.Sequence[RunRecord]) -> str | None:
        """Write a run's records of one stage (nothing when there are none)."""
        if not records:
            return None
        return self.table.save(f"stage={stage}/{run_id}", records)

    def load(self, stage: str | None = None) -> list[RunRecord]:
        prefix = None if stage is None else f"{self.table.dir}/stage={stage}/"
        keys = [
            p[len(self.table.dir) + 1 : -len(".parquet")]
            for p in self.table.paths()
            if prefix is None or p.startswith(prefix)
        ]
        return self.table.load(keys)

    def latest(self, stage: str) -> dict[str, RunRecord]:
        """The most recent record of every partition of a stage (completed or failed), ordered by
        run id (the driver's clock), never by the workers' timestamps."""
        out: dict[str, RunRecord] = {}
        for rec in sorted(self.load(stage), key=lambda r: r.run_id):
            out[rec.partition] = rec
        return out
