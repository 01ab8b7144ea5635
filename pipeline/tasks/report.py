"""The report stage: dataset statistics (Parquet), their plots (PNG) and ``metrics/report.html``.

One task over the whole dataset (the requested voxel sizes). It reads only reduced tables: the
sequences' class statistics and quality scores (the aggregate stage's, summed from the quality
stage's per-frame counts), the ADMesh library and the lineage; and one frame, which it renders
(with its cameras when the sensors stage ran). It writes

* ``metrics/statistics_assets/dataset.parquet`` (:class:`AssetStatisticsRecord`),
* ``metrics/plots/*.png`` (class voxels, instances, static/dynamic share per voxel size; assets;
  quality; the rendered frame and camera sheet),
* ``metrics/report.html`` (:mod:`carlaocc.pipeline.tasks.report_page`).
"""

from __future__ import annotations

import numpy as np

from carlaocc.catalog.admesh import dedupe_assets
from carlaocc.catalog.images import png_bytes
from carlaocc.catalog.lineage import LineageLog
from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.sensors import SensorStore
from carlaocc.catalog.store import Store, StoreError
from carlaocc.catalog.usage import store_usage
from carlaocc.pipeline.engine.spec import Context, Partition, StageSpec
from carlaocc.pipeline.tasks.aggregate import aggregate_partitions
from carlaocc.pipeline.tasks.partitions import sequences
from carlaocc.pipeline.tasks.report_page import PLOTS_DIR, REPORT_HTML, SENSOR_STEP, render_html, stage_lineage
from carlaocc.pipeline.tasks.scenes import scenes_partitions
from carlaocc.pipeline.tasks.sensors import sensors_partitions
from carlaocc.schemas.configs import DatasetConfig, QualityConfig
from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.records import (AssetRecord, AssetStatisticsRecord, ClassStatisticsRecord, QualityRecord,
                                      SequenceRecord)
from carlaocc.stages.render.figures import occupancy_figure
from carlaocc.stages.render.sensors import CameraView, sensor_sheet
from carlaocc.stages.report import plots
from carlaocc.stages.report.statistics import asset_distribution, motion_share, voxel_size_totals

TABLE_KEY = "dataset"
FRAME_HEIGHT = 380  # pixels of the rendered occupancy frame's panels
RENDER_INSTANCE_VOXELS = 1 << 26  # larger frames are rendered by class (no instance grid in memory)
def _frame_png(store: Store, seq: str, grid: GridSpec, frame: int) -> bytes:
    """The occupancy figure of one frame (BEV, 3D view, legend); instances coloured per object
    unless the grid is larger than :data:`RENDER_INSTANCE_VOXELS` (a 0.05 m instance frame is
    1.6 GB: such frames are drawn by class from the semantic grid alone)."""

    occ = OccupancyStore(store)
    small = int(np.prod(grid.shape)) <= RENDER_INSTANCE_VOXELS and occ.exists(seq, grid, "instance")
    data = occ.read_frame(seq, grid, frame, ("semantic", "instance") if small else ("semantic",))
    sem, inst = data["semantic"], data.get("instance")
    mode = "instance" if small else "semantic"
    sheet = occupancy_figure(sem, inst, grid, f"{seq} frame {frame} at {grid.key} m, colouring: {mode}",
                             height=FRAME_HEIGHT, mode=mode)
    return png_bytes(sheet.image)


def recorded_camera_roles(store: Store, seq: str, frame: int) -> dict[str, str]:
    """``camera -> direction in words (and stereo place)`` from the frame's recorded sensor poses
    (the rig the sequence was recorded with, whatever the config says now); empty without them."""
    from carlaocc.pipeline.tasks.frame import frame_rows
    from carlaocc.schemas.records import FrameRecord, SensorPoseRecord
    from carlaocc.schemas.rig import pose_roles
    from carlaocc.stages.geometry import invert_pose, pose_from_list

    if not ParquetTable(store, SensorPoseRecord).exists(seq):
        return {}
    frames = frame_rows(store, FrameRecord, seq, frame)
    if not frames:
        return {}
    to_lidar = invert_pose(pose_from_list(frames[0].lidar_pose))
    cams = set(SensorStore(store).cameras(seq))
    return pose_roles({r.sensor: (to_lidar @ pose_from_list(r.pose)).tolist()
                       for r in frame_rows(store, SensorPoseRecord, seq, frame) if r.sensor in cams})


def _sensors_png(store: Store, seq: str, frame: int) -> bytes | None:
    """The camera sheet of one frame (the RGB when every camera has it, the rectified maps), each
    camera titled with its direction, or None without cameras."""

    sensors = SensorStore(store)
    roles = recorded_camera_roles(store, seq, frame)
    views = []
    for cam in sensors.cameras(seq):
        names = set(sensors.names(seq, cam))
        if not {"depth", "semantic", "normal"} <= names or not sensors.exists(seq, cam, "depth", frame):
            continue

        def read(name: str):
            return sensors.read_image(seq, cam, frame, name) if name in names else None

        views.append(CameraView(cam, read("depth"), read("semantic"), read("instance"), read("normal"),
                                rgb=read("rgb"), direction=roles.get(cam, "")))
    if not views:
        return None
    return png_bytes(sensor_sheet(views, step=SENSOR_STEP).image)


def report_task(store: Store, cfg: QualityConfig, part: Partition) -> dict[str, str]:
    """Statistics tables, plots and ``metrics/report.html`` of the requested voxel sizes."""

    grids = [GridSpec.model_validate(g) for g in part.params["grids"]]
    seq_ids = list(part.params["sequences"])
    t_seq = ParquetTable(store, SequenceRecord)
    sequences = sorted((s for s in t_seq.load() if s.sequence_id in set(seq_ids)), key=lambda s: s.sequence_id)
    if [s.sequence_id for s in sequences] != sorted(seq_ids):
        raise StoreError(f"sequences {sorted(set(seq_ids) - {s.sequence_id for s in sequences})} are not in "
                         f"{store.url}: run the scenes stage")
    outputs: dict[str, str] = {}
    # 1. class statistics of these sequences and voxel sizes (the aggregate stage's)
    t_cls = ParquetTable(store, ClassStatisticsRecord)
    keys = [f"{s.sequence_id}/{g.key}" for g in grids for s in sequences]
    missing = [k for k in keys if not t_cls.exists(k)]
    if missing:
        raise StoreError(f"{t_cls.path(missing[0])} is missing from {store.url}: run the aggregate stage")
    class_rows = t_cls.load(keys)
    if t_cls.exists(TABLE_KEY):  # the whole-dataset file an earlier layout wrote
        store.remove(t_cls.path(TABLE_KEY))
    # 2. the ADMesh library per class and source (duplicates once, as the catalog views list it)
    asset_rows = asset_distribution(dedupe_assets(ParquetTable(store, AssetRecord).load()))
    t_ast = ParquetTable(store, AssetStatisticsRecord)
    outputs[t_ast.path(TABLE_KEY)] = t_ast.save(TABLE_KEY, asset_rows)
    # 3. quality scores of these sequences and voxel sizes
    # (the sequence rows the aggregate stage wrote, with each sequence's worst frame: never the
    # frames' own rows, 100 K files at the paper's scale)
    t_q = ParquetTable(store, QualityRecord)
    quality = t_q.load([k for k in keys if t_q.exists(k)])
    # 4. plots
    png: dict[str, bytes] = {}
    totals = voxel_size_totals(class_rows)
    for grid in grids:
        s = totals.get(float(grid.voxel_size))
        if s is None:
            continue
        k = grid.key
        png[f"class_voxels_{k}"] = plots.class_voxel_plot(s.voxels, f"Occupied voxels per class, {k} m, "
                                                                    f"{s.frames} frames")
        png[f"instances_{k}"] = plots.instances_plot(s.instances, s.moving, f"Instances per class, {k} m "
                                                                            f"(per sequence, summed)")
        png[f"motion_{k}"] = plots.motion_plot(motion_share(s.voxels, s.instances, s.moving),
                                               f"Static vs dynamic, {k} m")
    png["assets"] = plots.asset_plot(asset_rows)
    png["quality"] = plots.quality_plot(quality)
    if sequences and grids:
        seq = sequences[0]
        finest = min(grids, key=lambda g: g.voxel_size)
        frame = seq.frame_count // 2
        png["frame"] = _frame_png(store, seq.sequence_id, finest, frame)
        cams = _sensors_png(store, seq.sequence_id, frame)
        if cams is not None:
            png["sensors"] = cams
    for name, data in png.items():
        rel = f"{PLOTS_DIR}/{name}.png"
        outputs[rel] = store.write_bytes(rel, data)
    # the report owns its plot directory: pictures of voxel sizes no longer reported go
    for rel in store.glob(PLOTS_DIR, ".png"):
        if rel not in outputs:
            store.remove(rel)
    # 5. the page
    usage = store_usage(store, exclude=(REPORT_HTML, PLOTS_DIR))
    page = render_html(
        root=store.url, sequences=sequences, grids=grids, totals=totals, asset_rows=asset_rows,
        quality=quality, usage=[(u.part, u.files, u.bytes) for u in usage],
        lineage=stage_lineage(LineageLog(store).load()), images=png, label_table=cfg.taxonomy,
        slice=part.params.get("slice"),
    )
    outputs[REPORT_HTML] = store.write_bytes(REPORT_HTML, page.encode())
    return outputs


def slice_line(chosen: list, every: list, patterns: tuple[str, ...]) -> str:
    """The part of the dataset a report covers, in words: ``"2 of 3 sequences (--sequences
    town00_*), 2 frames each"``."""
    counts = sorted({s.frame_count for s in chosen})
    frames = (f"{counts[0]} frames each" if len(counts) == 1 else f"{counts[0]}-{counts[-1]} frames each"
              if counts else "no frames")
    which = (f"{len(chosen)} of {len(every)} sequences (--sequences {','.join(patterns)})" if patterns
             else f"every sequence ({len(every)})")
    return f"{which}, {frames}"


def report_config(config: DatasetConfig) -> QualityConfig:
    """The report stage's config: the metrics section (the report is the metrics' presentation)
    with the dataset's taxonomy."""
    return config.quality.model_copy(update={"taxonomy": config.taxonomy})


def _report_partitions(ctx: Context) -> list[Partition]:
    """One partition over the whole dataset at the requested voxel sizes: it reads every aggregate
    partition (the sequences' statistics and scores), the scenes and ingest partitions, and the
    frame it renders: its occupancy at the finest size, and its cameras once the sensors stage has
    run."""

    needs: set[tuple[str, str]] = set()
    for p in scenes_partitions(ctx):
        needs |= {("scenes", p.key), *p.needs}
    needs |= {("aggregate", p.key) for p in aggregate_partitions(ctx)}
    lineage = LineageLog(ctx.store)
    # the ADMesh plot counts the whole library: every ingested item, whichever source
    needs |= {("ingest", k) for k, r in lineage.latest("ingest").items() if r.status == "completed"}
    seqs = sequences(ctx)
    grids = [ctx.config.voxelize.grid(voxel_size) for voxel_size in ctx.voxel_sizes]
    if seqs and grids:
        seq, finest = seqs[0], min(grids, key=lambda g: g.voxel_size)
        frame = seq.frame_count // 2
        needs.add(("voxelize", f"{seq.sequence_id}/{finest.key}/{frame:04d}"))
        if lineage.latest("sensors"):
            needs |= {("sensors", p.key) for p in sensors_partitions(ctx) if p.key == f"{seq.sequence_id}/{frame:04d}"}
    return [Partition("dataset", {"grids": [g.model_dump(mode="json") for g in grids],
                                  "sequences": [s.sequence_id for s in seqs],
                                  "slice": slice_line(seqs, sequences(ctx, selected=False), ctx.sequence_patterns)},
                      needs=tuple(sorted(needs)))]


SPEC = StageSpec(
    name="report",
    description="statistics (voxels, instances, assets per class), plots and metrics/report.html",
    upstream=("ingest", "scenes", "voxelize", "sensors", "aggregate"),
    reads=("admesh/assets/", "scenes/", "metrics/statistics_classes/", "metrics/quality/", "catalog/runs/",
           "occupancy.zarr/ and sensors.zarr/ (the one frame rendered)"),
    writes=("metrics/statistics_assets/", "metrics/plots/", "metrics/report.html"),
    partitions=_report_partitions,
    task=report_task,
    config_of=report_config,
)
