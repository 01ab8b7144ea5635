"""The runner's contract, on two tiny stand-in stages (fast, no heavy compute):
cache keys, skip-when-unchanged, re-run of exactly what changed, failures and lineage."""

from __future__ import annotations

import pytest

from carlaocc.catalog.lineage import LineageLog
from carlaocc.catalog.parquet import ParquetTable
from carlaocc.pipeline.engine import runner
from carlaocc.pipeline.engine.spec import Partition, StageSpec
from carlaocc.schemas.configs import DatasetConfig
from carlaocc.schemas.records import QuarantineRecord


def _rec(reason: str) -> QuarantineRecord:
    return QuarantineRecord(stage="t", source="t", source_path="t", reason=reason, hint="")


def task_a(store, cfg, part):
    t = ParquetTable(store, QuarantineRecord)
    key = f"a/{part.key}"
    return {t.path(key): t.save(key, [_rec(f"seed={cfg.seed}")])}


def task_b(store, cfg, part):
    t = ParquetTable(store, QuarantineRecord)
    if cfg.frame_count == 13 and part.key == "p1":
        raise ValueError("unlucky frame count")
    upstream = t.load([f"a/{part.params['up']}"])[0].reason
    key = f"b/{part.key}"
    return {t.path(key): t.save(key, [_rec(f"{upstream};frames={cfg.frame_count}")])}


STAGES = {
    "ingest": StageSpec("ingest", "a", (), (), (),
                        lambda ctx: [Partition("x"), Partition("y")], task_a),
    "scenes": StageSpec("scenes", "b", ("ingest",), (), (),
                        lambda ctx: [Partition(f"p{i}", {"up": "xy"[i]}, (("ingest", "xy"[i]),)) for i in range(2)],
                        task_b),
}


@pytest.fixture(autouse=True)
def fake_stages(monkeypatch):
    monkeypatch.setattr(runner, "STAGES", STAGES)


def _run(store, cfg=None, **kw):
    return {o.stage: o for o in runner.run(store, cfg or DatasetConfig(), (0.2,), scheduler="synchronous", **kw)}


def _snapshot(store):
    fs = store.fs
    return {p: (fs.info(p).get("size"), fs.info(p).get("mtime", fs.info(p).get("created")), fs.cat_file(p))
            for p in fs.find(store.root)}


def test_first_run_runs_everything_then_nothing(store):
    out = _run(store)
    assert (out["ingest"].ran, out["scenes"].ran) == (2, 2)
    before = _snapshot(store)
    out = _run(store)
    assert (out["ingest"].ran, out["scenes"].ran) == (0, 0)
    assert (out["ingest"].skipped, out["scenes"].skipped) == (2, 2)
    assert _snapshot(store) == before  # a re-run with nothing changed writes nothing


def test_changed_config_reruns_that_stage_and_downstream_only(store):
    _run(store)
    cfg = DatasetConfig.model_validate({"scenes": {"frame_count": 30}})
    out = _run(store, cfg)
    assert (out["ingest"].ran, out["scenes"].ran) == (0, 2)
    assert runner.status(store, cfg, (0.2,))[1].to_run == []
    cfg2 = DatasetConfig.model_validate({"scenes": {"frame_count": 30}, "ingest": {"seed": 99}})
    plans = runner.status(store, cfg2, (0.2,))
    assert [pp.reason for pp in plans[0].to_run] == ["config changed"] * 2
    assert all("stale" in pp.reason for pp in plans[1].to_run)
    out = _run(store, cfg2)
    assert (out["ingest"].ran, out["scenes"].ran) == (2, 2)
    assert ParquetTable(store, QuarantineRecord).load(["b/p0"])[0].reason == "seed=99;frames=30"


def test_failed_task_is_named_recorded_and_rerun(store):
    cfg = DatasetConfig.model_validate({"scenes": {"frame_count": 13}})
    out = _run(store, cfg)
    assert [f.partition for f in out["scenes"].failed] == ["p1"]
    assert "unlucky frame count" in out["scenes"].failed[0].error
    latest = LineageLog(store).latest("scenes")
    assert latest["p1"].status == "failed" and latest["p0"].status == "completed"
    plans = runner.status(store, cfg, (0.2,))
    assert [(pp.partition.key, pp.reason.split(":")[0]) for pp in plans[1].to_run] == [("p1", "last run failed")]
    out = _run(store)  # fixed config: p0 (changed config) and p1 both run
    assert out["scenes"].ran == 2 and not out["scenes"].failed


def test_missing_outputs_are_rebuilt(store):
    _run(store)
    store.remove("admesh/quarantine/b/p0.parquet")
    plans = runner.status(store, DatasetConfig(), (0.2,))
    assert [(pp.partition.key, pp.reason) for pp in plans[1].to_run] == [("p0", "outputs missing or modified")]
    out = _run(store)
    assert out["scenes"].ran == 1


def test_force_and_single_stage(store):
    _run(store)
    out = _run(store, stages=["scenes"], force=True)
    assert list(out) == ["scenes"] and out["scenes"].ran == 2


def test_single_stage_without_upstream_is_a_plan_error(store):
    with pytest.raises(runner.PlanError, match="has not completed"):
        _run(store, stages=["scenes"])
    assert store.fs.find(store.root) == [] if store.fs.exists(store.root) else True


def test_unknown_stage(store):
    with pytest.raises(runner.PlanError, match="unknown stage 'voxelise'"):
        _run(store, stages=["voxelise"])


def test_lineage_records_inputs_and_outputs(store):
    _run(store)
    recs = LineageLog(store).load("scenes")
    assert len(recs) == 2 and {r.status for r in recs} == {"completed"}
    import json

    r = next(r for r in recs if r.partition == "p0")
    assert list(json.loads(r.input_fingerprints)) == ["ingest/x"]
    assert list(json.loads(r.output_fingerprints)) == ["admesh/quarantine/b/p0.parquet"]


def test_single_stage_run_refuses_a_stale_upstream(store):
    _run(store)
    cfg = DatasetConfig.model_validate({"ingest": {"seed": 5}})
    with pytest.raises(runner.PlanError, match="upstream ingest/x is stale"):
        _run(store, cfg, stages=["scenes"])
    out = _run(store, cfg, stages=["ingest", "scenes"])
    assert (out["ingest"].ran, out["scenes"].ran) == (2, 2)


def test_latest_is_ordered_by_run_id_not_worker_clock(store):
    from datetime import datetime, timezone

    from carlaocc.schemas.records import RunRecord

    def rec(run_id, status, hour):
        t = datetime(2026, 1, 1, hour, tzinfo=timezone.utc)
        return RunRecord(run_id=run_id, stage="scenes", partition="p0", code_version="c", config_hash="h",
                         cache_key="k", input_fingerprints="{}", output_fingerprints="{}", status=status,
                         started_at=t, ended_at=t, host="w")

    log = LineageLog(store)
    log.append("scenes", "20260101T000000000000Z-a", [rec("20260101T000000000000Z-a", "completed", 23)])
    log.append("scenes", "20260102T000000000000Z-b", [rec("20260102T000000000000Z-b", "failed", 1)])
    # the newer run failed even though its worker's clock says earlier
    assert log.latest("scenes")["p0"].status == "failed"


@pytest.mark.parametrize("bad", ["foo", "tcp://", "nonsense://x:1"])
def test_bad_scheduler_address_is_a_plan_error(store, bad):
    with pytest.raises(runner.PlanError, match="scheduler"):
        runner.run(store, DatasetConfig(), (0.2,), scheduler=bad)


def test_dask_address_and_threaded_local_cluster(store, monkeypatch):
    """The same stages on an existing scheduler (by address and by DASK_SCHEDULER_ADDRESS) and on
    the default LocalCluster (threads for memory://, processes would not see the fake stages)."""
    from distributed import LocalCluster

    if store.is_local:
        pytest.skip("worker processes cannot see the test's stand-in stages")
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None,
                      scheduler_kwargs={"dashboard": False}) as cluster:
        out = {o.stage: o for o in runner.run(store, DatasetConfig(), (0.2,), scheduler=cluster.scheduler_address)}
        assert (out["ingest"].ran, out["scenes"].ran) == (2, 2)
        monkeypatch.setenv("DASK_SCHEDULER_ADDRESS", cluster.scheduler_address)
        out = {o.stage: o for o in runner.run(store, DatasetConfig(), (0.2,), force=True)}
        assert (out["ingest"].ran, out["scenes"].ran) == (2, 2)
    monkeypatch.delenv("DASK_SCHEDULER_ADDRESS")
    out = {o.stage: o for o in runner.run(store, DatasetConfig(), (0.2,), force=True)}  # LocalCluster
    assert (out["ingest"].ran, out["scenes"].ran) == (2, 2)


_LIVE = {"now": 0, "peak": 0}  # tasks running at once in the bounded-window test (threads)


def _counted_task(store, cfg, part):
    import time

    _LIVE["now"] += 1
    _LIVE["peak"] = max(_LIVE["peak"], _LIVE["now"])
    time.sleep(0.01)
    _LIVE["now"] -= 1
    return {}


def test_partitions_are_submitted_in_a_bounded_window():
    """The driver keeps at most ``in_flight()`` tasks in the scheduler: 40 partitions through a
    window of 3 never have more than 3 submitted and unfinished, and every one is done once."""
    from distributed import LocalCluster

    from carlaocc.pipeline.engine.spec import Partition, StageSpec

    spec = StageSpec("x", "", (), (), (), partitions=lambda ctx: [], task=_counted_task)
    parts = [Partition(f"p{i:02d}") for i in range(40)]
    seen, submitted = [], []
    with LocalCluster(n_workers=1, threads_per_worker=8, processes=False, dashboard_address=None,
                      scheduler_kwargs={"dashboard": False}) as cluster:
        ex = runner.DaskExecutor(cluster.scheduler_address, processes=False, max_in_flight=3)
        real_submit = ex._get_client().submit

        def counting_submit(*args, **kwargs):
            unfinished = sum(not f.done() for f in submitted)
            assert unfinished < 3, unfinished  # room for this one
            fut = real_submit(*args, **kwargs)
            submitted.append(fut)
            return fut

        ex._client.submit = counting_submit
        try:
            ex.map(spec, "memory://bounded", DatasetConfig().scenes, parts, seen.append)
        finally:
            ex.close()
    assert sorted(r.partition for r in seen) == [p.key for p in parts] and {r.status for r in seen} == {"completed"}
    assert _LIVE["peak"] <= 3 and len(submitted) == 40


def test_lineage_is_compacted(store):
    """A run's flush files become one file per stage; past COMPACT_FILES the stage's files are
    merged into one; every record is kept and the latest per partition is unchanged."""
    from datetime import datetime, timezone

    from carlaocc.catalog import lineage as lineage_mod
    from carlaocc.schemas.records import RunRecord

    t = datetime(2026, 1, 1, tzinfo=timezone.utc)

    def rec(run_id, part, status="completed"):
        return RunRecord(run_id=run_id, stage="s", partition=part, code_version="c", config_hash="h", cache_key="k",
                         input_fingerprints="{}", output_fingerprints="{}", status=status, started_at=t, ended_at=t,
                         host="w")

    log = LineageLog(store)
    run = "20260101T000000000000Z-aaaaaa"
    for i in range(3):  # three flushes of one run
        log.append("s", f"{run}-{i:04d}", [rec(run, f"p{i}")])
    log.compact_run("s", run)
    assert [p.rsplit("/", 1)[1] for p in log._files("s")] == [f"{run}.parquet"]
    assert sorted(log.latest("s")) == ["p0", "p1", "p2"]
    # many runs: merged once there are more than COMPACT_FILES files
    for i in range(lineage_mod.COMPACT_FILES):
        r = f"20260102T{i:06d}000000Z-b"
        log.append("s", r, [rec(r, "p0", "failed" if i % 2 else "completed")])
    before = {k: v for k, v in LineageLog(store).latest("s").items()}
    n_records = len(LineageLog(store).load("s"))
    assert log.compact("s") and len(log._files("s")) == 1
    assert not log.compact("s")
    assert len(LineageLog(store).load("s")) == n_records
    assert LineageLog(store).latest("s") == before and before["p0"].status == "failed"
    # merging again names the file after the newest run it holds, not after the earlier merge
    for i in range(lineage_mod.COMPACT_FILES):
        r = f"20260103T{i:06d}000000Z-c"
        log.append("s", r, [rec(r, "p1")])
    assert log.compact("s")
    (name,) = [p.rsplit("/", 1)[1] for p in log._files("s")]
    assert name == f"compacted-20260103T{lineage_mod.COMPACT_FILES - 1:06d}000000Z-c.parquet"


def test_local_workers_fit_the_finest_task_under_the_nanny():
    gib = 1 << 30
    # 0.05 m: ~7 GiB a task (with the quality stage's kept frame buffers); 24 GiB and 2 cores
    # hold both workers
    need = runner.task_memory(1536 * 1024 * 260)
    assert 6.5 * gib < need < 7.5 * gib
    assert runner.local_workers(None, need, total=24 * gib, cores=2) == (2, 12 * gib)
    # 100 cores and 128 GiB: 17 workers, each with room for one task below the kill line
    n, limit = runner.local_workers(None, need, total=128 * gib, cores=100)
    assert n == 17 and limit * runner.NANNY_TERMINATE >= need
    # --workers wins; no task size: distributed's own share ("auto")
    assert runner.local_workers(7, need, total=128 * gib, cores=100)[0] == 7
    assert runner.local_workers(None, None, cores=3) == (3, "auto")


def test_partitions_whose_outputs_prepare_removed_are_retired(store):
    """``retire_orphans``: a partition no longer planned whose recorded outputs a stage's prepare
    removed gets a retired record; planned ones, already retired ones and ones whose outputs
    were kept stay as they are."""
    import json
    from datetime import datetime, timezone

    from carlaocc.catalog.lineage import LineageLog
    from carlaocc.schemas.records import RunRecord

    t = datetime(2026, 1, 1, tzinfo=timezone.utc)

    def rec(part, outputs, status="completed"):
        return RunRecord(run_id="r1", stage="s", partition=part, code_version="c", config_hash="h", cache_key="k",
                         input_fingerprints="{}", output_fingerprints=json.dumps({o: "f" for o in outputs}),
                         status=status, started_at=t, ended_at=t, host="w")

    log = LineageLog(store)
    log.append("s", "r1-0000", [rec("gone", ["t/gone.parquet"]), rec("kept", ["t/kept.parquet"]),
                                rec("planned", ["t/planned.parquet"]), rec("old", ["t/old.parquet"], "retired")])
    removed = frozenset({"t/gone.parquet", "t/planned.parquet", "t/old.parquet"})
    retired = runner.retire_orphans(log, "s", {"planned"}, removed)
    assert [r.partition for r in retired] == ["gone"]
    latest = LineageLog(store).latest("s")
    assert latest["gone"].status == "retired" and latest["gone"].output_fingerprints == "{}"
    assert latest["kept"].status == latest["planned"].status == "completed"
    assert runner.retire_orphans(log, "s", {"planned"}, frozenset()) == []
    assert runner.retire_orphans(log, "s", {"planned"}, removed) == []  # once
