"""What partitioning shares across stages: the partition keys one stage names in another's
``needs`` and the sequences per-sequence stages iterate (kept apart from the task bodies, so a
stage's code version does not take in the wiring of the stages it only names)."""

from __future__ import annotations

from carlaocc.catalog.parquet import ParquetTable
from carlaocc.pipeline.spec import Context, UpstreamMissing
from carlaocc.schemas.records import SequenceRecord

PROCEDURAL_SOURCE = "procedural"
INGEST_PARTITION = PROCEDURAL_SOURCE  # the one partition of the procedural library


def town_key(i: int) -> str:
    """The scenes partition key (and town name) of the ``i``-th configured town."""
    return f"town{i:02d}"


def sequences(ctx: Context) -> list[SequenceRecord]:
    """The sequences of the configured towns, by id; UpstreamMissing before the scenes stage ran."""
    towns = {town_key(i) for i in range(len(ctx.config.scenes.towns))}
    seqs = [s for s in ParquetTable(ctx.store, SequenceRecord).load() if s.town in towns]
    if not seqs:
        raise UpstreamMissing("no sequences yet: the scenes stage has not run")
    return sorted(seqs, key=lambda s: s.sequence_id)
