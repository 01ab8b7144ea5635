"""Lineage records: Parquet files under ``catalog/runs/stage=<stage>/``.

The driver writes what finished every few seconds (one file per flush, never one per task), then
merges a stage's files of the run into one (:meth:`LineageLog.compact_run`); once a stage holds
more than :data:`COMPACT_FILES` files, they are merged into one as well (:meth:`LineageLog.compact`),
so 100 K tasks and many runs stay a handful of files. Merging keeps every record: the merged file
is written (atomically) before its sources are removed, so a crash in between leaves records
twice, which :meth:`LineageLog.latest` reads as once.

A lineage file that cannot be read (truncated, garbage bytes) never stops a run or ``status``:
it is left out of what is loaded and listed in :attr:`LineageLog.damaged` (its path and why), so
the partitions it recorded look never run and are rebuilt; a run sets it aside
(:meth:`LineageLog.set_aside`: renamed ``<file>.damaged``, never deleted) before writing the
stage's new records.
"""

from __future__ import annotations

import posixpath
import re
import typing
import uuid
from datetime import datetime

from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.store import Store, StoreError
from carlaocc.schemas.records import RunRecord

DAMAGED_SUFFIX = ".damaged"
# a run id: r<sequence>-<UTC time>-<random>; ids of roots built before sequences were UTC times
_RUN_SEQUENCE = re.compile(r"(?:^|[-~])r(\d{8,})-")
_RUN_TIME = re.compile(r"(?:^|[-~r])(\d{8}T\d{6})")
COMPACT_FILES = 64  # a stage with more lineage files than this has them merged into one


class LineageLog:
    """Read and append lineage records of a store."""

    def __init__(self, store: Store):
        self.table = ParquetTable(store, RunRecord)
        # store-relative path -> why it cannot be read, for the files met by load()
        self.damaged: dict[str, str] = {}

    def append(self, stage: str, run_id: str, records: typing.Sequence[RunRecord]) -> str | None:
        """Write a run's records of one stage (nothing when there are none)."""
        if not records:
            return None
        return self.table.save(f"stage={stage}/{run_id}", records)

    def _stage_dir(self, stage: str) -> str:
        return f"{self.table.dir}/stage={stage}/"

    def load(self, stage: str | None = None) -> list[RunRecord]:
        """Every readable record (of one stage); files that cannot be read are skipped and
        noted in :attr:`damaged`."""
        prefix = None if stage is None else self._stage_dir(stage)
        for _ in range(3):
            out: list[RunRecord] = []
            vanished = False
            for path in self.table.paths():
                if prefix is not None and not path.startswith(prefix):
                    continue
                key = path[len(self.table.dir) + 1 : -len(".parquet")]
                try:
                    out.extend(self.table.load([key]))
                except StoreError:  # truncated, garbage bytes, another schema; or merged away
                    if not self.table.store.exists(path):
                        vanished = True  # a compaction merged it since the listing: list again
                        break
                    self.damaged[path] = "unreadable"
                except ValueError:  # rows that are not valid records
                    self.damaged[path] = "holds no valid lineage records"
            if not vanished:
                break
        return out

    def damaged_files(self, stage: str) -> list[str]:
        """The unreadable lineage files of a stage met so far (store-relative paths, sorted)."""
        return sorted(p for p in self.damaged if p.startswith(self._stage_dir(stage)))

    def set_aside(self, stage: str) -> list[str]:
        """Rename the unreadable lineage files of a stage met so far to ``<file>.damaged`` (kept
        for inspection, no longer read); returns their new store-relative paths."""
        moved = []
        for path in self.damaged_files(stage):
            target = path + DAMAGED_SUFFIX
            if self.table.store.exists(path):
                self.table.store.fs.mv(self.table.store.path(path), self.table.store.path(target))
                moved.append(target)
            del self.damaged[path]
        return moved

    def _files(self, stage: str) -> list[str]:
        """Store-relative paths of a stage's readable-looking lineage files."""
        prefix = self._stage_dir(stage)
        return [p for p in self.table.paths() if p.startswith(prefix)]

    def _merge(self, stage: str, paths: list[str], key: str | None) -> str | None:
        """Write the records of ``paths`` to ``stage=<stage>/<key>``, then remove the sources
        (an unreadable one is left alone for :meth:`set_aside`)."""
        records, merged = [], []
        for path in paths:
            try:
                records.extend(self.table.load([path[len(self.table.dir) + 1:-len(".parquet")]]))
                merged.append(path)
            except (StoreError, ValueError):
                continue
        if len(merged) < 2:
            return None
        # a merge cut short leaves its output beside its sources: one record per (run, partition)
        records = list({(r.run_id, r.partition): r for r in records}.values())
        records.sort(key=lambda r: (r.run_id, r.partition))
        # a stage's merged file is named after the newest run it holds (the file names themselves
        # may be earlier merges')
        key = key or f"compacted-{records[-1].run_id}"
        written = self.table.save(f"stage={stage}/{key}", records)
        target = self.table.path(f"stage={stage}/{key}")
        for path in merged:
            if path != target:
                self.table.store.remove(path)
        return written

    def compact_run(self, stage: str, run_id: str) -> None:
        """Merge the files one run wrote for a stage (one per flush) into ``<run_id>.parquet``,
        then the stage's files into one when there are more than :data:`COMPACT_FILES`."""
        prefix = f"{self._stage_dir(stage)}{run_id}-"
        self._merge(stage, [p for p in self._files(stage) if p.startswith(prefix)], run_id)
        self.compact(stage)

    def compact(self, stage: str, max_files: int = COMPACT_FILES) -> bool:
        """Merge a stage's lineage files into one (``compacted-<last run id>.parquet``) when it has
        more than ``max_files``; every record is kept. True when it merged."""
        files = self._files(stage)
        if len(files) <= max_files:
            return False
        return self._merge(stage, files, None) is not None

    def new_run_id(self, now: datetime) -> tuple[str, str | None]:
        """The id of a new run, ``r<sequence>-<UTC time>-<random>``, and a note when ``now`` is
        earlier than the newest run recorded (a clock set back, hosts that disagree on time).

        The sequence is one past the highest in the root's lineage file names (a listing, no
        file read), so run ids sort in the order runs were made whatever the clocks say: lineage's
        "latest" is the last written. Taken under the root lock
        (:func:`carlaocc.catalog.lock.root_lock`), two runs never get one number. Ids of roots
        built before sequences (UTC times, digits first) sort before every ``r`` id."""
        sequence, newest = 0, ""
        for path in self.table.paths():
            name = posixpath.basename(path)
            for m in _RUN_SEQUENCE.finditer(name):
                sequence = max(sequence, int(m.group(1)))
            for m in _RUN_TIME.finditer(name):
                newest = max(newest, m.group(1))
        stamp = now.strftime("%Y%m%dT%H%M%S%fZ")
        note = None
        if newest and stamp[:15] < newest:
            when = datetime.strptime(newest, "%Y%m%dT%H%M%S").strftime("%Y-%m-%d %H:%M:%S")
            note = (f"this host's clock ({now:%Y-%m-%d %H:%M:%S} UTC) is behind the newest run recorded in the "
                    f"root ({when} UTC): runs are ordered by their sequence number, never by clocks")
        return f"r{sequence + 1:08d}-{stamp}-{uuid.uuid4().hex[:6]}", note

    def latest(self, stage: str) -> dict[str, RunRecord]:
        """The most recent record of every partition of a stage (completed or failed), ordered by
        run id (the run's sequence number, :meth:`new_run_id`), never by any clock."""
        out: dict[str, RunRecord] = {}
        for rec in sorted(self.load(stage), key=lambda r: r.run_id):
            out[rec.partition] = rec
        return out
