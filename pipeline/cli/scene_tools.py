"""``carlaocc scenes``: export a town's unified mesh or a frame's panoptic mesh, and edit
sequences (``swap``: new sequences whose actors of one class use other assets)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from carlaocc.catalog.store import StoreError
from carlaocc.pipeline.cli.app import scenes_app
from carlaocc.pipeline.cli.common import ConfigOpt, RootOpt, open_store, write_bytes, fail, load_config


@scenes_app.command("town-mesh")
def scenes_town_mesh(
    town: Annotated[str, typer.Argument(help="town name, e.g. town00 (see: carlaocc catalog query 'select * from towns')")],
    out: Annotated[Path, typer.Option("--out", help="GLB file to write")],
    root: RootOpt = "data",
) -> None:
    """Write the town's unified static mesh (world frame, Z up converted to glTF's Y up) as GLB:
    one primitive per (class, instance), per-vertex attributes _SEMANTIC and _INSTANCE, and
    extras naming the class and instance (the city-level reconstruction of the paper)."""
    from carlaocc.pipeline.commands.scene_editing import town_mesh_glb

    store = open_store(root, writable=False)
    try:
        data, triangles, placements = town_mesh_glb(store, town)
    except StoreError as exc:
        fail(str(exc))
    write_bytes(out, data)
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

    from carlaocc.pipeline.commands.scene_editing import frame_mesh_glb
    from carlaocc.stages.scenes.assembly import region_of_grid

    cfg = load_config(config, root)
    if range_m is None:
        region = region_of_grid(cfg.voxelize.grid(0.2))
    else:
        region = (np.array([-range_m, -range_m, -5.0]), np.array([range_m, range_m, 20.0]))
    store = open_store(root, writable=False)
    try:
        data, triangles = frame_mesh_glb(store, sequence, frame, region)
    except StoreError as exc:
        fail(str(exc))
    write_bytes(out, data)
    typer.echo(f"wrote {out}: {triangles:,} triangles of {sequence} frame {frame}")


@scenes_app.command("swap")
def scenes_swap(
    class_name: Annotated[str, typer.Option("--class", help="class whose actors and static objects get other assets, e.g. Car, Building, Static")],
    seed: Annotated[int, typer.Option("--seed", help="seed of the replacement draw")],
    sequence: Annotated[Optional[list[str]], typer.Option("--sequence", help="sequence id(s) to edit (default: every original sequence)")] = None,
    root: RootOpt = "data",
    config: ConfigOpt = None,
) -> None:
    """Parametric editing: new sequences <id>~swap-<class>-s<seed> in which every actor and static
    object (building, prop) of the class uses another asset with a compatible footprint;
    trajectories, rig, timing and lots are unchanged; nothing is written (exit 2) when nothing can
    be swapped; parent_sequence_id and the runs table record where they came from. Then
    `carlaocc run --stages voxelize,quality` voxelizes them."""
    from carlaocc.pipeline.commands.scene_editing import swap_class

    cfg = load_config(config, root)
    store = open_store(root, writable=True)
    try:
        results = swap_class(store, class_name, seed, sequence or None, cfg.scenes.asset_sources)
    except StoreError as exc:
        fail(str(exc))
    for r in results:
        typer.echo(f"{r.sequence_id}: {r.swapped} {class_name} actor(s) and {r.swapped_static} static placement(s) "
                   f"swapped, {r.kept + r.kept_static} kept (no compatible asset); parent {r.parent}")
