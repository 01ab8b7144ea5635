"""Faults injected one at a time on tiny roots: concurrent writers, clocks that go back, a lineage
write that fails, stop signals, a frozen worker, ctime-only changes. Each case is what a lab that
shares datasets and machines meets; each test fails on the code before the fix (issue 37)."""

from __future__ import annotations

import errno
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest
import trimesh
from terminal import from_a_terminal
from typer.testing import CliRunner

from carlaocc.catalog.lineage import LineageLog
from carlaocc.catalog.lock import LOCK_FILE, RootBusy, root_lock
from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.sql import query
from carlaocc.catalog.store import Store
from carlaocc.pipeline.cli import app
from carlaocc.pipeline.engine import runner
from carlaocc.pipeline.engine.spec import Partition, StageSpec
from carlaocc.schemas.configs import DatasetConfig
from carlaocc.schemas.records import QuarantineRecord

cli = CliRunner()


# -- two tiny stand-in stages (as in test_runner.py) ----------------------------------------------
def _rec(reason: str) -> QuarantineRecord:
    return QuarantineRecord(stage="t", source="t", source_path="t", reason=reason, hint="")


def task_a(store, cfg, part):
    t = ParquetTable(store, QuarantineRecord)
    return {t.path(f"a/{part.key}"): t.save(f"a/{part.key}", [_rec(f"seed={cfg.seed}")])}


def task_b(store, cfg, part):
    t = ParquetTable(store, QuarantineRecord)
    if cfg.frame_count == 13 and part.key == "p1":
        raise ValueError("unlucky frame count")
    up = t.load([f"a/{part.params['up']}"])[0].reason
    return {t.path(f"b/{part.key}"): t.save(f"b/{part.key}", [_rec(f"{up};frames={cfg.frame_count}")])}


STAGES = {
    "ingest": StageSpec("ingest", "a", (), (), (), lambda ctx: [Partition("x"), Partition("y")], task_a),
    "scenes": StageSpec("scenes", "b", ("ingest",), (), (),
                        lambda ctx: [Partition(f"p{i}", {"up": "xy"[i]}, (("ingest", "xy"[i]),)) for i in range(2)],
                        task_b),
}


def _run(store, cfg=None, **kw):
    outcomes = runner.run(store, cfg or DatasetConfig(), (0.2,), scheduler="synchronous", registry=STAGES, **kw)
    return {o.stage: o for o in outcomes}


def _files(root: Path) -> dict[str, bytes]:
    """Every file of a root but the lock file (which exists while its holder holds it)."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and p.name != LOCK_FILE}


def _hold_lock_in_another_process(root: Path):
    """A process that takes the root lock and keeps it until its stdin closes."""
    code = ("import sys; from carlaocc.catalog.store import Store; from carlaocc.catalog.lock import root_lock\n"
            f"with root_lock(Store({str(root)!r})):\n    print('held', flush=True); sys.stdin.read()\n")
    proc = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


# -- writers coordinate ---------------------------------------------------------------------------
def test_a_second_writer_with_no_wait_is_refused_naming_the_holder_and_touches_nothing(tmp_path):
    root = tmp_path / "data"
    _run(Store(str(root)))
    before = _files(root)
    holder = _hold_lock_in_another_process(root)
    try:
        with pytest.raises(runner.PlanError, match=rf"being written by pid {holder.pid} on .*since"):
            _run(Store(str(root)), wait=False)
        # the command line: exit 2, one line; nothing in the root changed
        r = cli.invoke(app, ["run", "--root", str(root), "--no-wait", "--scheduler", "synchronous"])
        assert r.exit_code == 2, r.output
        assert f"being written by pid {holder.pid}" in r.output and "--no-wait" in r.output
        assert len([ln for ln in r.output.splitlines() if ln.startswith("error:")]) == 1
        assert _files(root) == before
    finally:
        holder.stdin.close()
        holder.wait(10)


def test_a_writer_waits_for_the_holder_saying_so_then_runs(tmp_path):
    store = Store(str(tmp_path / "data"))
    released = []
    held = threading.Event()

    def hold():
        with root_lock(store):
            held.set()
            time.sleep(0.8)
            released.append(datetime.now(timezone.utc))

    t = threading.Thread(target=hold)
    t.start()
    held.wait(5)
    said = []
    out = _run(store, log=said.append)
    t.join()
    assert out["scenes"].ran == 2
    waiting = [s for s in said if s.startswith("waiting for the dataset root")]
    assert len(waiting) == 1 and "Ctrl-C" in waiting[0]
    # every record of the run was written after the holder let go
    records = LineageLog(store).load()
    assert records and min(r.started_at for r in records) >= released[0]
    assert not (tmp_path / "data" / LOCK_FILE).exists()  # the lock file goes with the lock


def test_the_lock_is_released_by_a_killed_holder(tmp_path):
    root = tmp_path / "data"
    holder = _hold_lock_in_another_process(root)
    with pytest.raises(RootBusy):
        with root_lock(Store(str(root)), wait=False):
            pass
    holder.kill()  # kill -9: no clean-up ran
    holder.wait(10)
    with root_lock(Store(str(root)), wait=False):
        pass


def _glb(length: float) -> bytes:
    return trimesh.Scene([trimesh.creation.box((1.9, 1.5, length))]).export(file_type="glb")


def test_two_ingests_at_once_run_one_after_the_other_and_lose_no_mesh(tmp_path, monkeypatch):
    """The race the issue met: ingest A's closing clean-up (list the assets, list the meshes, remove
    the meshes no asset names) while ingest B has written meshes whose asset rows are not yet
    written. With the lock, B cannot start before A has finished."""
    from carlaocc.pipeline.commands import ingest as ingest_cmd
    from carlaocc.schemas.configs import SourceIngestConfig

    sources = []
    for name, lengths in (("a", (4.5, 4.1, 3.9)), ("b", (4.8, 4.3, 3.7))):
        src = tmp_path / name
        (src / "cars").mkdir(parents=True)
        for i, length in enumerate(lengths):
            (src / "cars" / f"{name}{i}.glb").write_bytes(_glb(length))
        cmap = tmp_path / f"{name}.csv"
        cmap.write_text("glob,category,subclass\ncars/*.glb,Car,sedan\n")
        sources.append(SourceIngestConfig(kind="folder", root=str(src), category_map=str(cmap)))
    store = Store(str(tmp_path / "data"))
    # A pauses inside its clean-up, after listing the asset tables: B gets every chance to write
    real_prune, in_prune, timeline = ingest_cmd.prune_orphan_meshes, threading.Event(), []

    def slow_prune(s):
        in_prune.set()
        time.sleep(1.0)
        timeline.append(("A pruned", time.monotonic()))
        return real_prune(s)

    said_b = []

    def ingest_b():
        in_prune.wait(30)
        monkeypatch.setattr(ingest_cmd, "prune_orphan_meshes", real_prune)  # B prunes at once
        ingest_cmd.ingest_source(store, sources[1], "synchronous", log=said_b.append)
        timeline.append(("B done", time.monotonic()))

    monkeypatch.setattr(ingest_cmd, "prune_orphan_meshes", slow_prune)
    tb = threading.Thread(target=ingest_b)
    tb.start()
    ingest_cmd.ingest_source(store, sources[0], "synchronous")
    tb.join(60)
    assert [name for name, _ in sorted(timeline, key=lambda e: e[1])] == ["A pruned", "B done"]
    assert any(s.startswith("waiting for the dataset root") for s in said_b)
    _, rows = query(store, "SELECT mesh_path FROM assets")
    assert len(rows) == 6
    missing = [p for (p,) in rows if not store.exists(p)]
    assert missing == []


# -- lineage order does not follow the clock ------------------------------------------------------
def test_a_clock_set_back_never_makes_stale_work_look_done(tmp_path, monkeypatch):
    store = Store(str(tmp_path / "data"))

    class Fast(datetime):  # the driver's host a day ahead
        @classmethod
        def now(cls, tz=None):
            return datetime.now(tz) + timedelta(days=1)

    monkeypatch.setattr(runner, "datetime", Fast)
    _run(store)
    monkeypatch.setattr(runner, "datetime", datetime)  # the clock corrected; the config changed
    said = []
    out = _run(store, DatasetConfig.model_validate({"scenes": {"frame_count": 7}}), log=said.append)
    assert out["scenes"].ran == 2
    assert any(s.startswith("note: this host's clock") and "behind the newest run" in s for s in said)
    # the last written record is the latest: the next run has nothing to do
    out = _run(store, DatasetConfig.model_validate({"scenes": {"frame_count": 7}}))
    assert (out["ingest"].ran, out["scenes"].ran) == (0, 0)
    assert ParquetTable(store, QuarantineRecord).load(["b/p0"])[0].reason.endswith(";frames=7")


def test_run_ids_carry_a_sequence_past_older_roots_ids(tmp_path):
    log = LineageLog(Store(str(tmp_path)))
    t = datetime(2026, 1, 1, tzinfo=timezone.utc)
    first, _ = log.new_run_id(t)
    assert first.startswith("r00000001-20260101T000000")
    # an id of a root built before sequences sorts before every sequence id
    assert "20991231T000000000000Z-abcdef" < first


# -- a lineage write that fails -------------------------------------------------------------------
def test_a_failed_lineage_write_names_the_file_and_keeps_the_tasks_error(tmp_path, monkeypatch):
    store = Store(str(tmp_path / "data"))
    _run(store)

    def full(self, stage, run_id, records):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), "/somewhere/.tmp-x.partial")

    monkeypatch.setattr(LineageLog, "append", full)
    with pytest.raises(runner.LineageWriteError) as err:
        _run(store, DatasetConfig.model_validate({"scenes": {"frame_count": 13}}))
    msg = str(err.value)
    assert "catalog/runs/stage=scenes/r00000002-" in msg and "No space left on device" in msg
    assert "the first failed task: scenes p1: ValueError: unlucky frame count" in msg


# -- signatures with ctime ------------------------------------------------------------------------
def _stale(store):
    ctx = runner.Context(store, DatasetConfig(), (0.2,), ())
    lineage = LineageLog(store)
    return {name: [pp.reason for pp in runner.plan_stage(spec, ctx, lineage, False, {}).partitions]
            for name, spec in STAGES.items()}


def test_ctime_only_changes_rehash_and_stay_clean_an_edit_with_its_time_restored_is_seen(tmp_path, monkeypatch):
    root = tmp_path / "data"
    store = Store(str(root))
    _run(store)
    hashed = []
    real = runner.Store.fingerprint
    monkeypatch.setattr(runner.Store, "fingerprint", lambda self, rel: hashed.append(rel) or real(self, rel))
    assert _stale(store) == {"ingest": [None, None], "scenes": [None, None]} and hashed == []
    # chmod: the bytes are the same, re-hashed and found intact
    target = next((root / "admesh" / "quarantine" / "b").glob("p0*.parquet"))
    os.chmod(target, 0o640)
    assert _stale(store)["scenes"] == [None, None] and len(hashed) == 1
    # a hard-linked snapshot (cp -al): every inode gains a link, the snapshot's status is clean
    snap = tmp_path / "snap"
    subprocess.run(["cp", "-al", str(root), str(snap)], check=True)
    assert _stale(Store(str(snap))) == {"ingest": [None, None], "scenes": [None, None]}
    # an in-place edit of the same size, its modification time put back: seen by status
    st = target.stat()
    data = bytearray(target.read_bytes())
    data[-20] ^= 0xFF
    with open(target, "r+b") as fh:
        fh.write(bytes(data))
    os.utime(target, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert _stale(store)["scenes"][0] is not None


# -- stop signals and a frozen worker (real processes) -------------------------------------------
def _carlaocc() -> list[str]:
    return [sys.executable, "-c", "from carlaocc.pipeline.cli import main; main()"]


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_stop_signal_ends_with_one_line_and_no_leaked_semaphores(tmp_path, sig):
    src = tmp_path / "src" / "cars"
    src.mkdir(parents=True)
    for i in range(6):
        (src / f"c{i}.glb").write_bytes(_glb(3.5 + i / 4))
    cmap = tmp_path / "map.csv"
    cmap.write_text("glob,category,subclass\ncars/*.glb,Car,sedan\n")
    proc = subprocess.Popen(_carlaocc() + ["ingest", "folder", str(src.parent), "--category-map", str(cmap),
                                           "--root", str(tmp_path / "data"), "--workers", "1"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, preexec_fn=from_a_terminal)
    # once its cluster is up and planning is done, stop it
    deadline = time.monotonic() + 60
    seen = b""
    fd = proc.stderr.fileno()
    os.set_blocking(fd, False)
    while b"planned" not in seen and time.monotonic() < deadline and proc.poll() is None:
        try:
            seen += os.read(fd, 65536)
        except BlockingIOError:
            time.sleep(0.05)
    proc.send_signal(sig)
    os.set_blocking(fd, True)
    _, err = proc.communicate(timeout=60)
    err = (seen + (err or b"")).decode()
    assert proc.returncode == 128 + sig, err
    errors = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert errors == [f"error: stopped by {signal.Signals(sig).name}: what finished is recorded; the same command "
                      "resumes from there"], err
    assert "leaked" not in err and "Traceback" not in err, err


FROZEN_WORKER = """
import json, os, signal, sys, time
from carlaocc.pipeline.engine.executors import DaskExecutor
from carlaocc.pipeline.engine.spec import Partition, StageSpec

def sleepy(store, cfg, part):
    time.sleep(0.5)
    return {}

said, results, stopped = [], [], []
ex = DaskExecutor(None, processes=True, workers=2, log=said.append)
pids = list(ex._get_client().run(os.getpid).values())

def on_done(res):
    results.append(res)
    if not stopped:  # the first result: freeze one worker mid-stage
        os.kill(pids[0], signal.SIGSTOP)
        stopped.append(pids[0])

try:
    ex.map(StageSpec("sleepy", "t", (), (), (), lambda ctx: [], sleepy), sys.argv[1], None,
           [Partition(f"t{i}") for i in range(8)], on_done)
finally:
    for pid in pids:
        try:
            os.kill(pid, signal.SIGCONT)
        except ProcessLookupError:
            pass
    ex.close()
print(json.dumps({"said": said, "results": [[r.partition, r.status, r.error] for r in results]}))
"""


def test_a_frozen_worker_is_noticed_and_its_tasks_run_elsewhere(tmp_path):
    """A worker stopped (SIGSTOP) mid-stage: its heartbeats stop, the scheduler restarts it after
    the worker TTL (3 s here, 120 s by default), its tasks run on the other worker, the run says
    which worker; the stage completes (it waited forever before). In its own process, as a
    command would run it."""
    import json

    env = {**os.environ, "DASK_DISTRIBUTED__SCHEDULER__WORKER_TTL": "3s"}
    proc = subprocess.Popen([sys.executable, "-c", FROZEN_WORKER, str(tmp_path)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env, start_new_session=True)
    try:
        out, err = proc.communicate(timeout=150)
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    assert proc.returncode == 0, err[-2000:]
    got = json.loads(out.strip().splitlines()[-1])
    assert sorted(p for p, _, _ in got["results"]) == [f"t{i}" for i in range(8)]
    assert all(status == "completed" for _, status, _ in got["results"]), got
    assert any("stopped answering (no heartbeat" in s for s in got["said"]), got["said"]


@pytest.fixture(autouse=True)
def _no_leftover_dirs(tmp_path):
    yield
    shutil.rmtree(tmp_path, ignore_errors=True)


# -- permission errors name the file --------------------------------------------------------------
def test_an_unreadable_chunk_is_named_by_export_not_the_output_folder(default_01, tmp_path, monkeypatch):
    """A root file another user cannot read (chunks were once written 0600): the export names that
    file, not its own output folder. (Tests run as root, whom a mode never stops: the read fails
    by injection, as the kernel would fail it.)"""
    from carlaocc.catalog import zarrstore

    real = zarrstore.get_object

    def denied(store, key):
        if "/c/" in key:
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), store.path(key))
        return real(store, key)

    monkeypatch.setattr(zarrstore, "get_object", denied)
    out = tmp_path / "occ3d"
    r = cli.invoke(app, ["export", "occ3d", "--root", default_01.url, "--out", str(out), "--voxel-size", "0.1"])
    assert r.exit_code == 1, r.output
    (line,) = [ln for ln in r.output.splitlines() if ln.startswith("error:")]
    assert line.startswith(f"error: cannot read {default_01.root}/occupancy.zarr/") and "Permission denied" in line
    assert "--out" not in line and not out.exists()


# -- what an independent review of the above found -------------------------------------------------
def test_an_ignored_stop_signal_stays_ignored():
    """`nohup carlaocc run ... &` (SIGHUP ignored) must not be stopped by a hang-up."""
    from carlaocc.pipeline.cli import install_stop_handlers

    saved = {s: signal.getsignal(s) for s in (signal.SIGHUP, signal.SIGTERM, signal.SIGINT)}
    try:
        signal.signal(signal.SIGHUP, signal.SIG_IGN)
        install_stop_handlers()
        assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
        assert signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL
    finally:
        for s, h in saved.items():
            signal.signal(s, h)


def test_a_lock_file_left_behind_goes_with_the_next_holder(tmp_path):
    root = tmp_path / "data"
    root.mkdir()
    (root / LOCK_FILE).write_bytes(b"")  # a killed holder's, or a refused maker's
    with root_lock(Store(str(root)), wait=False):
        pass
    assert not (root / LOCK_FILE).exists() and root.exists()


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to act as another user")
def test_another_users_lock_file_is_taken_read_only():
    """A group-shared root: the lock file another user made (0644 under umask 022) still locks."""
    import tempfile

    base = Path(tempfile.mkdtemp(prefix="carlaocc-shared-"))  # pytest's own folders are 0700
    os.chmod(base, 0o777)
    root = base / "data"
    root.mkdir()
    os.chmod(root, 0o777)
    lock = root / LOCK_FILE
    lock.write_bytes(b"")
    os.chmod(lock, 0o644)
    # imports first: the interpreter's own files may not be readable by the other user
    code = ("import os, fcntl, socket\n"
            "from carlaocc.catalog.store import Store; from carlaocc.catalog.lock import root_lock\n"
            f"store = Store({str(root)!r}); store.root\n"
            "os.setgid(65534); os.setuid(65534)\n"
            "with root_lock(store, wait=False):\n    print('held')\n")
    try:
        r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    finally:
        shutil.rmtree(base, ignore_errors=True)
    assert r.returncode == 0 and r.stdout.strip() == "held", r.stderr[-1500:]


def test_a_compaction_cut_short_leaves_no_record_twice(tmp_path):
    from carlaocc.schemas.records import RunRecord

    t = datetime(2026, 1, 1, tzinfo=timezone.utc)
    rec = RunRecord(run_id="r00000001-x", stage="scenes", partition="p0", code_version="c", config_hash="h",
                    cache_key="k", input_fingerprints="{}", output_fingerprints="{}", status="completed",
                    started_at=t, ended_at=t, host="w")
    log = LineageLog(Store(str(tmp_path)))
    log.append("scenes", "r00000001-x-0000", [rec])
    log.append("scenes", "compacted-r00000001-x", [rec])  # the merged file, its source not yet removed
    assert log.compact("scenes", max_files=1)
    assert len(log.load("scenes")) == 1
