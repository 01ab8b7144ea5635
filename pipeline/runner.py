"""Run stages as Dask tasks with incremental re-runs and lineage.

Stages run in dependency order; each stage's partitions are submitted as one batch of Dask tasks
(so a stage's cache keys can include the fingerprints of what its upstream tasks just wrote).
A partition is skipped when its latest lineage record is completed, has the same cache key
(stage, code version, config hash, partition, input fingerprints) and its outputs are intact.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import socket
import time
import traceback
import uuid
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Callable

import numpy as np

from carlaocc.catalog.lineage import DAMAGED_SUFFIX, LineageLog
from carlaocc.catalog.parquet import parquet_problem
from carlaocc.catalog.signatures import external_signature, output_signature, output_signatures
from carlaocc.catalog.store import Store, StoreError
from carlaocc.catalog.zarrio import ancestor_groups, frame_fingerprint, is_damaged, metadata_problem, parse_frame_key
from carlaocc.pipeline.registry import STAGE_ALIASES, STAGES
from carlaocc.pipeline.spec import Context, Partition, SelectionError, StageSpec, UpstreamMissing, cache_key
from carlaocc.schemas.configs import DatasetConfig, StageConfig
from carlaocc.schemas.records import RunRecord

SYNCHRONOUS = "synchronous"
_LINEAGE_FLUSH_SECONDS = 20.0


class PlanError(Exception):
    """The requested run cannot be planned (unknown stage, upstream never run...): exit code 2."""


# -- one task -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TaskResult:
    stage: str
    partition: str
    status: str
    outputs: dict[str, str]
    error: str
    started_at: datetime
    ended_at: datetime
    host: str
    signatures: dict[str, str] = field(default_factory=dict)  # output key -> stat signature


def execute_task(task: Callable, stage: str, store_url: str, cfg: StageConfig, partition: Partition,
                 kernel_threads: int | None = None) -> TaskResult:
    """Run one partition of a stage; never raises (a failure is a result with its error).

    ``kernel_threads`` caps the kernels' threads in this process (numba, open3d, OpenCV: see
    :mod:`carlaocc.stages.threads`): a LocalCluster already runs one worker process per core, so its
    kernels run single-threaded instead of oversubscribing.
    """
    if kernel_threads:
        from carlaocc.stages.threads import set_kernel_threads

        set_kernel_threads(kernel_threads)
    started = datetime.now(timezone.utc)
    store, signatures = Store(store_url), {}
    try:
        outputs = task(store, cfg, partition)
        # what the store says about each output just written (no bytes read): status trusts
        # the fingerprints while these are unchanged
        signatures = output_signatures(store, outputs)
        status, error = "completed", ""
    except Exception as exc:  # recorded in lineage and reported with its partition
        outputs, status = {}, "failed"
        tb = traceback.extract_tb(exc.__traceback__)[-1]
        error = f"{type(exc).__name__}: {exc} (at {os.path.basename(tb.filename)}:{tb.lineno})"
    return TaskResult(stage, partition.key, status, outputs, error, started,
                      datetime.now(timezone.utc), socket.gethostname(), signatures)


# -- executors ------------------------------------------------------------------------------------
class Executor:
    """Runs a batch of tasks, calling ``on_done`` as each finishes."""

    def map(self, spec: StageSpec, store_url: str, cfg: StageConfig, partitions: list[Partition],
            on_done: Callable[[TaskResult], None]) -> None:
        raise NotImplementedError

    def close(self) -> None:
        pass


class SynchronousExecutor(Executor):
    """In-process, one task after another (debugging)."""

    def map(self, spec, store_url, cfg, partitions, on_done):
        for p in partitions:
            on_done(execute_task(spec.task, spec.name, store_url, cfg, p))


class DaskExecutor(Executor):
    """A distributed client: an existing scheduler's address, or a LocalCluster made on first use
    (processes for local stores; threads for ``memory://`` stores, which live in this process)."""

    def __init__(self, address: str | None, processes: bool, workers: int | None = None,
                 max_in_flight: int | None = None, memory_limit: int | None = None):
        self.address, self.processes, self.workers = address, processes, workers
        self.max_in_flight, self.memory_limit = max_in_flight, memory_limit
        self.submit_seconds = 0.0  # the last map's first batch
        self._client = None
        self._cluster = None
        # own LocalCluster of single-threaded worker processes: one kernel thread each
        self.kernel_threads = 1 if (address is None and processes) else None

    # schemes whose address is host:port (probed with a plain TCP connect before the Client)
    HOST_PORT_SCHEMES = ("tcp", "tls", "ws", "wss", "ucx")
    PROBE_SECONDS = 3.0  # the TCP connect probe: a refused or silent port fails in seconds
    CONNECT_SECONDS = "10s"  # the Client's handshake once the port answers
    # distributed's loggers silenced while our own LocalCluster shuts down (its workers' heartbeats
    # race the closing connection pool and log CommClosedError tracebacks otherwise)
    QUIET_LOGGERS = ("distributed", "distributed.worker", "distributed.core", "distributed.nanny",
                     "distributed.comm", "distributed.batched", "distributed.scheduler",
                     "distributed.client", "distributed.deploy", "distributed.process")

    @staticmethod
    def host_port(address: str) -> tuple[str, int] | None:
        """``(host, port)`` of a host:port scheduler address (None for other schemes such as
        inproc://); ValueError naming what is wrong when the host or port is missing or the port
        is not in 1..65535."""
        from distributed.comm.addressing import parse_address, parse_host_port

        scheme, loc = parse_address(address, strict=True)
        if scheme not in DaskExecutor.HOST_PORT_SCHEMES:
            return None
        if loc.startswith("[") and "]" in loc:
            host, _, port = loc[1:].partition("]")
            port = port.removeprefix(":") if port.startswith(":") else None
        else:
            host, sep, port = loc.rpartition(":")
            if not sep:
                host, port = loc, None
        if not port:
            raise ValueError("no port (e.g. tcp://127.0.0.1:8786)")
        if not host:
            raise ValueError("no host (e.g. tcp://127.0.0.1:8786)")
        if not port.isdigit():
            raise ValueError(f"port {port!r} is not a number")
        if not 1 <= int(port) <= 65535:
            raise ValueError(f"port {int(port)} is not in 1..65535")
        parse_host_port(loc)  # what distributed itself will parse
        return host, int(port)

    @staticmethod
    def probe(address: str, timeout: float | None = None) -> None:
        """A quick TCP connect to a host:port scheduler address; OSError (refused, unknown host,
        timed out) when nothing listens there."""
        hp = DaskExecutor.host_port(address)
        if hp is None:
            return
        with socket.create_connection(hp, timeout=DaskExecutor.PROBE_SECONDS if timeout is None else timeout):
            pass

    @staticmethod
    def quiet_logs() -> None:
        """Silence distributed's loggers in this process (run on our workers before teardown)."""
        for name in DaskExecutor.QUIET_LOGGERS:
            logging.getLogger(name).setLevel(logging.CRITICAL + 1)

    def _get_client(self):
        if self._client is None:
            from distributed import Client, LocalCluster

            if self.address:
                try:
                    self.probe(self.address)
                except (OSError, ValueError) as exc:
                    raise PlanError(f"cannot reach the Dask scheduler at {self.address}: "
                                    f"{exc.strerror or exc if isinstance(exc, OSError) else exc} "
                                    f"(is a `dask scheduler` running there?)") from None
                try:
                    self._client = Client(self.address, timeout=self.CONNECT_SECONDS)
                except (OSError, TimeoutError, ValueError) as exc:
                    raise PlanError(f"cannot reach the Dask scheduler at {self.address}: "
                                    f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None
            else:
                import dask

                n, limit = local_workers(self.workers, self.memory_limit)
                self.workers_started, self.worker_memory = n, limit
                # distributed starts worker processes with MALLOC_TRIM_THRESHOLD_=65536, so glibc
                # hands every freed block above 64 KiB back to the kernel: a task's per-frame
                # images and grids are then page-faulted in afresh each time (measured: the sensors
                # task 2.4x slower, mostly system time). Our workers keep glibc's default.
                environ = {k: v for k, v in dask.config.get("distributed.nanny.pre-spawn-environ", {}).items()
                           if k != "MALLOC_TRIM_THRESHOLD_"}
                with dask.config.set({"distributed.nanny.pre-spawn-environ": environ}):
                    self._cluster = LocalCluster(
                        n_workers=n, threads_per_worker=1, processes=self.processes,
                        # each worker's share of the machine, sized so the nanny (which kills a
                        # worker at 95 % of its limit) leaves the finest task room: local_workers
                        memory_limit=limit,
                        # the scheduler's HTTP server (health, metrics) on a free port: the
                        # default 8787 taken by another cluster warns on stderr
                        dashboard_address=None,
                        scheduler_kwargs={"dashboard": False, "dashboard_address": "127.0.0.1:0"},
                        silence_logs=logging.ERROR,
                    )
                self._client = Client(self._cluster)
        return self._client

    # tasks in the scheduler at once, per worker thread: enough to keep every worker busy while
    # results come back, few enough that 100 K partitions never make a 100 K-task graph
    IN_FLIGHT_PER_THREAD = 4
    MIN_IN_FLIGHT = 16

    def in_flight(self) -> int:
        """How many tasks the driver keeps submitted at once (a bounded graph in the scheduler):
        :attr:`IN_FLIGHT_PER_THREAD` per worker thread the cluster has now, at least
        :attr:`MIN_IN_FLIGHT` (workers that join later are fed as tasks finish)."""
        if self.max_in_flight:
            return self.max_in_flight
        threads = sum(self._get_client().nthreads().values())
        return max(self.MIN_IN_FLIGHT, self.IN_FLIGHT_PER_THREAD * threads)

    def map(self, spec, store_url, cfg, partitions, on_done):
        from distributed import as_completed

        stage = spec.name
        client = self._get_client()
        todo = iter(partitions)
        futures = {}

        def submit(p: Partition):
            fut = client.submit(execute_task, spec.task, stage, store_url, cfg, p, self.kernel_threads, pure=False,
                                key=f"{stage}-{p.key}-{uuid.uuid4().hex[:8]}")
            futures[fut] = p
            return fut

        # the first batch, then one new task for each that finishes
        t0 = time.perf_counter()
        first = [submit(p) for _, p in zip(range(self.in_flight()), todo)]
        self.submit_seconds = time.perf_counter() - t0
        done = as_completed(first)
        for fut in done:
            p = futures.pop(fut)
            try:
                result = fut.result()
            except Exception as exc:  # the worker died (e.g. out of memory)
                now = datetime.now(timezone.utc)
                result = TaskResult(stage, p.key, "failed", {}, f"{type(exc).__name__}: {exc}",
                                    now, now, "?")
            fut.release()
            nxt = next(todo, None)
            if nxt is not None:
                done.add(submit(nxt))
            on_done(result)

    def close(self):
        """Close the client, then our own LocalCluster, with distributed's logs silenced in our
        workers and here while they shut down, so a finished run ends quietly."""
        import contextlib

        client, cluster = self._client, self._cluster
        self._client = self._cluster = None
        if cluster is None:  # someone else's scheduler: only our client goes
            if client is not None:
                with contextlib.suppress(Exception):
                    client.close()
            return
        saved = {name: logging.getLogger(name).level for name in self.QUIET_LOGGERS}
        try:
            if client is not None:
                with contextlib.suppress(Exception):
                    # in each worker process; a dead or hung worker neither raises nor waits long
                    client.run(DaskExecutor.quiet_logs, on_error="ignore", callback_timeout=5)
            self.quiet_logs()
            if client is not None:
                with contextlib.suppress(Exception):
                    client.close()
            with contextlib.suppress(Exception):
                cluster.close()
        finally:
            for name, level in saved.items():
                logging.getLogger(name).setLevel(level)


def resolve_scheduler(scheduler: str | None, probe: bool = False) -> str | None:
    """``--scheduler``, else ``$DASK_SCHEDULER_ADDRESS``, validated: 'synchronous', a Dask
    address (tcp://host:port with a port in 1..65535, ...) or None for a LocalCluster. Raises
    PlanError when malformed, or (``probe``) when a quick TCP connect finds nothing listening."""
    from_env = not scheduler
    scheduler = scheduler or os.environ.get("DASK_SCHEDULER_ADDRESS") or None
    if scheduler is None or scheduler == SYNCHRONOUS:
        return scheduler
    from distributed.comm.addressing import parse_address

    source = "DASK_SCHEDULER_ADDRESS" if from_env else "--scheduler"
    try:
        scheme, loc = parse_address(scheduler, strict=True)
    except ValueError as exc:
        raise PlanError(f"{source} {scheduler!r} is not a Dask scheduler address "
                        f"(e.g. tcp://127.0.0.1:8786) nor 'synchronous': {exc}") from None
    if not loc:
        raise PlanError(f"{source} {scheduler!r} has no host:port")
    from distributed.comm.registry import get_backend

    try:
        get_backend(scheme)
    except ValueError:
        raise PlanError(f"{source} {scheduler!r}: unknown protocol {scheme!r} (e.g. tcp://)") from None
    try:
        DaskExecutor.host_port(scheduler)
    except ValueError as exc:
        raise PlanError(f"{source} {scheduler!r} is a malformed scheduler address: {exc}") from None
    if probe:
        try:
            DaskExecutor.probe(scheduler)
        except OSError as exc:
            why = "timed out" if isinstance(exc, TimeoutError) else (exc.strerror or str(exc) or type(exc).__name__)
            raise PlanError(f"{source} {scheduler}: cannot reach a Dask scheduler there ({why}); start one "
                            f"(`dask scheduler`), fix the address, or leave {source} out for a local "
                            f"cluster") from None
    return scheduler


# a task's peak resident memory per voxel of the finest grid, and its fixed part (Python, numba,
# the scene mesh): measured 4.0 GB for a 0.05 m voxelize task (409 M voxels), 1.2 GB at 0.2 m
TASK_BYTES_PER_VOXEL = 10
TASK_BASE_BYTES = 1 << 30
NANNY_TERMINATE = 0.95  # distributed's default: a worker past 95 % of its limit is restarted


def task_memory(voxels: int) -> int:
    """Bytes a task of a grid of ``voxels`` voxels may need at its peak (an upper estimate)."""
    return TASK_BASE_BYTES + TASK_BYTES_PER_VOXEL * int(voxels)


def local_workers(workers: int | None, task_bytes: int | None, total: int | None = None,
                  cores: int | None = None) -> tuple[int, int | str]:
    """(worker processes, memory limit of each) for a LocalCluster on this machine: one worker per
    core, fewer when ``total`` memory (default: this machine's) cannot hold that many tasks of
    ``task_bytes`` below the nanny's kill line; ``workers`` (``--workers``) overrides the count.
    Each worker's limit is its share of the memory ("auto" when the task size is unknown)."""
    import psutil

    cores = cores or os.cpu_count() or 1
    if not task_bytes:
        return workers or cores, "auto"
    total = total or psutil.virtual_memory().total
    fit = max(1, int(total * NANNY_TERMINATE // task_bytes))
    n = workers or min(cores, fit)
    return n, int(total // n)


def make_executor(scheduler: str | None, store: Store, workers: int | None = None,
                  task_bytes: int | None = None) -> Executor:
    scheduler = resolve_scheduler(scheduler)
    if scheduler == SYNCHRONOUS:
        return SynchronousExecutor()
    # worker processes, unless the root lives in this process (memory://)
    return DaskExecutor(scheduler, processes=not store.in_memory, workers=workers, memory_limit=task_bytes)


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
    import fsspec

    from carlaocc.catalog.store import fingerprint_bytes

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


def stage_order(names: list[str] | None, registry: dict[str, StageSpec] | None = None) -> list[StageSpec]:
    """Registered stages in dependency order, optionally restricted to ``names`` (validated;
    earlier stage names are read as the stage's name, e.g. ``metrics`` as ``quality``)."""
    registry = STAGES if registry is None else registry
    if names:
        names = [STAGE_ALIASES.get(n, n) if n not in registry else n for n in names]
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


def run(store: Store, config: DatasetConfig, voxel_sizes: tuple[float, ...],
        stages: list[str] | None = None, scheduler: str | None = None, force: bool = False,
        progress: Progress | None = None, workers: int | None = None,
        log: Callable[[str], None] = lambda s: None,
        registry: dict[str, StageSpec] | None = None, sequences: tuple[str, ...] = ()) -> list[StageOutcome]:
    """Run the selected stages (all by default) of ``registry`` (the registered stages by
    default) in order, the per-sequence ones for the sequences matching ``sequences`` (fnmatch
    patterns on sequence ids; empty: all); stops after a stage with failures."""
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
    # sortable by the driver's clock: lineage's "latest" is ordered by run id, not worker clocks
    run_id = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%S%fZ") + "-" + uuid.uuid4().hex[:6]
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
                invalid = spec.prepare(ctx, [pp.partition for pp in todo], [pp.partition for pp in plan.partitions])
                for pp in plan.partitions:
                    if pp.reason is None and pp.partition.key in invalid:
                        pp.reason = "array re-created"
                        todo.append(pp)
                        outcome.skipped -= 1
            by_key = {pp.partition.key: pp for pp in todo}
            code, chash = spec.code_version(), spec.config_hash(config)
            pending: list[RunRecord] = []
            last_flush = [time.monotonic(), 0]

            def flush() -> None:
                if pending:
                    lineage.append(spec.name, f"{run_id}-{last_flush[1]:04d}", list(pending))
                    pending.clear()
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
                                         task_memory(int(np.prod(finest.shape))) if finest else None)
            progress.start(spec.name, len(todo))
            try:
                executor.map(spec, store.url, spec.config(config), [pp.partition for pp in todo], on_done)
            finally:
                flush()
                # the run's lineage files of the stage as one (and the stage's, past 64 files)
                lineage.compact_run(spec.name, run_id)
                progress.stop(spec.name)
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
