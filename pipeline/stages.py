"""The registered stages and their partitions: ingest -> scenes -> voxelize, sensors -> metrics."""

from __future__ import annotations

from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.store import StoreError
from carlaocc.pipeline import tasks
from carlaocc.pipeline.report import report_task
from carlaocc.pipeline.registry import Context, Partition, StageSpec, UpstreamMissing
from carlaocc.schemas.records import SequenceRecord
from carlaocc.schemas.configs import DatasetConfig, MetricsConfig, SensorsConfig, VoxelizeConfig

INGEST_PARTITION = tasks.PROCEDURAL_SOURCE
# code every task runs through besides its stage's compute: the contracts, the readers/writers and
# the task wiring; editing any of it changes every stage's code version
SHARED_CODE = ("carlaocc.schemas", "carlaocc.catalog.store", "carlaocc.catalog.parquet", "carlaocc.catalog.meshes", "carlaocc.catalog.occupancy", "carlaocc.catalog.zarrio",
               "carlaocc.pipeline.tasks", "carlaocc.stages.geometry")


def _ingest_partitions(ctx: Context) -> list[Partition]:
    return [Partition(INGEST_PARTITION, {"source": INGEST_PARTITION})]


def _town_key(i: int) -> str:
    return f"town{i:02d}"


def _town_files(spec) -> tuple[str, ...]:
    """Input files of a town (its OpenDRIVE file), fingerprinted with the partition."""
    if spec.opendrive is None:
        return ()
    from carlaocc.catalog.towns import resolve_opendrive

    try:
        return (str(resolve_opendrive(spec.opendrive)),)
    except (FileNotFoundError, ValueError) as exc:
        raise StoreError(f"town opendrive file: {exc}") from None


def _scenes_partitions(ctx: Context) -> list[Partition]:
    """One per town; each reads the library of the configured asset sources (the procedural
    partition and every ingested item of the other sources) and its OpenDRIVE file."""
    sources = ctx.config.scenes.asset_sources
    needs = [("ingest", INGEST_PARTITION)] if "procedural" in sources else []
    others = tuple(s for s in sources if s != "procedural")
    if others:
        from carlaocc.catalog.lineage import LineageLog

        latest = LineageLog(ctx.store).latest("ingest")
        needs += [("ingest", k) for k, r in sorted(latest.items())
                  if r.status == "completed" and k.split(":")[0] in others]
    return [Partition(_town_key(i), {"town_index": i}, needs=tuple(needs), files=_town_files(spec))
            for i, spec in enumerate(ctx.config.scenes.towns)]


def _sequences(ctx: Context) -> list[SequenceRecord]:
    towns = {_town_key(i) for i in range(len(ctx.config.scenes.towns))}
    seqs = [s for s in ParquetTable(ctx.store, SequenceRecord).load() if s.town in towns]
    if not seqs:
        raise UpstreamMissing("no sequences yet: the scenes stage has not run")
    return sorted(seqs, key=lambda s: s.sequence_id)


def voxelize_config(config: DatasetConfig) -> VoxelizeConfig:
    """The voxelize stage's config: ``voxelize`` with the rig of ``scenes`` (masks are cast from
    the sensors the sequences were recorded with; a rig change re-runs both stages)."""
    return config.voxelize.model_copy(update={"rig": config.scenes.rig})


def _voxelize_partitions(ctx: Context) -> list[Partition]:
    out = []
    for seq in _sequences(ctx):
        for res in ctx.resolutions:
            key = ctx.config.voxelize.grid(res).key
            for t in range(seq.frame_count):
                out.append(Partition(
                    f"{seq.sequence_id}/{key}/{t:04d}",
                    {"sequence_id": seq.sequence_id, "resolution": res, "frame_index": t},
                    needs=(("ingest", INGEST_PARTITION), ("scenes", seq.town)),
                ))
    return out


def _voxelize_prepare(ctx: Context, to_run: list[Partition], partitions: list[Partition]) -> set[str]:
    """Create the Zarr arrays of every (sequence, resolution) about to be written; when an array
    had to be replaced, every frame of it is invalidated."""
    frames = {s.sequence_id: s.frame_count for s in _sequences(ctx)}
    occ = OccupancyStore(ctx.store)
    groups = {(p.params["sequence_id"], p.params["resolution"]) for p in to_run}
    invalid: set[str] = set()
    for seq, res in sorted(groups):
        vcfg = ctx.config.voxelize
        # the rig's LiDAR mount travels with the arrays: exports to ego-frame grids need it
        lidar_to_ego = [list(r) for r in ctx.config.scenes.rig.lidar.sensor_to_ego()]
        if occ.create(seq, vcfg.grid(res), frames[seq], vcfg.chunk_edge, extra_attrs={"lidar_to_ego": lidar_to_ego},
                      names=tasks.occupancy_arrays(vcfg)):
            invalid |= {p.key for p in partitions
                        if (p.params["sequence_id"], p.params["resolution"]) == (seq, res)}
    return invalid


def sensors_config(config: DatasetConfig) -> SensorsConfig:
    """The sensors stage's config: ``sensors`` with the rig of ``scenes``."""
    return config.sensors.model_copy(update={"rig": config.scenes.rig})


def _sensors_partitions(ctx: Context) -> list[Partition]:
    return [Partition(f"{seq.sequence_id}/{t:04d}", {"sequence_id": seq.sequence_id, "frame_index": t},
                      needs=(("ingest", INGEST_PARTITION), ("scenes", seq.town)))
            for seq in _sequences(ctx) for t in range(seq.frame_count)]


def _sensors_prepare(ctx: Context, to_run: list[Partition], partitions: list[Partition]) -> set[str]:
    """Create the camera arrays of every sequence about to be written (intrinsics and extrinsics
    in their attributes); a replaced array invalidates every frame of its sequence. The recorded
    path creates only the arrays it writes and leaves the recorder's ``*_raw`` arrays alone."""
    from carlaocc.catalog.sensors import SensorStore
    from carlaocc.stages.sensors import camera_poses

    cfg = sensors_config(ctx.config)
    rig = cfg.rig
    frames = {s.sequence_id: s.frame_count for s in _sequences(ctx)}
    sensors = SensorStore(ctx.store)
    to_lidar = camera_poses(rig)
    invalid: set[str] = set()
    for seq in sorted({p.params["sequence_id"] for p in to_run}):
        replaced = False
        for cam in cfg.selected_cameras(rig):
            attrs = {"intrinsics": [list(r) for r in cam.intrinsics],
                     "camera_to_ego": [list(r) for r in cam.camera_to_ego()],
                     "camera_to_lidar": to_lidar[cam.name].tolist(),
                     "camera_frame": "opencv: x right, y down, z forward", "source": cfg.source}
            replaced |= sensors.create(seq, cam.name, cam.width, cam.height, frames[seq], tasks.sensor_arrays(cfg),
                                       extra_attrs=attrs, keep_others=cfg.source == "recorded")
        if replaced:
            invalid |= {p.key for p in partitions if p.params["sequence_id"] == seq}
    return invalid


def _metrics_partitions(ctx: Context) -> list[Partition]:
    out = []
    vcfg = ctx.config.voxelize
    for seq in _sequences(ctx):
        for res in ctx.resolutions:
            grid = vcfg.grid(res)
            # every frame's occupancy, and the town's scenes partition (the frames' LiDAR poses)
            needs = tuple(("voxelize", f"{seq.sequence_id}/{grid.key}/{t:04d}") for t in range(seq.frame_count))
            needs += (("scenes", seq.town),)
            out.append(Partition(
                f"{seq.sequence_id}/{grid.key}",
                {"sequence_id": seq.sequence_id, "resolution": res, "grid": grid.model_dump(mode="json")},
                needs=needs,
            ))
    return out


def report_config(config: DatasetConfig) -> MetricsConfig:
    """The report stage's config: the metrics section (the report is the metrics' presentation)."""
    return config.metrics


def _report_partitions(ctx: Context) -> list[Partition]:
    """One partition over the whole dataset at the requested resolutions: it reads every metrics
    partition and what they read (every occupancy frame), the scenes and ingest partitions, and
    every sensors partition once the sensors stage has run (the report shows cameras then)."""
    from carlaocc.catalog.lineage import LineageLog

    needs: set[tuple[str, str]] = set()
    for p in _scenes_partitions(ctx):
        needs |= {("scenes", p.key), *p.needs}
    for p in _metrics_partitions(ctx):
        needs |= {("metrics", p.key), *p.needs}
    lineage = LineageLog(ctx.store)
    # the ADMesh plot counts the whole library: every ingested item, whichever source
    needs |= {("ingest", k) for k, r in lineage.latest("ingest").items() if r.status == "completed"}
    if lineage.latest("sensors"):
        needs |= {("sensors", p.key) for p in _sensors_partitions(ctx)}
    grids = [ctx.config.voxelize.grid(res) for res in ctx.resolutions]
    return [Partition("dataset", {"grids": [g.model_dump(mode="json") for g in grids],
                                  "sequences": [s.sequence_id for s in _sequences(ctx)]},
                      needs=tuple(sorted(needs)))]


STAGES: dict[str, StageSpec] = {
    s.name: s
    for s in (
        StageSpec(
            name="ingest",
            description="procedural ADMesh library: closed metric meshes of every thing class",
            upstream=(),
            code_modules=("carlaocc.stages.ingest", *SHARED_CODE),
            reads=(),
            writes=("admesh/meshes/<id>.glb", "admesh/assets/", "admesh/parts/"),
            partitions=_ingest_partitions,
            task=tasks.ingest_task,
        ),
        StageSpec(
            name="scenes",
            description="towns (procedural styles, OpenDRIVE), traffic, ego sequences, rig poses, actors",
            upstream=("ingest",),
            code_modules=("carlaocc.stages.scenes", *SHARED_CODE),
            reads=("admesh/assets/",),
            writes=("scenes/meshes/", "scenes/placements/", "scenes/towns/", "scenes/sequences/", "scenes/frames/",
                    "scenes/sensor_poses/", "scenes/actors/"),
            partitions=_scenes_partitions,
            task=tasks.scenes_task,
        ),
        StageSpec(
            name="voxelize",
            description="panoptic voxelization of every frame's scene mesh (exact triangle-box overlap)",
            upstream=("ingest", "scenes"),
            code_modules=("carlaocc.stages.voxelize", "carlaocc.stages.scenes", *SHARED_CODE),
            reads=("admesh/", "scenes/"),
            writes=("occupancy.zarr/<seq>/<res>/{semantic,instance,mask_camera,mask_lidar,flow}",),
            partitions=_voxelize_partitions,
            task=tasks.voxelize_task,
            prepare=_voxelize_prepare,
            config_of=voxelize_config,
        ),
        StageSpec(
            name="sensors",
            description="ray-cast camera maps and LiDAR, simulator artifacts, instance-guided rectification, normals",
            upstream=("ingest", "scenes"),
            code_modules=("carlaocc.stages.sensors", "carlaocc.stages.scenes", "carlaocc.catalog.sensors", *SHARED_CODE),
            reads=("admesh/", "scenes/", "sensors.zarr/<seq>/<cam>/*_raw (recorded source)"),
            writes=("sensors.zarr/<seq>/<cam>/{depth,semantic,instance,normal}[_raw]", "lidar/<seq>/",
                    "metrics/rectification/"),
            partitions=_sensors_partitions,
            task=tasks.sensors_task,
            prepare=_sensors_prepare,
            config_of=sensors_config,
        ),
        StageSpec(
            name="metrics",
            description="spatial continuity per frame, sequence and class; temporal consistency per frame pair "
                        "and sequence",
            upstream=("voxelize", "scenes"),
            # the scores' modules only: the report's statistics and plots live in the same package
            code_modules=("carlaocc.stages.metrics.continuity", "carlaocc.stages.metrics.temporal", *SHARED_CODE),
            reads=("occupancy.zarr/", "scenes/frames/"),
            writes=("metrics/quality/", "metrics/quality_classes/"),
            partitions=_metrics_partitions,
            task=tasks.metrics_task,
        ),
        StageSpec(
            name="report",
            description="statistics (voxels, instances, assets per class), plots and metrics/report.html",
            upstream=("ingest", "scenes", "voxelize", "sensors", "metrics"),
            code_modules=("carlaocc.stages.metrics", "carlaocc.stages.render_occupancy", "carlaocc.stages.render_sensors", "carlaocc.stages.render",
                          "carlaocc.catalog.admesh", "carlaocc.catalog.lineage", "carlaocc.catalog.images", "carlaocc.catalog.sensors", "carlaocc.catalog.usage",
                          "carlaocc.pipeline.report", *SHARED_CODE),
            reads=("admesh/assets/", "scenes/", "occupancy.zarr/", "sensors.zarr/", "metrics/quality/",
                   "catalog/runs/"),
            writes=("metrics/statistics_classes/", "metrics/statistics_assets/", "metrics/plots/",
                    "metrics/report.html"),
            partitions=_report_partitions,
            task=report_task,
            config_of=report_config,
        ),
    )
}
