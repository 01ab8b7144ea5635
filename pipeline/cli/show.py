"""Looking at the data, headless, to PNG: ``admesh show|sheet`` (library assets) and
``show occupancy|sensors`` (a frame's grids at one or more voxel sizes; its camera maps)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from carlaocc.catalog.store import Store, StoreError
from carlaocc.pipeline.cli.app import admesh_app, show_app
from carlaocc.pipeline.cli.common import (ConfigOpt, RootOpt, check_sequences, parse_voxel_sizes, open_store, write_png, fail,
                                         load_config)
from carlaocc.schemas import taxonomy
from carlaocc.schemas.configs import DatasetConfig


def _render_assets(store: Store, where: str | None, asset_id: str | None, limit: int, size: int = 512):
    """(labels, images, class ids, any translucent part) of assets chosen by id or by a SQL WHERE
    clause over the assets view, each part in its semantic class's palette colour, glass
    translucent."""
    from carlaocc.catalog.admesh import dedupe_parts
    from carlaocc.catalog.meshes import MeshStore
    from carlaocc.catalog.parquet import ParquetTable
    from carlaocc.catalog.sql import QueryError, query
    from carlaocc.schemas.records import PartRecord
    from carlaocc.schemas.meshes import MeshPart
    from carlaocc.stages.render.assets import render_asset

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
    meshes, labels, images, classes, translucent = MeshStore(store), [], [], set(), False
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
        classes |= {r.semantic_id for r in recs}
        translucent |= any(r.transparent for r in recs)
    return labels, images, classes, translucent


@admesh_app.command("show")
def admesh_show(
    asset_id: Annotated[str, typer.Argument(help="the asset id (see: carlaocc catalog query 'SELECT asset_id FROM assets')")],
    out: Annotated[Path, typer.Option("--out", help="PNG file to write")] = Path("asset.png"),
    root: RootOpt = "data",
) -> None:
    """Render one asset to a PNG (semantic colours, glass translucent), headless."""
    labels, images, _, _ = _render_assets(open_store(root, writable=False), None, asset_id, 1)
    write_png(out, images[0])
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
    """A sheet of the assets a query selects (parts in their class colours, a legend of the
    classes), headless."""
    from carlaocc.stages.render.assets import asset_sheet

    labels, images, classes, translucent = _render_assets(open_store(root, writable=False), where, None, limit, size)
    write_png(out, asset_sheet(images, labels, classes, columns=columns, translucent=translucent,
                               title=f"{len(images)} assets where {where}").image)
    typer.echo(f"{len(images)} assets -> {out}")


def _occupancy_frame(store: Store, cfg: DatasetConfig, sequence: str, frame: int, voxel_size: float):
    from carlaocc.catalog.occupancy import OccupancyStore

    from carlaocc.schemas.grid import voxel_size_key

    check_sequences(store, [sequence], "--seq")  # a mistyped id: did you mean, not "run ... first"
    occ = OccupancyStore(store)
    grid = occ.stored_grid(sequence, voxel_size)  # the grid it was built on, whatever the config says now
    if grid is None:
        key = voxel_size_key(voxel_size)
        fail(f"{sequence} has no occupancy at {key} m in {store.url}: run `carlaocc run --voxel-size {key}`")
    n = occ.open(sequence, grid, "semantic").shape[0]
    if not 0 <= frame < n:
        fail(f"{sequence} has frames 0..{n - 1}, not {frame}")
    data = occ.read_frame(sequence, grid, frame)
    return data["semantic"], data["instance"], grid


@show_app.command("occupancy")
def show_occupancy(
    seq: Annotated[str, typer.Option("--seq", help="sequence id (see: carlaocc catalog query 'select * from sequences')")],
    frame: Annotated[int, typer.Option("--frame", min=0, help="frame index")],
    voxel_size: Annotated[str, typer.Option("--voxel-size", "--res", help="voxel size (m), or several comma-separated for the multi-voxel-size figure (e.g. 0.05,0.1,0.2,0.5; --res is the short alias)")],
    out: Annotated[Path, typer.Option("--out", help="PNG file to write")] = Path("occupancy.png"),
    mode: Annotated[str, typer.Option("--mode", help="instance (things per instance, stuff in the palette) | semantic | height")] = "instance",
    root: RootOpt = "data",
    config: ConfigOpt = None,
) -> None:
    """Render one frame's occupancy: a top view with axes in metres and a 3D view (one voxel size),
    or the multi-voxel-size figure (3D views and a zoomed top view per voxel size); a key states
    the colouring (classes, things by their instances' colours, the ego marker; in height mode a
    scale in metres)."""
    from carlaocc.stages.render.figures import multi_voxel_size_figure, occupancy_figure

    if mode not in ("instance", "semantic", "height"):
        fail(f"--mode must be instance, semantic or height, got {mode!r}")
    cfg = load_config(config, root)
    voxel_sizes = parse_voxel_sizes(voxel_size, cfg)
    store = open_store(root, writable=False)
    if len(voxel_sizes) == 1:
        sem, inst, grid = _occupancy_frame(store, cfg, seq, frame, voxel_sizes[0])
        image = occupancy_figure(sem, inst, grid, f"{seq} frame {frame} at {grid.key} m, colouring: {mode}",
                                 mode=mode).image
    else:
        frames = []
        for size in voxel_sizes:
            sem, inst, grid = _occupancy_frame(store, cfg, seq, frame, size)
            frames.append((f"{grid.key} m", sem, inst, grid))
        image = multi_voxel_size_figure(frames, mode=mode, title=f"{seq} frame {frame}, colouring: {mode}").image
    write_png(out, image)
    typer.echo(f"wrote {out} ({image.shape[1]}x{image.shape[0]})")


def _frame_skeletons(store, seq: str, frame: int):
    """(W, J, 3) LiDAR-frame joints of the frame's walkers from the skeletons table (W may be 0)."""
    import numpy as np

    from carlaocc.catalog.parquet import ParquetTable
    from carlaocc.pipeline.tasks.frame import frame_rows
    from carlaocc.schemas.records import SkeletonRecord

    if not ParquetTable(store, SkeletonRecord).exists(seq):
        fail(f"--skeletons: {seq} has no skeletons table in {store.url}: run the scenes stage")
    rows = frame_rows(store, SkeletonRecord, seq, frame)
    by_walker: dict[int, list] = {}
    for r in sorted(rows, key=lambda r: (r.instance_id, r.joint_index)):
        by_walker.setdefault(r.instance_id, []).append(r.lidar)
    return np.array(list(by_walker.values()), dtype=np.float64).reshape(len(by_walker), -1, 3)


def _with_skeletons(view, joints, poses, rig, cam: str):
    """``view`` with the walkers' joints projected into camera ``cam``."""
    import dataclasses

    from carlaocc.stages.geometry import invert_pose, transform_points
    from carlaocc.stages.render.sensors import project_skeletons

    spec = next((c for c in rig.cameras if c.name == cam), None)
    if spec is None or len(joints) == 0:
        return view
    to_cam = invert_pose(poses[cam])
    cam_pts = transform_points(to_cam, joints.reshape(-1, 3)).reshape(joints.shape)
    uv, visible = project_skeletons(cam_pts, spec.intrinsics, view.depth)
    return dataclasses.replace(view, skeleton_uv=uv, skeleton_visible=visible)


@show_app.command("sensors")
def show_sensors(
    seq: Annotated[str, typer.Option("--seq", help="sequence id (see: carlaocc catalog query 'select * from sequences')")],
    frame: Annotated[int, typer.Option("--frame", min=0, help="frame index")],
    out: Annotated[Path, typer.Option("--out", help="PNG file to write")] = Path("sensors.png"),
    camera: Annotated[Optional[list[str]], typer.Option("--camera", help="camera(s) to show (default: every camera stored)")] = None,
    step: Annotated[int, typer.Option("--step", min=1, max=16, help="draw every n-th pixel row and column (2 halves 1408x376 images)")] = 2,
    skeletons: Annotated[bool, typer.Option("--skeletons", help="draw the walkers' skeletons (the skeletons table) over the semantic and instance maps: white where visible, grey where hidden")] = False,
    root: RootOpt = "data",
    config: ConfigOpt = None,
) -> None:
    """Sheet of one frame's camera maps, each panel titled with its camera and the direction it
    faces, each row with its key (the RGB -- recorded, or rendered from the scene --, depth,
    normals, semantics, instances per camera) and the rectification figure: raw vs rectified depth and semantics, pixels of the
    transparency region tinted red and of the omission region blue (epsilon from the config).
    With --skeletons, the walkers' posed joints and bones over the semantic and instance maps."""
    from carlaocc.catalog.sensors import SensorStore
    from carlaocc.schemas.rig import camera_roles
    from carlaocc.stages.render.sensors import CameraView, sensor_sheet

    cfg = load_config(config, root)
    roles = camera_roles(cfg.scenes.rig.cameras)  # the direction each camera faces, in words
    store = open_store(root, writable=False)
    sensors = SensorStore(store)
    stored = sensors.cameras(seq)
    if not stored:
        fail(f"{seq} has no camera maps in {store.url}: run `carlaocc run --stages ingest,scenes,sensors`")
    missing = [c for c in (camera or []) if c not in stored]
    if missing:
        fail(f"--camera {', '.join(missing)}: {seq} has maps of {', '.join(stored)} only")
    joints = _frame_skeletons(store, seq, frame) if skeletons else None
    poses = None
    if joints is not None:
        from carlaocc.stages.sensors import camera_poses

        poses = camera_poses(cfg.scenes.rig)
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
        view = CameraView(cam, read("depth"), read("semantic"), read("instance"), read("normal"),
                          read("depth_raw"), read("semantic_raw"), read("rgb"), direction=roles.get(cam, ""))
        if joints is not None:
            view = _with_skeletons(view, joints, poses, cfg.scenes.rig, cam)
        views.append(view)
    image = sensor_sheet(views, epsilon=cfg.sensors.epsilon, step=step).image
    write_png(out, image)
    typer.echo(f"wrote {out} ({image.shape[1]}x{image.shape[0]})")
