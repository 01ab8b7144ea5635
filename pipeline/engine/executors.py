"""Where a stage's tasks run: one task run and recorded (:func:`execute_task`, never raising), in
process (:class:`SynchronousExecutor`) or on Dask (:class:`DaskExecutor`: an existing scheduler's
address or a LocalCluster sized for the run's finest grid, partitions submitted in a bounded
window), and the ``--scheduler`` value checked (:func:`resolve_scheduler`). The runner
(:mod:`carlaocc.pipeline.engine.runner`) plans the tasks and records what they return.
"""

from __future__ import annotations

import logging
import os
import socket
import time
import traceback
import uuid
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Callable

from carlaocc.catalog.signatures import output_signatures
from carlaocc.catalog.store import Store
from carlaocc.pipeline.engine.spec import Partition, PlanError, StageSpec
from carlaocc.schemas.configs import StageConfig
from carlaocc.stages.threads import THREAD_ENV

SYNCHRONOUS = "synchronous"


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

    ``kernel_threads`` caps the kernels' threads in this process (numba, BLAS, OpenMP, OpenCV,
    open3d's casts: see :mod:`carlaocc.stages.threads`): a LocalCluster already runs one
    single-threaded worker per core, so its kernels run single-threaded instead of oversubscribing.
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
class Executor(ABC):
    """Runs a batch of tasks, calling ``on_done`` as each finishes."""

    @abstractmethod
    def map(self, spec: StageSpec, store_url: str, cfg: StageConfig, partitions: list[Partition],
            on_done: Callable[[TaskResult], None]) -> None:
        """Run ``partitions`` of ``spec`` against the root at ``store_url``."""

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
                 max_in_flight: int | None = None, memory_limit: int | None = None,
                 log: Callable[[str], None] = lambda s: None):
        self.address, self.processes, self.workers = address, processes, workers
        self.log = log
        self.max_in_flight, self.memory_limit = max_in_flight, memory_limit
        self.submit_seconds = 0.0  # the last map's first batch
        self._client = None
        self._cluster = None
        # own LocalCluster of single-threaded workers (processes, or threads of this process for a
        # memory:// root): one kernel thread each (numba, BLAS, OpenMP, OpenCV, open3d's casts)
        self.kernel_threads = 1 if address is None else None

    # schemes whose address is host:port (probed with a plain TCP connect before the Client)
    HOST_PORT_SCHEMES = ("tcp", "tls", "ws", "wss", "ucx")
    PROBE_SECONDS = 3.0  # the TCP connect probe: a refused or silent port fails in seconds
    CONNECT_SECONDS = "10s"  # the Client's handshake once the port answers
    # a worker that sends no heartbeat for this long (a frozen process, a lost node) is restarted
    # by the scheduler and its tasks run on the others (distributed's `scheduler.worker-ttl`,
    # 5 minutes by default, which our LocalCluster shortens; an existing scheduler keeps its own).
    # A task's kernels release the GIL or return within seconds, so a live worker always beats.
    # $DASK_DISTRIBUTED__SCHEDULER__WORKER_TTL (e.g. "30s") overrides it.
    WORKER_TTL = "120s"
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
                # one thread for each kernel library from the worker's start (distributed sets
                # OpenMP's, OpenBLAS's and MKL's; numba's pool would start a thread per core).
                # numba's variable goes to the workers' own environment only: a nanny writes its
                # pre-spawn variables into the driver's os.environ, and a driver whose numba pool
                # already runs then fails its next compilation (numba re-reads the variable)
                environ.update({name: 1 for name in THREAD_ENV})
                worker_environ = {**dask.config.get("distributed.nanny.environ", {}), "NUMBA_NUM_THREADS": 1}
                ttl = os.environ.get("DASK_DISTRIBUTED__SCHEDULER__WORKER_TTL") or self.WORKER_TTL
                with dask.config.set({"distributed.nanny.pre-spawn-environ": environ,
                                      "distributed.nanny.environ": worker_environ,
                                      "distributed.scheduler.worker-ttl": ttl}):
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
            # the scheduler's own events: a worker restarted for missing heartbeats is reported
            self._client.subscribe_topic("scheduler", self._scheduler_event)
        return self._client

    def _scheduler_event(self, event) -> None:
        """Report what the scheduler did about a stuck worker (runs on the client's thread)."""
        _, msg = event
        if isinstance(msg, dict) and msg.get("action") == "worker-ttl-timed-out":
            for worker in msg.get("workers", []):
                self.log(f"worker {worker} stopped answering (no heartbeat for {float(msg.get('ttl', 0)):.0f} s): "
                         "the scheduler restarts it and its tasks run again on the others")

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
# the scene mesh): measured 4.0 GB for a 0.05 m voxelize task (409 M voxels), 1.2 GB at 0.2 m,
# plus 6 bytes a voxel the quality stage's frame buffers keep in the worker thread between its
# tasks (three arrays, two frames each: 2.4 GB at 0.05 m) whatever task the thread runs next
TASK_BYTES_PER_VOXEL = 16
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
                  task_bytes: int | None = None, log: Callable[[str], None] = lambda s: None) -> Executor:
    scheduler = resolve_scheduler(scheduler)
    if scheduler == SYNCHRONOUS:
        return SynchronousExecutor()
    # worker processes, unless the root lives in this process (memory://)
    return DaskExecutor(scheduler, processes=not store.in_memory, workers=workers, memory_limit=task_bytes, log=log)
