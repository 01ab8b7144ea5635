"""Building the dataset: ``run`` (all stages or some), ``ingest`` (an external mesh source),
``status`` (what is stale and why), ``stages`` (what each stage reads and writes), ``config``."""

from __future__ import annotations

import re
import time
from pathlib import Path
from typing import Annotated, Optional

import typer
from pydantic import ValidationError

from carlaocc.catalog.store import StoreError
from carlaocc.pipeline.cli.app import app
from carlaocc.pipeline.cli.common import (ConfigOpt, DefaultPlanOpt, LimitFramesOpt, MapsOpt, PlanLimitFramesOpt,
                                          PlanSequencesOpt, PlanVoxelSizeOpt, PresetOpt, RichProgress, RootOpt,
                                          TaxonomyOpt, check_towns, did_you_mean, fail, load_config, open_store,
                                          plan_config, resolve_plan, validation_message)


@app.command()
def run(
    voxel_size: PlanVoxelSizeOpt = None,
    root: RootOpt = "data",
    stages: Annotated[Optional[str], typer.Option("--stages", help="comma-separated stages to run alone (default: all)")] = None,
    config: ConfigOpt = None,
    scheduler: Annotated[Optional[str], typer.Option("--scheduler", help="Dask scheduler address, or 'synchronous' for debugging (default: $DASK_SCHEDULER_ADDRESS, else a LocalCluster)")] = None,
    workers: Annotated[Optional[int], typer.Option("--workers", min=1, help="LocalCluster workers (default: one per core)")] = None,
    force: Annotated[bool, typer.Option("--force", help="re-run the selected stages even when up to date")] = False,
    preset: PresetOpt = None,
    maps: MapsOpt = None,
    limit_frames: PlanLimitFramesOpt = None,
    sequences: PlanSequencesOpt = None,
    taxonomy: TaxonomyOpt = None,
    default_plan: DefaultPlanOpt = False,
    no_wait: Annotated[bool, typer.Option("--no-wait", help="refuse (exit 2) when another command is writing the root, instead of waiting for it to finish")] = False,
) -> None:
    """Build the dataset (or the selected stages) on the root's remembered plan (<root>/plan.yaml),
    else the default plan; --config, --preset, --res, --maps, --limit-frames, --sequences and
    --taxonomy change the keys they name, and the run remembers the resulting plan (saying which
    keys changed). --default-plan goes back to the default plan."""
    from carlaocc.pipeline.engine.runner import PlanError, resolve_scheduler, run as run_pipeline, stage_order

    from carlaocc.catalog.lock import RootBusy, root_lock

    store = open_store(root, writable=True)

    def build() -> None:
        plan, remembered = resolve_plan(store, root, config=config, preset=preset, maps=maps, limit_frames=limit_frames,
                                        sequences=sequences, taxonomy=taxonomy, voxel_size=voxel_size,
                                        default_plan=default_plan)
        cfg, voxel_sizes = plan.effective_config(), plan.voxel_sizes
        check_towns(cfg)
        names = [s.strip() for s in stages.split(",") if s.strip()] if stages else None
        check_stage_names(names)
        check_sequence_ids(store, plan, remembered, sequences is not None)
        try:
            stage_order(names)
            resolve_scheduler(scheduler, probe=True)
        except PlanError as exc:
            fail(str(exc))
        # the plan is remembered once work starts (a refused run touches nothing), or once the run ends
        kept: list[bool] = []

        def keep_plan() -> None:
            if not kept:
                kept.append(True)
                remember_plan(store, plan, remembered)

        progress = RichProgress(on_start=keep_plan)
        t0 = time.perf_counter()
        try:
            outcomes = run_pipeline(store, cfg, voxel_sizes, names, scheduler, force, progress, workers,
                                    log=lambda s: typer.echo(s, err=True), sequences=plan.slice.sequences,
                                    wait=not no_wait)
        except PlanError as exc:  # refused before any task ran
            progress.close()
            fail(str(exc))
        except (StoreError, OSError) as exc:  # a failure during work (the plan was kept if a stage started)
            progress.close()
            fail(f"{exc.filename}: {exc.strerror}" if isinstance(exc, OSError) and exc.filename and exc.strerror
                 else exc, code=1)
        except BaseException:  # the error path reports it; the bar must not stay on screen
            progress.close()
            raise
        progress.close()
        keep_plan()
        failed = [f for o in outcomes for f in o.failed]
        if failed:
            for f in failed[:10]:
                typer.echo(f"task failed: {f.stage} {f.partition}: {f.error}", err=True)
            if len(failed) > 10:
                typer.echo(f"... and {len(failed) - 10} more failed tasks (see the runs table)", err=True)
            raise typer.Exit(1)
        ran = sum(o.ran for o in outcomes)
        total = sum(o.total for o in outcomes)
        if ran == 0:
            typer.echo(f"nothing to do: all {total} tasks up to date in {store.url} (use --force to re-run)")
        else:
            typer.echo(f"done: ran {ran} of {total} tasks in {time.perf_counter() - t0:.1f} s")
        typer.echo(closing_line(store, root))

    # one writer at a time, from reading the remembered plan to remembering the new one: a run
    # that waited for another finds that one's plan and work (the engine's own lock is the same)
    try:
        with root_lock(store, wait=not no_wait, on_wait=lambda s: typer.echo(s, err=True)):
            build()
    except RootBusy as exc:
        fail(str(exc))
    except StoreError as exc:  # the lock file cannot be made (a read-only root was refused before)
        fail(str(exc), code=1)


def check_stage_names(names: list[str] | None) -> None:
    """Every ``--stages`` name is a stage, else one line naming it and the closest stage."""
    from carlaocc.pipeline.engine.registry import STAGES

    for n in names or []:
        if n not in STAGES:
            fail(f"--stages: unknown stage {n!r}{did_you_mean(n, STAGES)}; stages: {', '.join(STAGES)}")


def check_sequence_ids(store, plan, remembered, given: bool) -> None:
    """A ``--sequences`` item without wildcards that names no sequence of the root is a typo:
    one line naming it and the closest sequence id. Checked only while the plan's config is the
    one the root's sequences were made with (a new config may make new sequences)."""
    from carlaocc.catalog.parquet import ParquetTable
    from carlaocc.schemas.records import SequenceRecord

    if not given or not plan.slice.sequences or remembered is None or remembered.config != plan.config:
        return
    table = ParquetTable(store, SequenceRecord)
    known = sorted(s.sequence_id for s in table.load()) if table.paths() else []
    if not known:
        return
    for pattern in plan.slice.sequences:
        if not any(c in pattern for c in "*?[") and pattern not in known:
            fail(f"--sequences: no sequence {pattern!r} in {store.url}{did_you_mean(pattern, known)}; "
                 f"`carlaocc info --root {store.url} -v` lists them (patterns such as 'town00_*' work too)")


def remember_plan(store, plan, remembered) -> None:
    """Save ``plan`` as the root's remembered plan, saying so on stderr: which keys change when
    it replaces a different one."""
    from carlaocc.catalog.plan import PlanStore
    from carlaocc.schemas.plan import describe_changes, plan_changes

    plans = PlanStore(store)
    if remembered == plan:
        typer.echo(f"plan: {plan.summary()} (remembered in {plans.url})", err=True)
        return
    try:
        plans.save(plan)
    except (OSError, StoreError) as exc:
        fail(f"--root {store.url}: cannot write the plan {plans.url}: {getattr(exc, 'strerror', None) or exc}", code=1)
    if remembered is None:
        typer.echo(f"plan: {plan.summary()}; remembered in {plans.url}", err=True)
    else:
        changes = plan_changes(remembered, plan)
        typer.echo(f"plan: replacing the remembered plan ({len(changes)} key(s) change: {describe_changes(changes)}); "
                   f"now {plan.summary()}; remembered in {plans.url} (`carlaocc run --default-plan` goes back to "
                   f"the default plan)", err=True)


def closing_line(store, root: str) -> str:
    """The last line of a build: the frames and voxel sizes the root holds, where the report is
    and the command that opens it."""
    from carlaocc.catalog.inventory import inventory
    from carlaocc.pipeline.tasks.report_page import REPORT_HTML

    inv = inventory(store)
    built = "; ".join(f"{inv.frames_by_voxel_size[k]:,} frames of {inv.sequences_by_voxel_size[k]} sequence(s) "
                      f"at {k} m" for k in inv.voxel_sizes) or "no occupancy yet"
    line = f"built in {store.url}: {built}"
    if store.exists(REPORT_HTML):
        report = store.uri(REPORT_HTML)
        line += f"; report: {report}" + (f" (look at it: xdg-open {report})" if store.is_local else "")
    else:
        line += "; no report yet (the report stage has not run)"
    return line + f"; what the root holds: carlaocc info --root {root}"


@app.command()
def ingest(
    kind: Annotated[str, typer.Argument(help="source kind: folder, shapenet, buildingnet, meshfleet, carla (our UE export) or carla-recording (a CARLA recording in the CarlaOcc release layout: its vehicle models and walk cycle)")],
    path: Annotated[Path, typer.Argument(help="the source's root directory")],
    category_map: Annotated[Optional[Path], typer.Option("--category-map", help="folder sources: CSV with columns glob,category,subclass[,length_m]")] = None,
    root: RootOpt = "data",
    scheduler: Annotated[Optional[str], typer.Option("--scheduler", help="Dask scheduler address, or 'synchronous'")] = None,
    workers: Annotated[Optional[int], typer.Option("--workers", min=1, help="LocalCluster workers (default: one per core)")] = None,
    force: Annotated[bool, typer.Option("--force", help="re-ingest items even when unchanged")] = False,
    no_wait: Annotated[bool, typer.Option("--no-wait", help="refuse (exit 2) when another command is writing the root, instead of waiting for it to finish")] = False,
) -> None:
    """Ingest a mesh source into the ADMesh library: one task per source item; unchanged items
    are skipped, bad items quarantined with a reason (see the quarantine table), never fatal."""
    from carlaocc.pipeline.commands.ingest import IngestError, ingest_source
    from carlaocc.pipeline.engine.runner import PlanError, resolve_scheduler
    from carlaocc.schemas.configs import SourceIngestConfig

    if category_map is not None and not category_map.is_file():
        what = "is a directory, not a CSV file" if category_map.is_dir() else "does not exist"
        fail(f"--category-map {category_map} {what}")
    try:
        cfg = SourceIngestConfig(kind=kind, root=str(path.resolve()),
                                 category_map=str(category_map.resolve()) if category_map else None)
    except ValidationError as exc:
        fail(validation_message("ingest", exc).replace("ingest: kind: ", f"unknown source kind {kind!r}: "))
    try:
        resolve_scheduler(scheduler, probe=True)
    except PlanError as exc:
        fail(str(exc))
    if cfg.kind == "carla-recording":  # a recording's calibration is checked before anything is written
        from carlaocc.catalog.carla_recording import RecordingError, discover, read_calib

        try:
            read_calib(discover(cfg.root).calib)
        except RecordingError as exc:
            fail(f"recording {cfg.root}: {exc}")
    store = open_store(root, writable=True)
    progress = RichProgress()
    try:
        s = ingest_source(store, cfg, scheduler, force, progress, workers, log=lambda m: typer.echo(m, err=True),
                          wait=not no_wait)
    except (IngestError, PlanError) as exc:
        progress.close()
        fail(str(exc))
    except StoreError as exc:  # a failure during work (a lineage write, the lock file)
        progress.close()
        fail(str(exc), code=1)
    except BaseException:  # the error path reports it; the bar must not stay on screen
        progress.close()
        raise
    progress.close()
    for f in s.failed[:10]:
        typer.echo(f"task failed: {f.stage} {f.partition}: {f.error}", err=True)
    reasons = ", ".join(f"{n} {r}" for r, n in s.quarantined.most_common())
    typer.echo(f"{cfg.kind} {cfg.root}: {s.items} items, {s.ran} ingested now, {s.skipped} unchanged; "
               f"library holds {s.ingested} assets from it, {sum(s.quarantined.values())} quarantined"
               + (f" ({reasons})" if reasons else "") + (f"; {s.pruned} vanished items pruned" if s.pruned else "")
               + "".join(f"; skipped the dataset root {d} inside the source" for d in s.excluded))
    if s.failed:
        raise typer.Exit(1)
    if cfg.kind == "carla-recording":
        _write_recording_config(store, root, cfg.root)


def _write_recording_config(store, root: str, recording: str) -> None:
    """Write (or extend) ``<root>/dataset.yaml`` so ``carlaocc run`` builds the recording."""
    import yaml

    from carlaocc.pipeline.cli.common import DATASET_CONFIG, root_config
    from carlaocc.pipeline.tasks.recording import recording_config

    if "://" in str(root):
        typer.echo(f"the dataset root {root} is not a local directory: write the recording's config yourself "
                   f"(towns of style carla-recording, see `carlaocc config`)", err=True)  # fmt: skip
        return
    existing = root_config(root)
    try:
        cfg = recording_config(recording, load_config(existing) if existing else None)
    except StoreError as exc:
        fail(str(exc))
    path = Path(root) / DATASET_CONFIG
    text = yaml.safe_dump(cfg.model_dump(mode="json", exclude_defaults=True), sort_keys=False)
    path.write_text(text)
    # a remembered plan takes the new config (its voxel sizes and slice stay): `run` without
    # options must build what was just ingested
    from carlaocc.catalog.plan import PlanStore

    plans = PlanStore(store)
    try:
        plan = plans.load()
    except StoreError:
        plan = None  # an unreadable plan: `run` says so itself
    if plan is not None and plan.config != cfg:
        plans.save(plan.model_copy(update={"config": cfg}))
        typer.echo(f"plan: {plans.url} now holds this config (its voxel sizes and slice kept)", err=True)
    maps = ", ".join(t.map for t in cfg.scenes.towns if t.style == "carla-recording")
    typer.echo(f"wrote {path}: towns {maps} from {recording}; `carlaocc run --root {root} --voxel-size 0.1` builds them")


@app.command()
def status(
    voxel_size: PlanVoxelSizeOpt = None,
    root: RootOpt = "data",
    config: ConfigOpt = None,
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="list every stale partition")] = False,
    preset: PresetOpt = None,
    maps: MapsOpt = None,
    limit_frames: PlanLimitFramesOpt = None,
    sequences: PlanSequencesOpt = None,
    taxonomy: TaxonomyOpt = None,
    default_plan: DefaultPlanOpt = False,
) -> None:
    """List what is stale and why (runs nothing, writes nothing) for the root's remembered plan,
    or the plan the same options as `carlaocc run` make of it; a stage whose config changed
    names the changed keys."""
    from carlaocc.catalog.plan import PlanStore
    from carlaocc.pipeline.engine.registry import STAGES
    from carlaocc.pipeline.engine.runner import PlanError, status as plan_status
    from carlaocc.schemas.plan import config_changes, describe_changes, plan_changes

    store = open_store(root, writable=False)
    wanted, remembered = resolve_plan(store, root, config=config, preset=preset, maps=maps, limit_frames=limit_frames,
                                      sequences=sequences, taxonomy=taxonomy, voxel_size=voxel_size,
                                      default_plan=default_plan)
    cfg = wanted.effective_config()
    check_towns(cfg)
    where = PlanStore(store).url
    if remembered is None:
        typer.echo(f"plan: {wanted.summary()} (none remembered in {where} yet)")
    elif remembered == wanted:
        typer.echo(f"plan: {wanted.summary()} (remembered in {where})")
    else:
        changes = plan_changes(remembered, wanted)
        typer.echo(f"plan: {wanted.summary()}; differs from the remembered plan in {where} by "
                   f"{describe_changes(changes)} (`carlaocc run` with these options would replace it)")
    try:
        plans = plan_status(store, cfg, wanted.voxel_sizes, wanted.slice.sequences)
    except PlanError as exc:
        fail(str(exc))

    def changed_keys(stage) -> str:
        # which keys of the stage's config differ from the remembered plan's (the config it was built on)
        if remembered is None:
            return ""
        keys = config_changes(stage.config(remembered.effective_config()), stage.config(cfg))
        return f" ({', '.join(keys[:6])}{f' and {len(keys) - 6} more' if len(keys) > 6 else ''})" if keys else ""

    for plan in plans:
        name = plan.stage.name
        if plan.blocked:
            typer.echo(f"{name:<9} waiting: {plan.blocked}")
            continue
        stale = plan.to_run
        total = len(plan.partitions)
        if not stale:
            typer.echo(f"{name:<9} up to date ({total} partitions)")
            continue
        reasons: dict[str, int] = {}
        for pp in stale:
            # one line per stage at any scale: waiting partitions are counted per upstream stage
            why = re.sub(r"^upstream (\w+)/\S+ (is stale|has not completed)$", r"upstream \1 \2", pp.reason)
            if why == "config changed":
                why += changed_keys(STAGES[name])
            reasons[why] = reasons.get(why, 0) + 1
        summary = "; ".join(f"{n} {r}" for r, n in sorted(reasons.items(), key=lambda kv: -kv[1]))
        typer.echo(f"{name:<9} stale {len(stale)}/{total}: {summary}")
        if verbose:
            for pp in stale:
                typer.echo(f"    {pp.partition.key}: {pp.reason}")


@app.command()
def info(
    root: RootOpt = "data",
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="list every sequence")] = False,
) -> None:
    """What a dataset root holds (reads it, runs and writes nothing): its remembered plan, the
    sequences, the frames built at each voxel size, the splits, the label table, its size and
    where the report is."""
    from carlaocc.catalog.inventory import inventory
    from carlaocc.catalog.plan import PlanStore
    from carlaocc.pipeline.tasks.report_page import REPORT_HTML

    store = open_store(root, writable=False)
    plans = PlanStore(store)
    try:
        plan = plans.load()
    except StoreError as exc:
        fail(exc)
    inv = inventory(store)
    typer.echo(f"root:        {store.url} ({inv.bytes / 1e6:,.1f} MB in {inv.files:,} files)")
    typer.echo(f"plan:        {plan.summary()} ({plans.url})" if plan is not None else
               "plan:        none remembered (no `carlaocc run` here yet)")
    seqs = inv.sequences
    frames = sum(s.frame_count for s in seqs.values())
    towns = sorted({s.town for s in seqs.values()})
    typer.echo(f"sequences:   {len(seqs)} in {len(towns)} town(s), {frames:,} frames planned"
               + (f" ({', '.join(towns)})" if towns else ""))
    shown = list(seqs.values()) if verbose else list(seqs.values())[:8]
    for s in shown:
        typer.echo(f"    {s.sequence_id}: {s.town}, traffic {s.traffic_level}, {s.frame_count} frames at {s.rate_hz:g} Hz")
    if len(shown) < len(seqs):
        typer.echo(f"    ... and {len(seqs) - len(shown)} more (--verbose lists them)")
    built = "; ".join(f"{k} m: {inv.frames_by_voxel_size[k]:,} frames of {inv.sequences_by_voxel_size[k]} "
                      f"sequence(s)" for k in inv.voxel_sizes)
    typer.echo(f"occupancy:   {built or 'none built'}")
    typer.echo("splits:      " + (", ".join(f"{k} {n}" for k, n in inv.splits.items()) or "none written")
               + (" sequences" if inv.splits else ""))
    table = ", ".join(inv.label_tables) or (f"{plan.config.taxonomy} (planned; no occupancy yet)" if plan else "-")
    typer.echo(f"label table: {table}" + ("  (two tables: rebuild one of them)" if len(inv.label_tables) > 1 else ""))
    report = store.uri(REPORT_HTML) if store.exists(REPORT_HTML) else None
    typer.echo(f"report:      {report}" if report else "report:      not built yet (the report stage)")


@app.command()
def verify(
    root: RootOpt = "data",
    stages: Annotated[Optional[str], typer.Option(
        "--stages", help="comma-separated stages to verify (default: every stage in lineage)")] = None,
    record: Annotated[bool, typer.Option(
        "--record/--no-record", help="record the new stat signatures of intact outputs whose signature "
                                     "moved (a copied or restored root), so `status` is cheap again")] = True,
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="list every partition found damaged")] = False,
) -> None:
    """Re-hash every recorded output against the fingerprint lineage holds for it (reads the
    whole dataset). `status` and `run` trust recorded fingerprints while an output's size, time and
    inode (or the object store's ETag) are unchanged; this is the full check. Exit code 1 when an
    output is damaged, modified or missing: `carlaocc run` rebuilds those partitions."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from carlaocc.pipeline.commands.verify import verify as verify_outputs

    store = open_store(root, writable=record)
    names = tuple(s.strip() for s in stages.split(",") if s.strip()) if stages else ()
    bars: dict[str, int] = {}
    with Progress(TextColumn("verify {task.description:<9}"), BarColumn(), MofNCompleteColumn(),
                  TextColumn("partitions"), TimeElapsedColumn(), transient=True) as bar:
        def advance(stage: str, total: int) -> None:
            if stage not in bars:
                bars[stage] = bar.add_task(stage, total=total)
            bar.advance(bars[stage])

        found = verify_outputs(store, names, record=record, advance=advance)
    if not found:
        typer.echo(f"nothing recorded in {store.url}: no lineage to verify")
        return
    bad = 0
    for v in found:
        line = f"{v.stage:<9} {v.partitions - len(v.problems)}/{v.partitions} partitions intact ({v.outputs:,} outputs)"
        if v.resigned:
            line += f"; signatures recorded anew for {v.resigned}"
        if v.problems:
            reasons: dict[str, int] = {}
            for why in v.problems.values():
                kind = why.split(":")[0]
                reasons[kind] = reasons.get(kind, 0) + 1
            line += "; " + "; ".join(f"{n} {r}" for r, n in sorted(reasons.items()))
        typer.echo(line)
        if verbose:
            for part, why in sorted(v.problems.items()):
                typer.echo(f"    {part}: {why}")
        bad += len(v.problems)
    if bad:
        typer.echo(f"{bad} partition(s) damaged or modified: `carlaocc run` rebuilds them", err=True)
        raise typer.Exit(1)


@app.command("stages")
def list_stages() -> None:
    """List the registered stages, what they read and write."""
    from carlaocc.pipeline.engine.registry import STAGES

    for s in STAGES.values():
        typer.echo(f"{s.name}: {s.description}")
        typer.echo(f"    after: {', '.join(s.upstream) or '-'}")
        typer.echo(f"    writes: {', '.join(s.writes)}")


@app.command("config")
def show_config(config: ConfigOpt = None, root: Annotated[Optional[str], typer.Option(
        "--root", help="a dataset root: its own dataset.yaml when it has one")] = None,
        preset: PresetOpt = None, maps: MapsOpt = None, limit_frames: LimitFramesOpt = None,
        taxonomy: TaxonomyOpt = None) -> None:
    """Print the effective dataset config as YAML (a starting point for --config files): the
    --config file or --preset plan, else the root's dataset.yaml, else the embedded default; with
    a summary of the plan (towns, sequences, frames) on stderr. The rig's fields are in CARLA's
    convention, as published (y right, yaw positive to the right); YAML comments after them give
    the rig in the dataset's frame (y left) with the direction each sensor faces in words."""
    import yaml

    from carlaocc.schemas.rig import rig_lines

    cfg = plan_config(config, root, preset, maps, limit_frames, taxonomy)
    typer.echo(yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False))
    typer.echo("# scenes.rig above is in CARLA's convention, as published (y right, yaw positive to the right).\n"
               "# The rig in the dataset's ego frame (x forward, y left, z up, m; yaw positive to the left;\n"
               "# docs/architecture.md \"Reference rig\"):")
    for line in rig_lines(cfg.scenes.rig):
        typer.echo(f"#   {line}")
    towns = cfg.scenes.towns
    seqs = sum(t.sequences_of(level) for t in towns for level in t.traffic_levels if t.style != "carla-recording")
    typer.echo(f"plan: {len(towns)} towns, {seqs} simulated sequences x {cfg.scenes.frame_count} frames at "
               f"{cfg.scenes.rate_hz:g} Hz", err=True)
