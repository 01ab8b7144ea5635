"""A real Dask cluster on loopback (a scheduler and two nanny-managed worker processes, started
and stopped by the test): a worker killed with SIGKILL while it executes a voxelize task is
restarted by its nanny, the task runs again, and the frames are byte-identical to a clean
synchronous build."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from carlaocc.catalog.lineage import LineageLog
from carlaocc.catalog.store import Store
from carlaocc.pipeline.engine import runner
from carlaocc.schemas.configs import DatasetConfig

VOXEL_SIZE = 0.4
CONFIG = DatasetConfig.model_validate({"scenes": {"frame_count": 4}})


def _dask(*args: str) -> list[str]:
    return [str(Path(sys.executable).with_name("dask")), *args]


@pytest.fixture
def cluster(tmp_path):
    """``dask scheduler`` on 127.0.0.1 and ``dask worker --nworkers 2 --nthreads 1`` (nannies),
    stopped (and their process groups killed) afterwards; yields the scheduler address."""
    info = tmp_path / "scheduler.json"
    procs = [subprocess.Popen(_dask("scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                                    "--scheduler-file", str(info)),
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)]
    try:
        deadline = time.monotonic() + 60
        while not info.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        address = json.loads(info.read_text())["address"]
        procs.append(subprocess.Popen(_dask("worker", "--scheduler-file", str(info), "--nworkers", "2",
                                            "--nthreads", "1", "--no-dashboard", "--host", "127.0.0.1"),
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True))
        from distributed import Client

        with Client(address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=60)
        yield address
    finally:
        for p in reversed(procs):
            try:
                os.killpg(p.pid, signal.SIGTERM)
                p.wait(timeout=20)
            except (ProcessLookupError, subprocess.TimeoutExpired):
                os.killpg(p.pid, signal.SIGKILL)


def _frames(store: Store) -> dict[str, bytes]:
    """Every file of occupancy.zarr but the temporary ones a killed write may leave (dot names)."""
    base = Path(store.root) / "occupancy.zarr"
    return {str(p.relative_to(base)): p.read_bytes() for p in sorted(base.rglob("*"))
            if p.is_file() and not p.name.startswith(".")}


def test_a_worker_killed_mid_task_is_retried_byte_identical(cluster, tmp_path):
    from distributed import Client

    store = Store(str(tmp_path / "data"))
    sequences = ("town00_high_seq000",)
    runner.run(store, CONFIG, (VOXEL_SIZE,), stages=["ingest", "scenes"], scheduler=cluster)
    # the reference: the same root, its frames voxelized cleanly in this process (below)
    clean = Store(str(tmp_path / "clean"))
    shutil.copytree(store.root, clean.root)
    killed: list[int] = []

    def executing(dask_worker) -> tuple[int, list[str]]:  # runs in each worker (pickled by value)
        import os

        return os.getpid(), [str(ts.key) for ts in dask_worker.state.executing]

    def kill_one() -> None:
        # the first worker seen executing a voxelize task is killed outright (its nanny restarts it)
        with Client(cluster, timeout="30s") as client:
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline and not killed:
                for worker, (pid, keys) in client.run(executing, on_error="ignore").items():
                    if any(k.startswith("voxelize-") for k in keys):
                        os.kill(pid, signal.SIGKILL)
                        killed.append(pid)
                        return
                time.sleep(0.01)

    watcher = threading.Thread(target=kill_one)
    watcher.start()
    out = runner.run(store, CONFIG, (VOXEL_SIZE,), stages=["voxelize"], scheduler=cluster, sequences=sequences)
    watcher.join()
    assert killed, "no voxelize task was seen running"
    (vox,) = out
    assert vox.ran == 4 and not vox.failed
    latest = LineageLog(store).latest("voxelize")
    assert sorted(latest) == [f"{sequences[0]}/{VOXEL_SIZE}/{t:04d}" for t in range(4)]
    assert all(r.status == "completed" for r in latest.values())
    runner.run(clean, CONFIG, (VOXEL_SIZE,), stages=["voxelize"], scheduler="synchronous", sequences=sequences)
    assert _frames(clean) == _frames(store)
