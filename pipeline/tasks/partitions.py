"""What partitioning shares across stages: the partition keys one stage names in another's
``needs`` and the sequences per-sequence stages iterate (kept apart from the task bodies, so a
stage's code version does not take in the wiring of the stages it only names)."""

from __future__ import annotations

from fnmatch import fnmatchcase

from carlaocc.catalog.parquet import ParquetTable
from carlaocc.pipeline.engine.spec import Context, SelectionError, UpstreamMissing
from carlaocc.schemas.records import SequenceRecord

PROCEDURAL_SOURCE = "procedural"
INGEST_PARTITION = PROCEDURAL_SOURCE  # the one partition of the procedural library


def town_key(i: int) -> str:
    """The scenes partition key (and town name) of the ``i``-th configured town."""
    return f"town{i:02d}"


def sequences(ctx: Context, selected: bool = True) -> list[SequenceRecord]:
    """The sequences of the configured towns, by id -- only those matching the run's sequence
    selection (``--sequences`` patterns) unless ``selected`` is False; UpstreamMissing before
    the scenes stage ran, SelectionError when the patterns match none."""

    towns = {town_key(i) for i in range(len(ctx.config.scenes.towns))}
    seqs = [s for s in ParquetTable(ctx.store, SequenceRecord).load() if s.town in towns]
    if not seqs:
        raise UpstreamMissing("no sequences yet: the scenes stage has not run")
    if selected and ctx.sequence_patterns:
        chosen = [s for s in seqs if any(fnmatchcase(s.sequence_id, p) for p in ctx.sequence_patterns)]
        if not chosen:
            ids = sorted(s.sequence_id for s in seqs)
            raise SelectionError(f"--sequences {','.join(ctx.sequence_patterns)} matches none of the "
                                 f"{len(ids)} sequences ({', '.join(ids[:4])}{', ...' if len(ids) > 4 else ''})")
        seqs = chosen
    return sorted(seqs, key=lambda s: s.sequence_id)

