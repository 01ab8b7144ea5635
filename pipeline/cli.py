"""The ``carlaocc`` command line.

Exit codes: 0 ok, 1 a task failed (named with its partition), 2 a usage or input error (one line
naming the culprit; nothing in the dataset root is touched).
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import time
from pathlib import Path
from typing import Annotated, Optional

import typer
from pydantic import ValidationError

from carlaocc.catalog.store import Store, StoreError
from carlaocc.schemas import taxonomy
from carlaocc.schemas.configs import DatasetConfig, parse_resolutions

app = typer.Typer(
    name="carlaocc",
    help="Build instance-centric panoptic occupancy datasets from 3D meshes.\n\n"
    "Stages: ingest -> scenes -> voxelize -> metrics. Every stage is Dask tasks over partitions; "
    "unchanged work is skipped (lineage in <root>/catalog/runs).",
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)
catalog_app = typer.Typer(help="Read-only SQL over the dataset catalog (DuckDB).", no_args_is_help=True,
                          rich_markup_mode=None)
app.add_typer(catalog_app, name="catalog")
admesh_app = typer.Typer(help="Look at the ADMesh library: render assets to PNG (headless).",
                         no_args_is_help=True, rich_markup_mode=None)
app.add_typer(admesh_app, name="admesh")
scenes_app = typer.Typer(help="Towns and sequences: export meshes, edit sequences.", no_args_is_help=True,
                         rich_markup_mode=None)
app.add_typer(scenes_app, name="scenes")
show_app = typer.Typer(help="Look at the dataset: render frames to PNG (headless).", no_args_is_help=True,
                       rich_markup_mode=None)
app.add_typer(show_app, name="show")
from carlaocc.pipeline.evaluate import eval_app  # noqa: E402  (carlaocc eval ssc|panoptic|depth|det)

app.add_typer(eval_app, name="eval")

RootOpt = Annotated[str, typer.Option("--root", help="dataset root: a directory or an fsspec URL (memory://...)")]
ResOpt = Annotated[str, typer.Option("--res", help="voxel size(s) in metres, comma-separated, e.g. 0.2 or 0.2,0.05")]
ConfigOpt = Annotated[Optional[Path], typer.Option("--config", help="YAML or JSON dataset config (see `carlaocc config`)")]


def fail(message: str, code: int = 2) -> None:
    """Print a one-line error and exit."""
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(code)


def _validation_message(source: str, exc: ValidationError) -> str:
    err = exc.errors()[0]
    loc = ".".join(str(p) for p in err["loc"]) or "(top level)"
    if err["type"] == "extra_forbidden":
        return f"{source}: unknown key {loc!r}"
    return f"{source}: {loc}: {err['msg']}"


def load_config(path: Path | None) -> DatasetConfig:
    """The dataset config from a YAML/JSON file, or the embedded default."""
    if path is None:
        return DatasetConfig()
    if not path.is_file():
        fail(f"config file {path} does not exist")
    text = path.read_text()
    try:
        if path.suffix.lower() == ".json":
            data = json.loads(text)
        else:
            import yaml

            data = yaml.safe_load(text)
    except Exception as exc:
        fail(f"config file {path} cannot be parsed: {str(exc).splitlines()[0]}")
    if data is None:
        data = {}
    if not isinstance(data, dict):
        fail(f"config file {path}: expected a mapping of stage names to settings")
    try:
        return DatasetConfig.model_validate(data)
    except ValidationError as exc:
        fail(_validation_message(f"config file {path}", exc))


# a frame is held densely in memory (uint8 semantic + uint32 instance = 5 bytes a voxel)
MAX_FRAME_VOXELS = 1_000_000_000


def check_towns(cfg: DatasetConfig) -> None:
    """Every OpenDRIVE town's file exists and parses; else a one-line error naming it."""
    from carlaocc.catalog.opendrive import read_opendrive
    from carlaocc.catalog.towns import resolve_opendrive

    for i, spec in enumerate(cfg.scenes.towns):
        if spec.opendrive is None:
            continue
        try:
            read_opendrive(resolve_opendrive(spec.opendrive))
        except (OSError, ValueError) as exc:
            fail(f"scenes.towns[{i}].opendrive: {exc}")


def _resolutions(res: str, config: DatasetConfig) -> tuple[float, ...]:
    try:
        values = parse_resolutions(res)
        for v in values:
            grid = config.voxelize.grid(v)  # the region must hold at least one voxel
            n = grid.shape[0] * grid.shape[1] * grid.shape[2]
            if n > MAX_FRAME_VOXELS:
                raise ValueError(f"{n:.3g} voxels a frame ({' x '.join(map(str, grid.shape))}) exceeds "
                                 f"the {MAX_FRAME_VOXELS:.0e} a worker holds in memory; use a larger "
                                 f"voxel or a smaller region")
    except ValidationError as exc:
        fail(f"--res {res}: {exc.errors()[0]['msg'].removeprefix('Value error, ')}")
    except ValueError as exc:
        fail(f"--res {res}: {exc}")
    return values


def _store(root: str, writable: bool) -> Store:
    store = Store(root)
    if writable:
        try:
            store.check_writable()
        except StoreError as exc:
            fail(str(exc))
    return store


class _RichProgress:
    """A progress bar per stage: tasks done / total and elapsed time."""

    def __init__(self) -> None:
        from rich.console import Console
        from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                                   TimeElapsedColumn)

        self._progress = Progress(
            TextColumn("{task.description:<9}"), BarColumn(), MofNCompleteColumn(),
            TextColumn("tasks"), TimeElapsedColumn(), console=Console(stderr=True),
        )
        self._tasks: dict[str, int] = {}

    def start(self, stage: str, total: int) -> None:
        if not self._tasks:
            self._progress.start()
        self._tasks[stage] = self._progress.add_task(stage, total=total)

    def advance(self, stage: str) -> None:
        self._progress.advance(self._tasks[stage])

    def stop(self, stage: str) -> None:
        self._progress.refresh()

    def close(self) -> None:
        if self._tasks:
            self._progress.stop()


@app.command()
def run(
    res: ResOpt = "0.2",
    root: RootOpt = "data",
    stages: Annotated[Optional[str], typer.Option("--stages", help="comma-separated stages to run alone (default: all)")] = None,
    config: ConfigOpt = None,
    scheduler: Annotated[Optional[str], typer.Option("--scheduler", help="Dask scheduler address, or 'synchronous' for debugging (default: $DASK_SCHEDULER_ADDRESS, else a LocalCluster)")] = None,
    workers: Annotated[Optional[int], typer.Option("--workers", min=1, help="LocalCluster workers (default: one per core)")] = None,
    force: Annotated[bool, typer.Option("--force", help="re-run the selected stages even when up to date")] = False,
) -> None:
    """Build the dataset (or the selected stages) on the embedded default or a --config file."""
    from carlaocc.pipeline.runner import PlanError, resolve_scheduler, run as run_pipeline, stage_order

    cfg = load_config(config)
    check_towns(cfg)
    resolutions = _resolutions(res, cfg)
    names = [s.strip() for s in stages.split(",") if s.strip()] if stages else None
    try:
        stage_order(names)
        resolve_scheduler(scheduler)
    except PlanError as exc:
        fail(str(exc))
    store = _store(root, writable=True)
    progress = _RichProgress()
    t0 = time.perf_counter()
    try:
        outcomes = run_pipeline(store, cfg, resolutions, names, scheduler, force, progress, workers,
                                log=lambda s: typer.echo(s, err=True))
    except PlanError as exc:
        progress.close()
        fail(str(exc))
    except (StoreError, OSError) as exc:
        progress.close()
        fail(str(exc))
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
    kind: Annotated[str, typer.Argument(help="source kind: folder, shapenet, buildingnet, meshfleet or carla")],
    path: Annotated[Path, typer.Argument(help="the source's root directory")],
    category_map: Annotated[Optional[Path], typer.Option("--category-map", help="folder sources: CSV with columns glob,category,subclass[,length_m]")] = None,
    root: RootOpt = "data",
    scheduler: Annotated[Optional[str], typer.Option("--scheduler", help="Dask scheduler address, or 'synchronous'")] = None,
    workers: Annotated[Optional[int], typer.Option("--workers", min=1, help="LocalCluster workers (default: one per core)")] = None,
    force: Annotated[bool, typer.Option("--force", help="re-ingest items even when unchanged")] = False,
) -> None:
    """Ingest a mesh source into the ADMesh library: one task per source item; unchanged items
    are skipped, bad items quarantined with a reason (see the quarantine table), never fatal."""
    from carlaocc.pipeline.ingest import IngestError, ingest_source
    from carlaocc.pipeline.runner import PlanError, resolve_scheduler
    from carlaocc.schemas.configs import SourceIngestConfig

    try:
        cfg = SourceIngestConfig(kind=kind, root=str(path.resolve()),
                                 category_map=str(category_map.resolve()) if category_map else None)
    except ValidationError as exc:
        fail(_validation_message("ingest", exc).replace("ingest: kind: ", f"unknown source kind {kind!r}: "))
    try:
        resolve_scheduler(scheduler)
    except PlanError as exc:
        fail(str(exc))
    store = _store(root, writable=True)
    progress = _RichProgress()
    try:
        s = ingest_source(store, cfg, scheduler, force, progress, workers, log=lambda m: typer.echo(m, err=True))
    except (IngestError, PlanError) as exc:
        progress.close()
        fail(str(exc))
    progress.close()
    for f in s.failed[:10]:
        typer.echo(f"task failed: {f.stage} {f.partition}: {f.error}", err=True)
    reasons = ", ".join(f"{n} {r}" for r, n in s.quarantined.most_common())
    typer.echo(f"{cfg.kind} {cfg.root}: {s.items} items, {s.ran} ingested now, {s.skipped} unchanged; "
               f"library holds {s.ingested} assets from it, {sum(s.quarantined.values())} quarantined"
               + (f" ({reasons})" if reasons else "") + (f"; {s.pruned} vanished items pruned" if s.pruned else ""))
    if s.failed:
        raise typer.Exit(1)


@app.command()
def status(
    res: ResOpt = "0.2",
    root: RootOpt = "data",
    config: ConfigOpt = None,
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="list every stale partition")] = False,
) -> None:
    """List what is stale and why (runs nothing, writes nothing)."""
    from carlaocc.pipeline.runner import status as plan_status

    cfg = load_config(config)
    resolutions = _resolutions(res, cfg)
    store = _store(root, writable=False)
    for plan in plan_status(store, cfg, resolutions):
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
            reasons[pp.reason] = reasons.get(pp.reason, 0) + 1
        summary = "; ".join(f"{n} {r}" for r, n in sorted(reasons.items(), key=lambda kv: -kv[1]))
        typer.echo(f"{name:<9} stale {len(stale)}/{total}: {summary}")
        if verbose:
            for pp in stale:
                typer.echo(f"    {pp.partition.key}: {pp.reason}")


@app.command("stages")
def list_stages() -> None:
    """List the registered stages, what they read and write."""
    from carlaocc.pipeline.stages import STAGES

    for s in STAGES.values():
        typer.echo(f"{s.name}: {s.description}")
        typer.echo(f"    after: {', '.join(s.upstream) or '-'}")
        typer.echo(f"    writes: {', '.join(s.writes)}")


@app.command("config")
def show_config(config: ConfigOpt = None) -> None:
    """Print the effective dataset config as YAML (a starting point for --config files)."""
    import yaml

    typer.echo(yaml.safe_dump(load_config(config).model_dump(mode="json"), sort_keys=False))


def _format_value(v) -> str:
    if isinstance(v, float):
        return "NaN" if math.isnan(v) else f"{v:.6g}"
    return "NULL" if v is None else str(v)


@catalog_app.command("query")
def catalog_query(
    sql: Annotated[str, typer.Argument(help="a read-only SQL query over the catalog views")],
    root: RootOpt = "data",
    fmt: Annotated[str, typer.Option("--format", help="table, csv or json")] = "table",
) -> None:
    """Run read-only SQL. Views: assets, parts, quarantine, placements, sequences, frames, actors,
    runs, quality, quality_classes, statistics_classes, statistics_assets, classes."""
    from carlaocc.catalog.sql import QueryError, QueryRefused, query

    if fmt not in ("table", "csv", "json"):
        fail(f"--format {fmt!r}: choose table, csv or json")
    store = Store(root)
    try:
        cols, rows = query(store, sql)
    except QueryRefused as exc:
        fail(str(exc))
    except QueryError as exc:
        fail(f"SQL: {exc}")
    except StoreError as exc:
        fail(str(exc))
    if fmt == "json":
        clean = lambda v: None if isinstance(v, float) and not math.isfinite(v) else v  # JSON has no NaN
        typer.echo(json.dumps([{c: clean(v) for c, v in zip(cols, r)} for r in rows], default=str, indent=1))
    elif fmt == "csv":
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(cols)
        w.writerows(rows)
        typer.echo(buf.getvalue().rstrip("\n"))
    else:
        cells = [[_format_value(v) for v in r] for r in rows]
        widths = [max([len(c)] + [min(len(r[i]), 60) for r in cells]) for i, c in enumerate(cols)]
        typer.echo("  ".join(c.ljust(w) for c, w in zip(cols, widths)))
        typer.echo("  ".join("-" * w for w in widths))
        for r in cells:
            typer.echo("  ".join(v[:60].ljust(w) for v, w in zip(r, widths)))
        typer.echo(f"({len(rows)} rows)")


def _render_assets(store: Store, where: str | None, asset_id: str | None, limit: int, size: int = 512):
    """(labels, images) of assets chosen by id or by a SQL WHERE clause over the assets view,
    each part in its semantic class's palette colour, glass translucent."""
    from carlaocc.catalog.admesh import dedupe_parts
    from carlaocc.catalog.meshes import MeshStore
    from carlaocc.catalog.parquet import ParquetTable
    from carlaocc.catalog.sql import QueryError, query
    from carlaocc.schemas.records import PartRecord
    from carlaocc.stages.geometry import MeshPart
    from carlaocc.stages.render import render_asset

    if asset_id is not None:
        sql = f"SELECT asset_id, category, subclass, mesh_path FROM assets WHERE asset_id = '{asset_id.replace(chr(39), '')}'"
    else:
        sql = f"SELECT asset_id, category, subclass, mesh_path FROM assets WHERE {where} ORDER BY category, subclass, asset_id LIMIT {int(limit)}"
    try:
        _, rows = query(store, sql)
    except QueryError as exc:
        message = str(exc).splitlines()[0]
        if "convert string" in message and "category" in message:
            message += " (category holds class names: use category = 'Car', or category_id = 14)"
        fail(f"--where: {message}" if asset_id is None else message)
    if not rows:
        fail(f"no asset {asset_id!r} in {store.url}" if asset_id else f"no asset matches --where {where!r}")
    parts = {}
    for p in dedupe_parts(ParquetTable(store, PartRecord).load()):
        parts.setdefault(p.asset_id, []).append(p)
    meshes, labels, images = MeshStore(store), [], []
    for aid, category, subclass, mesh_path in rows:
        recs = sorted(parts.get(aid, []), key=lambda r: r.part_index)
        try:
            arrays = meshes.load(mesh_path)
        except StoreError as exc:
            fail(f"asset {aid}: {exc}")
        mesh_parts = [MeshPart(r.name, v, f, r.semantic_id, r.material, r.transparent,
                               color=(*taxonomy.by_id(r.semantic_id).color, 110 if r.transparent else 255))
                      for r, (v, f) in zip(recs, arrays)]
        images.append(render_asset(mesh_parts, size=size))
        labels.append(f"{category}/{subclass} {aid[:8]}")
    return labels, images


def _write_png(out: Path, image) -> None:
    from carlaocc.catalog.images import save_png

    if out.is_dir():
        fail(f"--out {out} is a directory; give a file name such as {out / 'asset.png'}")
    try:
        save_png(None, str(out), image)
    except (OSError, StoreError) as exc:
        fail(f"--out {out}: cannot write: {exc}")


@admesh_app.command("show")
def admesh_show(
    asset_id: Annotated[str, typer.Argument(help="the asset id (see: carlaocc catalog query 'SELECT asset_id FROM assets')")],
    out: Annotated[Path, typer.Option("--out", help="PNG file to write")] = Path("asset.png"),
    root: RootOpt = "data",
) -> None:
    """Render one asset to a PNG (semantic colours, glass translucent), headless."""
    labels, images = _render_assets(Store(root), None, asset_id, 1)
    _write_png(out, images[0])
    typer.echo(f"{labels[0]} -> {out}")


@admesh_app.command("sheet")
def admesh_sheet(
    where: Annotated[str, typer.Option("--where", help="SQL condition over the assets view, e.g. \"category = 'Car'\" or \"category_id = 14\"")] = "true",
    out: Annotated[Path, typer.Option("--out", help="PNG file to write")] = Path("assets.png"),
    limit: Annotated[int, typer.Option("--limit", min=1, max=400, help="at most this many assets")] = 48,
    columns: Annotated[int, typer.Option("--columns", min=1, max=20)] = 6,
    size: Annotated[int, typer.Option("--size", min=64, max=1024, help="thumbnail edge, pixels")] = 256,
    root: RootOpt = "data",
) -> None:
    """A contact sheet of the assets a query selects (semantic colours), headless."""
    from carlaocc.stages.render import contact_sheet

    labels, images = _render_assets(Store(root), where, None, limit, size)
    _write_png(out, contact_sheet(images, labels, columns=columns))
    typer.echo(f"{len(images)} assets -> {out}")


@scenes_app.command("town-mesh")
def scenes_town_mesh(
    town: Annotated[str, typer.Argument(help="town name, e.g. town00 (see: carlaocc catalog query 'select * from towns')")],
    out: Annotated[Path, typer.Option("--out", help="GLB file to write")],
    root: RootOpt = "data",
) -> None:
    """Write the town's unified static mesh (world frame, Z up converted to glTF's Y up) as GLB:
    one primitive per (class, instance), per-vertex attributes _SEMANTIC and _INSTANCE, and
    extras naming the class and instance (the city-level reconstruction of the paper)."""
    from carlaocc.pipeline.scenes import town_mesh_glb

    store = _store(root, writable=False)
    try:
        data, triangles, placements = town_mesh_glb(store, town)
    except StoreError as exc:
        fail(str(exc))
    _write_bytes(out, data)
    typer.echo(f"wrote {out}: {triangles:,} triangles from {placements:,} placements of {town}")


@scenes_app.command("frame-mesh")
def scenes_frame_mesh(
    sequence: Annotated[str, typer.Argument(help="sequence id, e.g. town00_low_seq000")],
    frame: Annotated[int, typer.Argument(min=0, help="frame index")],
    out: Annotated[Path, typer.Option("--out", help="GLB file to write")],
    root: RootOpt = "data",
    config: ConfigOpt = None,
    range_m: Annotated[Optional[float], typer.Option("--range", min=1.0, help="cut to a box of +-RANGE m around the LiDAR (default: the occupancy region of the voxelize config)")] = None,
) -> None:
    """Write one frame's panoptic scene mesh (LiDAR frame) as GLB, with per-face semantic and
    instance ids, for inspection."""
    import numpy as np

    from carlaocc.pipeline.scenes import frame_mesh_glb
    from carlaocc.stages.scenes.assembly import region_of_grid

    cfg = load_config(config)
    if range_m is None:
        region = region_of_grid(cfg.voxelize.grid(0.2))
    else:
        region = (np.array([-range_m, -range_m, -5.0]), np.array([range_m, range_m, 20.0]))
    store = _store(root, writable=False)
    try:
        data, triangles = frame_mesh_glb(store, sequence, frame, region)
    except StoreError as exc:
        fail(str(exc))
    _write_bytes(out, data)
    typer.echo(f"wrote {out}: {triangles:,} triangles of {sequence} frame {frame}")


@scenes_app.command("swap")
def scenes_swap(
    class_name: Annotated[str, typer.Option("--class", help="thing class whose actors get other assets, e.g. Car")],
    seed: Annotated[int, typer.Option("--seed", help="seed of the replacement draw")],
    sequence: Annotated[Optional[list[str]], typer.Option("--sequence", help="sequence id(s) to edit (default: every original sequence)")] = None,
    root: RootOpt = "data",
    config: ConfigOpt = None,
) -> None:
    """Parametric editing: new sequences <id>~swap-<class>-s<seed> in which every actor of the
    class uses another asset with a compatible footprint; trajectories, rig and timing are
    unchanged; parent_sequence_id and the runs table record where they came from. Then
    `carlaocc run --stages voxelize,metrics` voxelizes them."""
    from carlaocc.pipeline.scenes import swap_class

    cfg = load_config(config)
    store = _store(root, writable=True)
    try:
        results = swap_class(store, class_name, seed, sequence or None, cfg.scenes.asset_sources)
    except StoreError as exc:
        fail(str(exc))
    for r in results:
        typer.echo(f"{r.sequence_id}: {r.swapped} {class_name} instance(s) swapped, {r.kept} kept (no compatible asset)"
                   f"; parent {r.parent}")


def _floats(text: Optional[str], name: str, kind=float) -> Optional[tuple]:
    if text is None:
        return None
    try:
        vals = tuple(kind(v) for v in text.split(","))
    except ValueError:
        fail(f"{name} must be three comma-separated numbers, got {text!r}")
    if len(vals) != 3:
        fail(f"{name} must be three comma-separated numbers, got {text!r}")
    return vals


@app.command("voxelize")
def voxelize_files(
    meshes: Annotated[list[str], typer.Argument(help="mesh files (OBJ, PLY, STL, OFF, GLB...) or ADMesh asset ids")],
    voxel_size: Annotated[float, typer.Option("--voxel-size", help="voxel edge, metres (0.02 to 1.0 is the tested range)")],
    out: Annotated[Path, typer.Option("--out", help="OUT.npz (semantic, instance, voxel_size, voxel_origin, shape) or OUT.zarr")],
    class_name: Annotated[Optional[list[str]], typer.Option("--class", help="class of the mesh files: once for all, or once per file in order (e.g. Car)")] = None,
    fill: Annotated[str, typer.Option("--fill", help="auto: fill closed thing meshes; surface: fill nothing; solid: fill every closed mesh")] = "auto",
    origin: Annotated[Optional[str], typer.Option("--origin", help="grid minimum corner x,y,z in metres (with --shape)")] = None,
    shape: Annotated[Optional[str], typer.Option("--shape", help="grid size nx,ny,nz in voxels (with --origin)")] = None,
    root: Annotated[Optional[str], typer.Option("--root", help="dataset root holding the ADMesh library, for asset ids")] = None,
) -> None:
    """Voxelize mesh files or ADMesh assets exactly (triangle-box overlap, closed meshes filled),
    without a dataset. Things get instance ids 1, 2, ... in argument order. The grid defaults to
    the meshes' bounding box snapped to multiples of the voxel size."""
    from carlaocc.pipeline.standalone import InputError, grid_for, load_inputs, save_result, voxelize_inputs
    from carlaocc.stages.voxelize.compose import FILL_MODES

    if fill not in FILL_MODES:
        fail(f"--fill must be one of {', '.join(FILL_MODES)}, got {fill!r}")
    if out.suffix.lower() not in (".npz", ".zarr"):
        fail(f"--out must end in .npz or .zarr, got {out}")
    store = _store(root, writable=False) if root else None
    try:
        scene = load_inputs(meshes, class_name or [], store)
        grid = grid_for(scene, voxel_size, _floats(origin, "--origin"), _floats(shape, "--shape", int))
        t0 = time.perf_counter()
        result = voxelize_inputs(scene, grid, fill)
        seconds = time.perf_counter() - t0
        save_result(result, out)
    except (InputError, ValueError) as exc:
        fail(str(exc))
    except OSError as exc:
        fail(f"--out {out}: cannot write: {exc.strerror or exc}")
    occupied = int((result.semantic > 0).sum())
    X, Y, Z = grid.shape
    typer.echo(f"wrote {out}: {X}x{Y}x{Z} grid at {voxel_size:g} m from origin "
               f"({', '.join(f'{c:g}' for c in grid.origin)}), {occupied:,} occupied voxels, "
               f"{sum(len(m.faces) for m in scene):,} triangles in {seconds:.2f} s")


@app.command("export")
def export_cmd(
    fmt: Annotated[str, typer.Argument(help="occ3d | semantickitti | surroundocc | carlaocc-npz")],
    res: Annotated[float, typer.Option("--res", help="the built resolution to export from (the finest gives the best resampling)")],
    out: Annotated[Path, typer.Option("--out", help="directory to write the dataset layout into")],
    root: RootOpt = "data",
    config: ConfigOpt = None,
    sequence: Annotated[Optional[list[str]], typer.Option("--sequence", help="sequence id(s) to export (default: all voxelized)")] = None,
) -> None:
    """Export the occupancy in the layouts models train on: occ3d (gts/<seq>/<frame>/labels.npz,
    200x200x16 at 0.4 m, ego frame, free 17, masks), semantickitti (sequences/<seq>/voxels/
    <frame>.bin/.label/.invalid/.occluded, 256x256x32 at 0.2 m, forward), surroundocc
    (<seq>/<frame>.npy sparse rows, 200x200x16 at 0.5 m), carlaocc-npz (<seq>/<frame>.npz on our
    grid, sem << 11 | inst; refuses ids beyond 5/11 bits instead of wrapping)."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from carlaocc.catalog.formats import FormatError
    from carlaocc.pipeline.export import FORMATS, export, frame_count

    if fmt not in FORMATS:
        fail(f"unknown format {fmt!r}; formats: {', '.join(FORMATS)}")
    cfg = load_config(config)
    store = _store(root, writable=False)
    try:
        total = frame_count(store, cfg, res, sequence)
        with Progress(TextColumn(f"export {fmt}"), BarColumn(), MofNCompleteColumn(), TextColumn("frames"),
                      TimeElapsedColumn(), transient=True) as bar:
            task = bar.add_task(fmt, total=total)
            summary = export(store, cfg, fmt, res, out, sequence, progress=lambda n: bar.advance(task, n))
    except (StoreError, FormatError, ValueError) as exc:
        fail(str(exc))
    except OSError as exc:
        fail(f"--out {out}: cannot write: {exc.strerror or exc}")
    typer.echo(f"wrote {summary.files:,} files for {summary.frames} frames of {summary.sequences} sequence(s) "
               f"in {fmt} layout under {out}")


def _occupancy_frame(store: Store, cfg: DatasetConfig, sequence: str, frame: int, res: float):
    from carlaocc.catalog.occupancy import OccupancyStore

    from carlaocc.schemas.grid import resolution_key

    occ = OccupancyStore(store)
    grid = occ.stored_grid(sequence, res)  # the grid it was built on, whatever the config says now
    if grid is None:
        key = resolution_key(res)
        fail(f"{sequence} has no occupancy at {key} m in {store.url}: run `carlaocc run --res {key}`")
    n = occ.open(sequence, grid, "semantic").shape[0]
    if not 0 <= frame < n:
        fail(f"{sequence} has frames 0..{n - 1}, not {frame}")
    data = occ.read_frame(sequence, grid, frame)
    return data["semantic"], data["instance"], grid


@show_app.command("occupancy")
def show_occupancy(
    seq: Annotated[str, typer.Option("--seq", help="sequence id (see: carlaocc catalog query 'select * from sequences')")],
    frame: Annotated[int, typer.Option("--frame", min=0, help="frame index")],
    res: Annotated[str, typer.Option("--res", help="voxel size, or several comma-separated for the multi-resolution figure (e.g. 0.05,0.1,0.2,0.5)")],
    out: Annotated[Path, typer.Option("--out", help="PNG file to write")] = Path("occupancy.png"),
    mode: Annotated[str, typer.Option("--mode", help="instance (things per instance, stuff in the palette) | semantic | height")] = "instance",
    root: RootOpt = "data",
    config: ConfigOpt = None,
) -> None:
    """Render one frame's occupancy: a bird's-eye height map and a 3D view (one resolution), or
    the multi-resolution figure (3D views and a zoomed bird's-eye crop per resolution)."""
    from carlaocc.stages.render_occupancy import multi_resolution_figure, occupancy_figure

    if mode not in ("instance", "semantic", "height"):
        fail(f"--mode must be instance, semantic or height, got {mode!r}")
    cfg = load_config(config)
    resolutions = _resolutions(res, cfg)
    store = _store(root, writable=False)
    if len(resolutions) == 1:
        sem, inst, grid = _occupancy_frame(store, cfg, seq, frame, resolutions[0])
        image = occupancy_figure(sem, inst, grid, f"{seq} frame {frame} at {grid.key} m", mode=mode)
    else:
        frames = []
        for r in resolutions:
            sem, inst, grid = _occupancy_frame(store, cfg, seq, frame, r)
            frames.append((f"{grid.key} m", sem, inst, grid))
        image = multi_resolution_figure(frames, mode=mode, title=f"{seq} frame {frame}")
    _write_png(out, image)
    typer.echo(f"wrote {out} ({image.shape[1]}x{image.shape[0]})")


@show_app.command("sensors")
def show_sensors(
    seq: Annotated[str, typer.Option("--seq", help="sequence id (see: carlaocc catalog query 'select * from sequences')")],
    frame: Annotated[int, typer.Option("--frame", min=0, help="frame index")],
    out: Annotated[Path, typer.Option("--out", help="PNG file to write")] = Path("sensors.png"),
    camera: Annotated[Optional[list[str]], typer.Option("--camera", help="camera(s) to show (default: every camera stored)")] = None,
    step: Annotated[int, typer.Option("--step", min=1, max=16, help="draw every n-th pixel row and column (2 halves 1408x376 images)")] = 2,
    root: RootOpt = "data",
    config: ConfigOpt = None,
) -> None:
    """Contact sheet of one frame's camera maps (no RGB: depth, normals, semantics, instances per
    camera) and the rectification figure: raw vs rectified depth and semantics, pixels of the
    transparency region tinted red and of the omission region blue (epsilon from the config)."""
    from carlaocc.catalog.sensors import SensorStore
    from carlaocc.stages.render_sensors import CameraView, sensor_sheet

    cfg = load_config(config)
    store = _store(root, writable=False)
    sensors = SensorStore(store)
    stored = sensors.cameras(seq)
    if not stored:
        fail(f"{seq} has no camera maps in {store.url}: run `carlaocc run --stages ingest,scenes,sensors`")
    missing = [c for c in (camera or []) if c not in stored]
    if missing:
        fail(f"--camera {', '.join(missing)}: {seq} has maps of {', '.join(stored)} only")
    views = []
    for cam in camera or stored:
        names = set(sensors.names(seq, cam))
        n = sensors.open(seq, cam, "depth").shape[0] if "depth" in names else 0
        if not 0 <= frame < n:
            fail(f"{seq}/{cam} has frames 0..{n - 1}, not {frame}")

        def read(name: str):
            return sensors.read_image(seq, cam, frame, name) if name in names else None

        if read("normal") is None:
            fail(f"{seq}/{cam} has no normal map: run the sensors stage")
        views.append(CameraView(cam, read("depth"), read("semantic"), read("instance"), read("normal"),
                                read("depth_raw"), read("semantic_raw")))
    image = sensor_sheet(views, epsilon=cfg.sensors.epsilon, step=step)
    _write_png(out, image)
    typer.echo(f"wrote {out} ({image.shape[1]}x{image.shape[0]})")


@app.command("compare-resolutions")
def compare_resolutions(
    fine: Annotated[float, typer.Option("--fine", help="the finer built resolution, e.g. 0.05")],
    coarse: Annotated[float, typer.Option("--coarse", help="a coarser built resolution, an integer multiple, e.g. 0.2")],
    root: RootOpt = "data",
    config: ConfigOpt = None,
    sequence: Annotated[Optional[list[str]], typer.Option("--sequence", help="sequence id(s) (default: all)")] = None,
    json_out: Annotated[Optional[Path], typer.Option("--json", help="also write the per-frame figures as JSON")] = None,
) -> None:
    """Pool the fine grid onto the coarse one by class priority and count where the pooled grid
    and the coarse grid voxelized directly from the meshes disagree (occupancy and label)."""
    from carlaocc.catalog.occupancy import OccupancyStore
    from carlaocc.pipeline.export import voxelized_sequences
    from carlaocc.stages.voxelize.resample import pool_to_grid, pooling_disagreement

    from carlaocc.schemas.grid import resolution_key

    load_config(config)  # a bad --config is refused like everywhere else
    store = _store(root, writable=False)
    if not (fine > 0 and coarse > fine):
        fail(f"--coarse ({coarse}) must be larger than --fine ({fine}), both positive")
    occ = OccupancyStore(store)
    rows = []
    try:
        for seq, gf, n in voxelized_sequences(store, fine, sequence):
            gc = occ.stored_grid(seq, coarse)
            if gc is None:
                continue
            for t in range(n):
                pooled = pool_to_grid(occ.read_frame(seq, gf, t, ("semantic",))["semantic"], gf, gc)
                d = pooling_disagreement(occ.read_frame(seq, gc, t, ("semantic",))["semantic"], pooled)
                rows.append({"sequence": seq, "frame": t, **d})
    except (StoreError, ValueError) as exc:
        fail(str(exc))
    if not rows:
        fail(f"no sequence has both {resolution_key(fine)} m and {resolution_key(coarse)} m occupancy in {store.url}")
    typer.echo(f"{'sequence':<28} {'frames':>6} {'occ. IoU':>9} {'occ. mismatch':>14} {'label mismatch':>15} {'mismatch rate':>14}")
    for seq in sorted({r["sequence"] for r in rows}):
        rs = [r for r in rows if r["sequence"] == seq]
        # occupancy_mismatch = union - intersection, union = direct + pooled - intersection
        occ_mis = sum(r["occupancy_mismatch"] for r in rs)
        inter = sum(r["occupied_direct"] + r["occupied_pooled"] - r["occupancy_mismatch"] for r in rs) // 2
        union = inter + occ_mis
        lab_mis = sum(r["label_mismatch"] for r in rs)
        typer.echo(f"{seq:<28} {len(rs):>6} {inter / max(union, 1):>9.4f} {occ_mis:>14,} {lab_mis:>15,} "
                   f"{(occ_mis + lab_mis) / max(union, 1):>14.4f}")
    if json_out:
        _write_bytes(json_out, json.dumps(rows, indent=1).encode())


def _write_bytes(out: Path, data: bytes) -> None:
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_name(out.name + ".tmp")
        tmp.write_bytes(data)
        tmp.replace(out)
    except OSError as exc:
        fail(f"cannot write {out}: {exc.strerror or exc}")


from carlaocc.pipeline.audit import audit_cli  # noqa: E402  (after app: the audit command lives in its module)

app.command("audit")(audit_cli)


def main() -> None:
    """Console-script entry point."""
    os.environ.setdefault("PYTHONWARNINGS", "ignore::DeprecationWarning")
    app()


if __name__ == "__main__":
    main()
