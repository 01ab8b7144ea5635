"""Run stages as Dask tasks with incremental re-runs and lineage.

Stages run in dependency order; each stage's partitions are submitted as one batch of Dask tasks
(so a stage's cache keys can include the fingerprints of what its upstream tasks just wrote).
A partition is skipped when its latest lineage record is completed, has the same cache key
(stage, code version, config hash, partition, input fingerprints) and its outputs are intact.
"""

from __future__ import annotations

import hashlib
import json
import time
import uuid
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Callable

import fsspec
import numpy as np

from carlaocc.catalog.lineage import DAMAGED_SUFFIX, LineageLog
from carlaocc.catalog.lock import RootBusy, root_lock
from carlaocc.catalog.parquet import parquet_problem
from carlaocc.catalog.signatures import external_signature, output_signature
from carlaocc.catalog.store import Store, StoreError, fingerprint_bytes
from carlaocc.catalog.zarrio import ancestor_groups, frame_fingerprint, is_damaged, metadata_problem, parse_frame_key
# where tasks run (pipeline/engine/executors.py; callers and tests reach these as runner.X too)
from carlaocc.pipeline.engine.executors import (NANNY_TERMINATE, SYNCHRONOUS, TASK_BASE_BYTES,  # noqa: F401
                                                TASK_BYTES_PER_VOXEL, DaskExecutor, Executor, SynchronousExecutor,
                                                TaskResult, execute_task, local_workers, make_executor,
                                                resolve_scheduler, task_memory)
from carlaocc.pipeline.engine.registry import RETIRED_STAGES, STAGES
from carlaocc.pipeline.engine.spec import (Context, Partition, PlanError, Prepared, SelectionError,  # noqa: F401
                                           StageSpec, UpstreamMissing, cache_key)
from carlaocc.schemas.configs import DatasetConfig
from carlaocc.schemas.records import RunRecord

_LINEAGE_FLUSH_SECONDS = 20.0


# -- planning -------------------------------------------------------------------------------------
@dataclass
class PartitionPlan:
    partition: Partition
    cache_key: str
    input_fingerprints: dict[str, str]
    reason: str | None  # None: up to date
    input_signatures: dict[str, str] = field(default_factory=dict)  # external file -> signature


@dataclass
class StagePlan:
    stage: StageSpec
    partitions: list[PartitionPlan] = field(default_factory=list)
    blocked: str | None = None  # why it cannot be planned yet

    @property
    def to_run(self) -> list[PartitionPlan]:
        return [p for p in self.partitions if p.reason is not None]


def _digest(outputs: str) -> str:
    return hashlib.sha256(outputs.encode()).hexdigest()[:24]


def file_fingerprint(path: str) -> str:
    """Fingerprint of an external input file (a local path or fsspec URL); "missing" if absent."""
    try:
        fs, p = fsspec.core.url_to_fs(path)
        if fs.isfile(p) is False and fs.exists(p):
            return "not a regular file"
        return fingerprint_bytes(fs.cat_file(p))
    except FileNotFoundError:
        return "missing"
    except OSError as exc:  # a link loop, no permission...: the task reports it
        return f"unreadable: {exc.strerror or exc}"


def outputs_problem(store: Store, outputs: dict[str, str],
                    checked: dict[str, str | None] | None = None,
                    signatures: dict[str, str] | None = None) -> str | None:
    """Why recorded outputs are not intact, or None when every one still has its recorded
    fingerprint (files by their bytes, Zarr frames by their encoded chunks): ``outputs damaged:
    <path> unreadable`` for a Zarr frame whose metadata (its array's, a group's above it) or a
    chunk cannot be read, or a Parquet file that cannot; else ``outputs missing or modified``.
    ``checked`` caches the Zarr groups' verdicts between calls.

    With the outputs' recorded stat ``signatures`` (:mod:`carlaocc.catalog.signatures`), an output
    whose signature is unchanged keeps its recorded fingerprint without being read (a Zarr frame's
    groups' small metadata are still checked); only the others are re-hashed."""
    modified = False
    checked = {} if checked is None else checked
    signatures = signatures or {}
    for key, fp in outputs.items():
        frame = parse_frame_key(key)  # a frame of an array of occupancy.zarr, sensors.zarr...
        if key in signatures and output_signature(store, key) == signatures[key]:
            if frame is None:
                continue
            problem = None
            for group in ancestor_groups(frame[0], frame[1]):
                if group not in checked:
                    checked[group] = metadata_problem(store, group, "group")
                if checked[group] is not None:
                    problem = f"outputs damaged: {group}/zarr.json {checked[group]}"
                    break
            if problem is None:
                continue
            return problem
        try:
            current = store.fingerprint(key) if frame is None else frame_fingerprint(store, *frame, checked=checked)
        except OSError:  # a directory where a file was, no permission...
            return f"outputs damaged: {key} unreadable"
        if current == fp:
            continue
        if is_damaged(current):
            return "outputs " + current  # "outputs damaged: <path> unreadable"
        if current is not None and key.endswith(".parquet") and parquet_problem(store, key) == "unreadable":
            return f"outputs damaged: {key} unreadable"
        modified = True
    return "outputs missing or modified" if modified else None


def outputs_intact(store: Store, outputs: dict[str, str]) -> bool:
    """Every recorded output still has its recorded fingerprint (see :func:`outputs_problem`)."""
    return outputs_problem(store, outputs) is None


def _lineage_note(lineage: LineageLog, stage: str) -> str | None:
    """``lineage unreadable: <path>`` (and how many more) when a lineage file of the stage could
    not be read: the partitions it recorded look never run."""
    bad = lineage.damaged_files(stage)
    if not bad:
        return None
    return f"lineage unreadable: {bad[0]}" + (f" (+{len(bad) - 1} more)" if len(bad) > 1 else "")


def plan_stage(spec: StageSpec, ctx: Context, lineage: LineageLog, force: bool,
               stale_upstream: dict[str, set[str]]) -> StagePlan:
    """Cache keys and staleness reasons of every partition of a stage.

    Damage is staleness, never an exception: outputs that cannot be read make their partition
    stale (``outputs damaged: <path> unreadable``), an unreadable lineage file of the stage makes
    the partitions with no readable record stale (``lineage unreadable: <path>``), and an
    upstream table that cannot be read while partitioning blocks the stage with its path."""
    plan = StagePlan(spec)
    try:
        partitions = spec.partitions(ctx)
    except UpstreamMissing as exc:
        plan.blocked = str(exc)
        return plan
    except SelectionError as exc:  # a usage error, before anything runs
        raise PlanError(str(exc)) from None
    except StoreError as exc:  # an upstream output it partitions by is damaged: the upstream re-runs
        plan.blocked = str(exc)
        return plan
    code, chash = spec.code_version(), spec.config_hash(ctx.config)
    latest = lineage.latest(spec.name)
    upstream_latest = {s: lineage.latest(s) for s in spec.upstream}
    never_run = _lineage_note(lineage, spec.name) or "never run"
    checked: dict[str, str | None] = {}
    for p in partitions:
        inputs, waiting = {}, None
        for up_stage, up_key in p.needs:
            rec = upstream_latest.get(up_stage, {}).get(up_key)
            if rec is None or rec.status != "completed":
                waiting = waiting or f"upstream {up_stage}/{up_key} has not completed"
                continue
            if up_key in stale_upstream.get(up_stage, set()):
                waiting = waiting or f"upstream {up_stage}/{up_key} is stale"
            inputs[f"{up_stage}/{up_key}"] = _digest(rec.output_fingerprints)
        # external input files (a source mesh, a category map) by their bytes, or by the
        # fingerprint the last run recorded while the file's stat signature is unchanged
        rec = latest.get(p.key)
        known_fp = json.loads(rec.input_fingerprints) if rec is not None and rec.input_signatures else {}
        known_sig = json.loads(rec.input_signatures) if rec is not None and rec.input_signatures else {}
        signatures = {}
        for path in p.files:
            name, sig = f"file:{path}", external_signature(path)
            if sig is not None:
                signatures[name] = sig
            if sig is not None and known_sig.get(name) == sig and name in known_fp:
                inputs[name] = known_fp[name]
            else:
                inputs[name] = file_fingerprint(path)
        key = cache_key(spec.name, code, chash, p, inputs)
        if waiting:
            reason = waiting
        elif force:
            reason = "forced"
        elif rec is None:
            reason = never_run
        elif rec.status == "retired":
            reason = "outputs removed (the partition was retired)"
        elif rec.status != "completed":
            reason = f"last run failed: {rec.error}"
        elif rec.cache_key == key:
            reason = outputs_problem(ctx.store, json.loads(rec.output_fingerprints), checked,
                                     json.loads(rec.output_signatures) if rec.output_signatures else None)
        elif rec.code_version != code:
            reason = "code changed"
        elif rec.config_hash != chash:
            reason = "config changed"
        else:
            reason = "inputs changed"
        plan.partitions.append(PartitionPlan(p, key, inputs, reason, signatures))
    return plan


def retire_orphans(lineage: LineageLog, stage: str, planned: set[str], removed: frozenset[str]) -> list[RunRecord]:
    """Append a ``retired`` record for every partition of ``stage`` that is no longer planned and
    whose latest record names an output in ``removed`` (what the stage's ``prepare`` deleted: no
    partition owns it any more); returns them. Retired partitions are never planned again nor
    verified; their outputs are gone."""
    if not removed:
        return []
    retired = []
    for key, rec in sorted(lineage.latest(stage).items()):
        if rec.status == "retired" or key in planned:
            continue
        outputs = json.loads(rec.output_fingerprints) if rec.output_fingerprints else {}
        if removed.intersection(outputs):
            retired.append(rec.model_copy(update={
                "run_id": rec.run_id + "~retired", "status": "retired", "output_fingerprints": "{}",
                "output_signatures": "", "error": "no partition owns its outputs any more: removed"}))
    if retired:
        lineage.append(stage, f"retired-{uuid.uuid4().hex}", retired)
    return retired


def stage_order(names: list[str] | None, registry: dict[str, StageSpec] | None = None) -> list[StageSpec]:
    """Registered stages in dependency order, optionally restricted to ``names`` (validated; a
    retired name, e.g. ``metrics``, is refused with the name it became)."""
    registry = STAGES if registry is None else registry
    if names:
        retired = [n for n in names if n in RETIRED_STAGES and n not in registry]
        if retired:
            new = RETIRED_STAGES[retired[0]]
            raise PlanError(f"stage {retired[0]!r} was renamed {new!r}: use --stages {new}")
        unknown = [n for n in names if n not in registry]
        if unknown:
            raise PlanError(f"unknown stage {unknown[0]!r} (stages: {', '.join(registry)})")
    return [s for s in registry.values() if not names or s.name in names]


def status(store: Store, config: DatasetConfig, voxel_sizes: tuple[float, ...],
           sequences: tuple[str, ...] = ()) -> list[StagePlan]:
    """Plan every stage without running anything (what is stale and why), for the sequences
    matching ``sequences`` (fnmatch patterns; empty: all)."""
    ctx, lineage = Context(store, config, voxel_sizes, tuple(sequences)), LineageLog(store)
    plans, stale = [], {}
    for spec in stage_order(None):
        plan = plan_stage(spec, ctx, lineage, False, stale)
        stale[spec.name] = {pp.partition.key for pp in plan.to_run}
        plans.append(plan)
    return plans


# -- running --------------------------------------------------------------------------------------
@dataclass
class StageOutcome:
    stage: str
    total: int
    ran: int = 0
    skipped: int = 0
    failed: list[TaskResult] = field(default_factory=list)
    seconds: float = 0.0


class Progress:
    """Progress callbacks; the CLI renders them as a bar, tests pass a silent one."""

    def start(self, stage: str, total: int) -> None: ...
    def advance(self, stage: str) -> None: ...
    def stop(self, stage: str) -> None: ...


def _os_reason(exc: BaseException) -> str:
    """An OSError's reason in words (``No space left on device``), else the exception's line."""
    if getattr(exc, "strerror", None):
        return exc.strerror
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


def _lineage_write_error(store: Store, failure: tuple[str, BaseException], unrecorded: int,
                         failed: list[TaskResult]) -> "LineageWriteError":
    path, exc = failure
    first = (f"; the first failed task: {failed[0].stage} {failed[0].partition}: {failed[0].error}"
             if failed else "")
    return LineageWriteError(f"cannot record lineage in {store.uri(path)}: {_os_reason(exc)}; {unrecorded} "
                             f"finished tasks are not recorded and run again next time{first}")


class LineageWriteError(StoreError):
    """The driver could not record what its tasks did (a full disk, no permission): the message
    names the lineage file and keeps the first failed task's own error."""


def run(store: Store, config: DatasetConfig, voxel_sizes: tuple[float, ...],
        stages: list[str] | None = None, scheduler: str | None = None, force: bool = False,
        progress: Progress | None = None, workers: int | None = None,
        log: Callable[[str], None] = lambda s: None,
        registry: dict[str, StageSpec] | None = None, sequences: tuple[str, ...] = (),
        wait: bool = True) -> list[StageOutcome]:
    """Run the selected stages (all by default) of ``registry`` (the registered stages by
    default) in order, the per-sequence ones for the sequences matching ``sequences`` (fnmatch
    patterns on sequence ids; empty: all); stops after a stage with failures.

    Holds the root's writer lock throughout (:func:`carlaocc.catalog.lock.root_lock`): with another
    command writing the root, waits for it (saying so through ``log``), or with ``wait=False``
    raises :class:`PlanError` naming it before anything is read or written."""
    try:
        with root_lock(store, wait=wait, on_wait=log):
            return _run_locked(store, config, voxel_sizes, stages, scheduler, force, progress, workers, log,
                               registry, sequences)
    except RootBusy as exc:
        raise PlanError(str(exc)) from None


def _run_locked(store, config, voxel_sizes, stages, scheduler, force, progress, workers, log, registry,
                sequences) -> list[StageOutcome]:
    progress = progress or Progress()
    selected = stage_order(stages, registry)
    ctx, lineage = Context(store, config, voxel_sizes, tuple(sequences)), LineageLog(store)
    scheduler = resolve_scheduler(scheduler)
    # stages not selected but upstream of a selected one: what of theirs is stale blocks the run
    stale: dict[str, set[str]] = {}
    names = {s.name for s in selected}
    for spec in stage_order(None, registry):
        if spec.name in names:
            break
        upstream_plan = plan_stage(spec, ctx, lineage, False, stale)
        stale[spec.name] = {pp.partition.key for pp in upstream_plan.to_run}
    # the run's sequence number in the root orders its records (lineage's "latest"), not a clock
    run_id, clock_note = lineage.new_run_id(datetime.now(timezone.utc))
    if clock_note:
        log(f"note: {clock_note}")
    executor: Executor | None = None
    outcomes: list[StageOutcome] = []
    try:
        for spec in selected:
            t_plan = time.perf_counter()
            plan = plan_stage(spec, ctx, lineage, force, stale)
            t_plan = time.perf_counter() - t_plan
            if plan.blocked:
                raise PlanError(f"cannot run {spec.name}: {plan.blocked} "
                                f"(run the upstream stages first: {', '.join(spec.upstream)})")
            waiting = [pp for pp in plan.partitions if pp.reason and pp.reason.startswith("upstream")]
            if waiting:
                raise PlanError(f"cannot run {spec.name}/{waiting[0].partition.key}: {waiting[0].reason} "
                                f"(run it first, or add it to --stages)")
            stale[spec.name] = set()  # it runs now: downstream stages see it fresh
            todo = plan.to_run
            outcome = StageOutcome(spec.name, len(plan.partitions), skipped=len(plan.partitions) - len(todo))
            outcomes.append(outcome)
            for moved in lineage.set_aside(spec.name):  # its partitions were planned as never run
                log(f"{spec.name}: lineage file {moved.removesuffix(DAMAGED_SUFFIX)} cannot be read: set aside "
                    f"as {moved}; the partitions it recorded are rebuilt")
            log(f"{spec.name}: planned {outcome.total} partitions in {t_plan:.2f} s")
            if not todo:
                log(f"{spec.name}: {outcome.total} up to date, nothing to do")
                continue
            t0 = time.perf_counter()
            if spec.prepare is not None:
                # creating outputs may invalidate partitions planned as done (a replaced array)
                prepared = spec.prepare(ctx, [pp.partition for pp in todo], [pp.partition for pp in plan.partitions])
                if not isinstance(prepared, Prepared):
                    prepared = Prepared(invalid=frozenset(prepared))
                invalid = prepared.invalid
                # outputs removed because no partition owns them: their partitions' lineage says so
                retire_orphans(lineage, spec.name, {pp.partition.key for pp in plan.partitions}, prepared.removed)
                for pp in plan.partitions:
                    if pp.reason is None and pp.partition.key in invalid:
                        pp.reason = "array re-created"
                        todo.append(pp)
                        outcome.skipped -= 1
            by_key = {pp.partition.key: pp for pp in todo}
            code, chash = spec.code_version(), spec.config_hash(config)
            pending: list[RunRecord] = []
            last_flush = [time.monotonic(), 0]
            lineage_error: list[tuple[str, OSError | StoreError]] = []  # the last failed write, if any

            def flush() -> None:
                # records not written stay pending for the next flush (a disk that fills up, then
                # frees): the work goes on; the run fails at the end if they never could be written
                if pending:
                    key = f"stage={spec.name}/{run_id}-{last_flush[1]:04d}"
                    try:
                        lineage.append(spec.name, f"{run_id}-{last_flush[1]:04d}", list(pending))
                    except (OSError, StoreError) as exc:
                        lineage_error[:] = [(lineage.table.path(key), exc)]
                    else:
                        pending.clear()
                        lineage_error.clear()
                        last_flush[1] += 1
                last_flush[0] = time.monotonic()

            def on_done(res: TaskResult) -> None:
                pp = by_key[res.partition]
                pending.append(RunRecord(
                    run_id=run_id, stage=spec.name, partition=res.partition, code_version=code,
                    config_hash=chash, cache_key=pp.cache_key,
                    input_fingerprints=json.dumps(pp.input_fingerprints, sort_keys=True),
                    output_fingerprints=json.dumps(res.outputs, sort_keys=True),
                    status=res.status, started_at=res.started_at, ended_at=res.ended_at,
                    host=res.host, error=res.error,
                    output_signatures=json.dumps(res.signatures, sort_keys=True),
                    input_signatures=json.dumps(pp.input_signatures, sort_keys=True),
                ))
                if res.status == "completed":
                    outcome.ran += 1
                else:
                    outcome.failed.append(res)
                progress.advance(spec.name)
                if time.monotonic() - last_flush[0] > _LINEAGE_FLUSH_SECONDS:
                    flush()

            if executor is None:
                # workers sized for the finest grid's tasks (a 0.05 m task needs ~5 GB)
                finest = config.voxelize.grid(min(voxel_sizes)) if voxel_sizes else None
                executor = make_executor(scheduler, store, workers,
                                         task_memory(int(np.prod(finest.shape))) if finest else None, log=log)
            progress.start(spec.name, len(todo))
            try:
                executor.map(spec, store.url, spec.config(config), [pp.partition for pp in todo], on_done)
            finally:
                flush()
                if not lineage_error:
                    try:
                        # the run's lineage files of the stage as one (and the stage's, past 64 files)
                        lineage.compact_run(spec.name, run_id)
                    except (OSError, StoreError) as exc:  # the per-flush files hold every record
                        log(f"{spec.name}: lineage files not merged ({_os_reason(exc)}); they are read as they are")
                progress.stop(spec.name)
            if lineage_error:
                raise _lineage_write_error(store, lineage_error[0], len(pending), outcome.failed)
            if isinstance(executor, DaskExecutor):
                log(f"{spec.name}: first {min(len(todo), executor.in_flight())} of {len(todo)} tasks submitted in "
                    f"{executor.submit_seconds:.2f} s (at most {executor.in_flight()} in the scheduler at once)")
            outcome.seconds = time.perf_counter() - t0
            log(f"{spec.name}: ran {outcome.ran}, skipped {outcome.skipped} up to date, "
                f"failed {len(outcome.failed)} ({outcome.seconds:.1f} s)")
            if outcome.failed:
                break
    finally:
        if executor is not None:
            executor.close()
    return outcomes
