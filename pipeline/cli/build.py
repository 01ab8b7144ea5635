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
from carlaocc.pipeline.cli.common import (ConfigOpt, LimitFramesOpt, MapsOpt, PresetOpt, RichProgress, RootOpt,
                                          SequencesOpt, TaxonomyOpt, VoxelSizeOpt, check_towns, fail, load_config,
                                          open_store, parse_voxel_sizes, plan_config, sequence_patterns,
                                          validation_message)


@app.command()
def run(
    voxel_size: VoxelSizeOpt = "0.2",
    root: RootOpt = "data",
    stages: Annotated[Optional[str], typer.Option("--stages", help="comma-separated stages to run alone (default: all)")] = None,
    config: ConfigOpt = None,
    scheduler: Annotated[Optional[str], typer.Option("--scheduler", help="Dask scheduler address, or 'synchronous' for debugging (default: $DASK_SCHEDULER_ADDRESS, else a LocalCluster)")] = None,
    workers: Annotated[Optional[int], typer.Option("--workers", min=1, help="LocalCluster workers (default: one per core)")] = None,
    force: Annotated[bool, typer.Option("--force", help="re-run the selected stages even when up to date")] = False,
    preset: PresetOpt = None,
    maps: MapsOpt = None,
    limit_frames: LimitFramesOpt = None,
    sequences: SequencesOpt = None,
    taxonomy: TaxonomyOpt = None,
) -> None:
    """Build the dataset (or the selected stages) on the embedded default, a --config file or a
    --preset plan (--maps, --limit-frames and --sequences pick the towns and a slice of it)."""
    from carlaocc.pipeline.engine.runner import PlanError, resolve_scheduler, run as run_pipeline, stage_order

    cfg = plan_config(config, root, preset, maps, limit_frames, taxonomy)
    check_towns(cfg)
    voxel_sizes = parse_voxel_sizes(voxel_size, cfg)
    names = [s.strip() for s in stages.split(",") if s.strip()] if stages else None
    try:
        stage_order(names)
        resolve_scheduler(scheduler, probe=True)
    except PlanError as exc:
        fail(str(exc))
    store = open_store(root, writable=True)
    progress = RichProgress()
    t0 = time.perf_counter()
    try:
        outcomes = run_pipeline(store, cfg, voxel_sizes, names, scheduler, force, progress, workers,
                                log=lambda s: typer.echo(s, err=True), sequences=sequence_patterns(sequences))
    except PlanError as exc:  # refused before any task ran
        progress.close()
        fail(str(exc))
    except (StoreError, OSError) as exc:  # a failure during work
        progress.close()
        fail(f"{exc.filename}: {exc.strerror}" if isinstance(exc, OSError) and exc.filename and exc.strerror
             else exc, code=1)
    except BaseException:  # the error path reports it; the bar must not stay on screen
        progress.close()
        raise
    progress.close()
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
        typer.echo(f"done: ran {ran} of {total} tasks in {time.perf_counter() - t0:.1f} s; dataset at {store.url}")


@app.command()
def ingest(
    kind: Annotated[str, typer.Argument(help="source kind: folder, shapenet, buildingnet, meshfleet, carla (our UE export) or carla-recording (a CARLA recording in the CarlaOcc release layout: its vehicle models and walk cycle)")],
    path: Annotated[Path, typer.Argument(help="the source's root directory")],
    category_map: Annotated[Optional[Path], typer.Option("--category-map", help="folder sources: CSV with columns glob,category,subclass[,length_m]")] = None,
    root: RootOpt = "data",
    scheduler: Annotated[Optional[str], typer.Option("--scheduler", help="Dask scheduler address, or 'synchronous'")] = None,
    workers: Annotated[Optional[int], typer.Option("--workers", min=1, help="LocalCluster workers (default: one per core)")] = None,
    force: Annotated[bool, typer.Option("--force", help="re-ingest items even when unchanged")] = False,
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
        s = ingest_source(store, cfg, scheduler, force, progress, workers, log=lambda m: typer.echo(m, err=True))
    except (IngestError, PlanError) as exc:
        progress.close()
        fail(str(exc))
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
    maps = ", ".join(t.map for t in cfg.scenes.towns if t.style == "carla-recording")
    typer.echo(f"wrote {path}: towns {maps} from {recording}; `carlaocc run --root {root} --voxel-size 0.1` builds them")


@app.command()
def status(
    voxel_size: VoxelSizeOpt = "0.2",
    root: RootOpt = "data",
    config: ConfigOpt = None,
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="list every stale partition")] = False,
    preset: PresetOpt = None,
    maps: MapsOpt = None,
    limit_frames: LimitFramesOpt = None,
    sequences: SequencesOpt = None,
    taxonomy: TaxonomyOpt = None,
) -> None:
    """List what is stale and why (runs nothing, writes nothing), for the same plan and slice
    options as `carlaocc run`."""
    from carlaocc.pipeline.engine.runner import PlanError, status as plan_status

    cfg = plan_config(config, root, preset, maps, limit_frames, taxonomy)
    check_towns(cfg)
    voxel_sizes = parse_voxel_sizes(voxel_size, cfg)
    store = open_store(root, writable=False)
    try:
        plans = plan_status(store, cfg, voxel_sizes, sequence_patterns(sequences))
    except PlanError as exc:
        fail(str(exc))
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
            reasons[why] = reasons.get(why, 0) + 1
        summary = "; ".join(f"{n} {r}" for r, n in sorted(reasons.items(), key=lambda kv: -kv[1]))
        typer.echo(f"{name:<9} stale {len(stale)}/{total}: {summary}")
        if verbose:
            for pp in stale:
                typer.echo(f"    {pp.partition.key}: {pp.reason}")


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
    a summary of the plan (towns, sequences, frames) on stderr."""
    import yaml

    cfg = plan_config(config, root, preset, maps, limit_frames, taxonomy)
    typer.echo(yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False))
    towns = cfg.scenes.towns
    seqs = sum(t.sequences_of(level) for t in towns for level in t.traffic_levels if t.style != "carla-recording")
    typer.echo(f"plan: {len(towns)} towns, {seqs} simulated sequences x {cfg.scenes.frame_count} frames at "
               f"{cfg.scenes.rate_hz:g} Hz", err=True)
