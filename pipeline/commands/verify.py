"""``carlaocc verify``: re-hash every recorded output against its lineage fingerprint.

``status`` and ``run`` trust a recorded fingerprint while the output's stat signature (size,
modification time and inode, or the object store's ETag: :mod:`carlaocc.catalog.signatures`) is
unchanged, so they read no chunk data. Verification is the explicit, expensive check: every
output of the latest completed record of every partition is read and hashed again, and what no
longer matches is listed (damaged: cannot be read; modified: other bytes; missing).

An intact output whose signature moved (a root copied or restored from a backup keeps its bytes
but not its inodes and times) has its new signature recorded in lineage (a record of the same
run with the new signatures, under a ``verify-<time>`` lineage file), so the next ``status`` is
cheap again; a damaged one has its signatures dropped from lineage the same way, so the next
``status`` re-hashes it and says why, and ``run`` rebuilds it. Nothing else is written.
"""

from __future__ import annotations

import json
import uuid
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Callable

from carlaocc.catalog.lineage import LineageLog
from carlaocc.catalog.lock import root_lock
from carlaocc.catalog.signatures import output_signatures
from carlaocc.catalog.store import Store
from carlaocc.pipeline.engine.runner import outputs_problem


@dataclass
class StageVerification:
    """What verifying one stage's recorded outputs found."""

    stage: str
    partitions: int = 0
    outputs: int = 0
    problems: dict[str, str] = field(default_factory=dict)  # partition -> why it is not intact
    resigned: int = 0  # intact partitions whose signatures were recorded anew


def verify(store: Store, stages: tuple[str, ...] = (), record: bool = True,
           advance: Callable[[str, int], None] = lambda stage, total: None) -> list[StageVerification]:
    """Re-hash the outputs of every partition's latest completed record (of ``stages``; empty:
    every stage in lineage; a retired partition, whose outputs a stage removed when it stopped
    owning them, is not checked). ``advance(stage, total)`` is called once per partition checked.
    With ``record``, intact partitions whose stat signatures moved get them recorded again."""
    lineage = LineageLog(store)
    names = sorted({r.stage for r in lineage.load()}) if not stages else list(stages)
    out = []
    run_id = "verify-" + datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%S%fZ") + "-" + uuid.uuid4().hex[:6]
    for stage in names:
        found = StageVerification(stage)
        out.append(found)
        latest = [r for r in lineage.latest(stage).values() if r.status == "completed"]
        resigned = []  # (the record verified, its re-signed copy)
        checked: dict[str, str | None] = {}
        for rec in sorted(latest, key=lambda r: r.partition):
            outputs = json.loads(rec.output_fingerprints)
            found.partitions += 1
            found.outputs += len(outputs)
            # no signatures given: every output is read and hashed
            problem = outputs_problem(store, outputs, checked)
            advance(stage, len(latest))
            if problem is not None:
                found.problems[rec.partition] = problem
                if record and rec.output_signatures:
                    # its signatures are trusted no more: status and run re-hash it and rebuild
                    resigned.append((rec, rec.model_copy(update={"run_id": rec.run_id + "~" + run_id,
                                                                 "output_signatures": ""})))
                continue
            now = json.dumps(output_signatures(store, outputs), sort_keys=True)
            if record and now != rec.output_signatures:
                # a record later than the one it copies (lineage orders by run id): "verify-" sorts
                # after the driver's timestamps, so keep the run id and sort by a suffix instead
                resigned.append((rec, rec.model_copy(update={"run_id": rec.run_id + "~" + run_id,
                                                             "output_signatures": now})))
                found.resigned += 1
        if resigned:
            # written as a writer of the root, and only over records still the latest (a run may
            # have rebuilt or retired a partition while it was being verified)
            with root_lock(store):
                now_latest = lineage.latest(stage)
                keep = [new for rec, new in resigned
                        if (cur := now_latest.get(rec.partition)) is not None and cur.run_id == rec.run_id]
                if keep:
                    lineage.append(stage, run_id, keep)
    return out
