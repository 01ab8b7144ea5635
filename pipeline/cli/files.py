"""Commands on mesh and grid files outside the pipeline's stages: ``voxelize`` (any mesh files
to a grid), ``export`` (to the layouts models train on), ``compare-resolutions``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Optional

import typer

from carlaocc.catalog.store import StoreError
from carlaocc.pipeline.cli.app import app
from carlaocc.pipeline.cli.common import (ConfigOpt, RootOpt, _floats, _store, _write_bytes,
                                         fail, load_config)


@app.command("voxelize")
def voxelize_files(
    meshes: Annotated[list[str], typer.Argument(help="mesh files (OBJ, PLY, STL, OFF, GLB...) or ADMesh asset ids")],
    voxel_size: Annotated[float, typer.Option("--voxel-size", help="voxel edge, metres (0.02 to 1.0 is the tested range)")],
    out: Annotated[Path, typer.Option("--out", help="OUT.npz (semantic, instance, voxel_size, voxel_origin, shape) or OUT.zarr")],
    class_name: Annotated[Optional[list[str]], typer.Option("--class", help="class of the mesh files: once for all, or once per file in order (e.g. Car)")] = None,
    fill: Annotated[str, typer.Option("--fill", help="auto: fill volumetric classes (vehicles, people, buildings, walls, poles, props, trunks); solid: fill every mesh; surface: fill nothing. Watertight meshes are filled by column parity, open ones by winding numbers")] = "auto",
    origin: Annotated[Optional[str], typer.Option("--origin", help="grid minimum corner x,y,z in metres (with --shape)")] = None,
    shape: Annotated[Optional[str], typer.Option("--shape", help="grid size nx,ny,nz in voxels (with --origin)")] = None,
    root: Annotated[Optional[str], typer.Option("--root", help="dataset root holding the ADMesh library, for asset ids")] = None,
) -> None:
    """Voxelize mesh files or ADMesh assets exactly (triangle-box overlap, solids filled even when
    not watertight), without a dataset. Prints where the voxels came from: surface, fill, and
    hole handling (filled voxels a flood fill from outside would not have found). Things get instance ids 1, 2, ... in argument order. The grid defaults to
    the meshes' bounding box snapped to multiples of the voxel size."""
    from carlaocc.pipeline.standalone import InputError, fill_summary, grid_for, load_inputs, save_result, voxelize_inputs
    from carlaocc.stages.voxelize.fill import FILL_MODES

    if fill not in FILL_MODES:
        fail(f"--fill must be one of {', '.join(FILL_MODES)}, got {fill!r}")
    if out.suffix.lower() not in (".npz", ".zarr"):
        fail(f"--out must end in .npz or .zarr, got {out}")
    store = _store(root, writable=False) if root else None
    try:
        scene = load_inputs(meshes, class_name or [], store)
        grid = grid_for(scene, voxel_size, _floats(origin, "--origin"), _floats(shape, "--shape", int))
        result = voxelize_inputs(scene, grid, fill)
        seconds = result.seconds
        save_result(result, out)
    except (InputError, ValueError) as exc:
        fail(exc)
    except OSError as exc:
        fail(f"--out {out}: cannot write: {exc.strerror or exc}")
    occupied = int((result.semantic > 0).sum())
    X, Y, Z = grid.shape
    typer.echo(f"wrote {out}: {X}x{Y}x{Z} grid at {voxel_size:g} m from origin "
               f"({', '.join(f'{c:g}' for c in grid.origin)}), {occupied:,} occupied voxels, "
               f"{sum(len(m.faces) for m in scene):,} triangles in {seconds:.2f} s")
    typer.echo(fill_summary(result, fill))


@app.command("export")
def export_cmd(
    fmt: Annotated[str, typer.Argument(help="occ3d | semantickitti | sscbench-kitti360 | surroundocc | carlaocc-npz | carlaocc-release | mmdet3d-infos | openocc-v2 | uniocc | det-gt")],
    out: Annotated[Path, typer.Option("--out", help="directory to write the dataset layout into")],
    res: Annotated[Optional[float], typer.Option("--voxel-size", "--res", help="the built voxel size (m) to export from (the finest gives the best resampling; carlaocc-release: 0.1 by default, any size dividing 0.1)")] = None,
    root: RootOpt = "data",
    config: ConfigOpt = None,
    sequence: Annotated[Optional[list[str]], typer.Option("--sequence", help="sequence id(s) to export (default: all voxelized)")] = None,
    label_encoding: Annotated[str, typer.Option("--label-encoding", help="carlaocc-npz / carlaocc-release labels: bits (semantic << 11 | instance, what the release's code writes and its loader reads; default) | decimal (semantic * 1000 + instance, the release's documentation; the files say so in a label_encoding key)")] = "bits",
) -> None:
    """Export the occupancy in the layouts models train on: occ3d (gts/<seq>/<frame>/labels.npz,
    200x200x16 at 0.4 m, ego frame, free 17, masks), semantickitti (sequences/<seq>/voxels/
    <frame>.bin/.label/.invalid/.occluded, 256x256x32 at 0.2 m, forward), sscbench-kitti360
    (preprocess/labels/<seq>/<frame>_1_1.npy and _1_8.npy, KITTI-360 ids, unobserved 255;
    data_2d_raw/<seq>/image_00/data_rect/<frame>.png), surroundocc
    (<seq>/<frame>.npy sparse rows, 200x200x16 at 0.5 m), carlaocc-npz (<seq>/<frame>.npz on our
    grid; labels semantic << 11 | instance as the release's code reads them, or --label-encoding
    decimal; ids renumbered per class where they would collide),
    carlaocc-release (the official release's layout: Town<NN>_Opt_Seq<NN>/occupancy/{vs_0_1,
    vs_0_2_forward_view, vs_0_4_surround_view}, poses, calib, splits, camera maps, LiDAR),
    mmdet3d-infos (carlaocc_infos_{train,val,test}.pkl/.json with the keys BEVDet / FlashOcc /
    SparseOcc pipelines read, samples/<camera>/<token>.jpg, samples/LIDAR_TOP/<token>.bin,
    gts/<scene>/<token>/labels.npz as Occ3D, grid.json; every path relative to --out),
    openocc-v2 (<seq>/<token>/labels.npz: semantics, instances, flow vx vy m/s, ego frame 0.4 m),
    uniocc (scene_infos.pkl, <seq>/<frame>.npz: occ_label, occ_mask_camera, occ_flow_forward /
    backward in voxels, ego pose, cameras, annotations), det-gt (det_gt.json: the boxes in the
    nuScenes detection result layout with velocities, attributes and LiDAR point counts, for
    carlaocc eval det). Every occupancy export writes grid.json (frame,
    origin, voxel size, axes, labels, centre = origin + (index + 0.5) * voxel size) and the
    dataset's splits beside it (splits/{train,val,test}.txt)."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from carlaocc.catalog.formats import FormatError
    from carlaocc.pipeline.export import FORMATS, export, frame_count

    if fmt not in FORMATS:
        fail(f"unknown format {fmt!r}; formats: {', '.join(FORMATS)}")
    if label_encoding not in ("bits", "decimal"):
        fail(f"--label-encoding {label_encoding!r}: must be bits or decimal")
    if res is None and fmt == "det-gt":  # boxes do not depend on it: the finest size built picks the frames
        from carlaocc.data import CarlaOccDataset, DatasetError

        try:
            res = CarlaOccDataset(root, occupancy="none", cameras=False, lidar=False, boxes=False).voxel_size
        except DatasetError as exc:
            fail(exc)
    if res is None:
        if fmt != "carlaocc-release":
            fail(f"export {fmt} needs --voxel-size (the built resolution to export from)")
        res = 0.1
    cfg = load_config(config, root)
    store = _store(root, writable=False)
    try:
        total = frame_count(store, cfg, res, sequence)
        with Progress(TextColumn(f"export {fmt}"), BarColumn(), MofNCompleteColumn(), TextColumn("frames"),
                      TimeElapsedColumn(), transient=True) as bar:
            task = bar.add_task(fmt, total=total)
            summary = export(store, cfg, fmt, res, out, sequence, progress=lambda n: bar.advance(task, n),
                             encoding=label_encoding)
    except (StoreError, FormatError, ValueError) as exc:
        fail(exc)
    except OSError as exc:
        fail(f"--out {out}: cannot write: {exc.strerror or exc}")
    typer.echo(f"wrote {summary.files:,} files for {summary.frames} frames of {summary.sequences} sequence(s) "
               f"in {fmt} layout under {out}")
    if fmt == "carlaocc-release":
        import json

        rates = {v["rate_hz"] for v in json.loads((out / "carlaocc_export.json").read_text())["sequences"].values()}
        if rates - {10.0}:
            typer.echo(f"note: the release's reader assumes 10 Hz (timestamp = frame * 0.1); these sequences run at "
                       f"{', '.join(f'{r:g}' for r in sorted(rates))} Hz (carlaocc_export.json records it; the paper "
                       f"preset is 10 Hz)", err=True)


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
    from carlaocc.stages.voxelize.pooling import pool_to_grid, pooling_disagreement

    from carlaocc.schemas.grid import resolution_key

    load_config(config, root)  # a bad --config is refused like everywhere else
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
        fail(exc)
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
