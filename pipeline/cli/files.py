"""Commands on mesh and grid files outside the pipeline's stages: ``voxelize`` (any mesh files
to a grid), ``export`` (to the layouts models train on), ``compare-voxel-sizes`` (``compare-resolutions``, its
earlier name, is refused with the new one).

Each command imports its work when it runs (see ``carlaocc.pipeline.cli``, "Imports"); the
export command's help lists the registered formats, read from the registry when asked."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Annotated, Optional

import typer

from typer.core import TyperCommand

from carlaocc.catalog.store import StoreError
from carlaocc.pipeline.cli.app import app
from carlaocc.pipeline.cli.common import (ConfigOpt, RootOpt, check_sequences, fail, load_config, open_store,
                                          parse_floats, remembered_plan, write_bytes)
from carlaocc.schemas.grid import voxel_size_key


@app.command("voxelize")
def voxelize_files(
    meshes: Annotated[list[str], typer.Argument(help="mesh files (OBJ, PLY, STL, OFF, GLB...) or ADMesh asset ids")],
    voxel_size: Annotated[float, typer.Option("--voxel-size", "--res", help="voxel size (the voxel edge), metres (0.02 to 1.0 is the tested range; --res is the short alias)")],
    out: Annotated[Path, typer.Option("--out", help="OUT.npz: the occupied voxels only (format_version 1: voxel_index, the linear indices (i*Y + j)*Z + k ascending, with voxel_semantic and voxel_instance; voxel_size, voxel_origin, shape); carlaocc.catalog.voxel_file.load_voxels(OUT).dense() gives the dense arrays. OUT.zarr: dense semantic and instance arrays, empty chunks not written")],
    class_name: Annotated[Optional[list[str]], typer.Option("--class", help="class of the mesh files: once for all, or once per file in order (e.g. Car)")] = None,
    fill: Annotated[str, typer.Option("--fill", help="auto: fill volumetric classes (vehicles, people, buildings, walls, poles, props, trunks); solid: fill every mesh; surface: fill nothing. Watertight meshes are filled by column parity, open ones by winding numbers")] = "auto",
    origin: Annotated[Optional[str], typer.Option("--origin", help="grid minimum corner x,y,z in metres (with --shape)")] = None,
    shape: Annotated[Optional[str], typer.Option("--shape", help="grid size nx,ny,nz in voxels (with --origin)")] = None,
    root: Annotated[Optional[str], typer.Option("--root", help="dataset root holding the ADMesh library, for asset ids")] = None,
    dense: Annotated[bool, typer.Option("--dense", help="OUT.npz in the dense layout of earlier versions (semantic uint8 and instance uint32 of the whole grid, compressed; voxel_size, voxel_origin, shape): slower and as large in memory as the grid")] = False,
) -> None:
    """Voxelize mesh files or ADMesh assets exactly (triangle-box overlap, solids filled even when
    not watertight), without a dataset. Prints where the voxels came from: surface, fill, and
    hole handling (filled voxels a flood fill from outside would not have found). Things get instance ids 1, 2, ... in argument order. The grid defaults to
    the meshes' bounding box snapped to multiples of the voxel size. OUT.npz holds the occupied
    voxels (numpy alone: semantic = np.zeros(d["shape"], np.uint8); semantic.flat[d["voxel_index"]]
    = d["voxel_semantic"]; the same for instance); --dense writes the whole grids instead."""
    from carlaocc.pipeline.commands.standalone import (InputError, fill_summary, grid_for, load_inputs, save_result,
                                                       voxelize_inputs)
    from carlaocc.stages.voxelize.fill import FILL_MODES

    if fill not in FILL_MODES:
        fail(f"--fill must be one of {', '.join(FILL_MODES)}, got {fill!r}")
    # numba's OpenMP threads wait for work asleep, not spinning (unless the user chose otherwise):
    # on a busy machine a spinning thread burns its core while its partner is descheduled (the
    # bench street, load 3.5-4.3: 2.91-3.03 CPU s against 3.05-3.47, the same wall time). Read by
    # the OpenMP runtime when the first parallel kernel starts its threads, i.e. after this line.
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    if out.suffix.lower() not in (".npz", ".zarr"):
        fail(f"--out must end in .npz or .zarr, got {out}")
    if dense and out.suffix.lower() != ".npz":
        fail(f"--dense is a layout of OUT.npz; --out {out} is a Zarr group (always whole arrays)")
    store = open_store(root, writable=False) if root else None
    try:
        scene = load_inputs(meshes, class_name or [], store, fill)
        grid = grid_for(scene, voxel_size, parse_floats(origin, "--origin"), parse_floats(shape, "--shape", int))
        result = voxelize_inputs(scene, grid, fill)
        seconds = result.seconds
        save_result(result, out, dense=dense)
    except (InputError, ValueError) as exc:
        fail(exc)
    except OSError as exc:
        fail(f"--out {out}: cannot write: {exc.strerror or exc}")
    X, Y, Z = grid.shape
    typer.echo(f"wrote {out}: {X}x{Y}x{Z} grid at {voxel_size:g} m from origin "
               f"({', '.join(f'{c:g}' for c in grid.origin)}), {len(result.voxels):,} occupied voxels, "
               f"{sum(len(m.faces) for m in scene):,} triangles in {seconds:.2f} s")
    typer.echo(fill_summary(result, fill))


def export_help() -> str:
    """The export command's help: every registered format and what it writes under --out."""
    from carlaocc.pipeline.commands.export import FORMATS

    return ("Export the occupancy in the layouts models train on (the formats, what each writes under --out):\n\n"
            + "\n\n".join(f"{f.name}: {f.description}" for f in FORMATS.values())
            + "\n\nEvery occupancy export writes grid.json (frame, origin, voxel size, axes, labels, "
            "centre = origin + (index + 0.5) * voxel size) and the dataset's splits beside it "
            "(splits/{train,val,test}.txt).")


class ExportCommand(TyperCommand):
    """``carlaocc export``, whose full help is built from the format registry when it is shown."""

    def format_help_text(self, ctx, formatter) -> None:
        self.help = export_help()
        super().format_help_text(ctx, formatter)


@app.command("export", cls=ExportCommand,
             short_help="Export the occupancy in the layouts models train on (export --help lists them).")
def export_cmd(
    fmt: Annotated[str, typer.Argument(help="the format (listed above)")],
    out: Annotated[Path, typer.Option("--out", help="directory to write the dataset layout into")],
    voxel_size: Annotated[Optional[float], typer.Option("--voxel-size", "--res", help="the built voxel size (m) to export from (the finest gives the best resampling; carlaocc-release: 0.1 by default, any size dividing 0.1; det-gt: the finest built)")] = None,
    root: RootOpt = "data",
    config: ConfigOpt = None,
    sequence: Annotated[Optional[list[str]], typer.Option("--sequence", help="sequence id(s) to export (default: all voxelized)")] = None,
    label_encoding: Annotated[Optional[str], typer.Option("--label-encoding", help="carlaocc-npz / carlaocc-release labels: bits (semantic << 11 | instance, what the release's code writes and its loader reads; default) | decimal (semantic * 1000 + instance, the release's documentation; the files say so in a label_encoding key)")] = None,
) -> None:
    from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn,
                               TimeRemainingColumn)

    from carlaocc.catalog.formats import FormatError
    from carlaocc.pipeline.commands.export import FORMATS, export, frame_count, resolve_voxel_size

    if fmt not in FORMATS:
        fail(f"unknown format {fmt!r}; formats: {', '.join(FORMATS)}")
    options = {}
    if label_encoding is not None:
        if "encoding" not in FORMATS[fmt].options:
            fail(f"--label-encoding applies to {', '.join(n for n, f in FORMATS.items() if 'encoding' in f.options)}, "
                 f"not {fmt}")
        if label_encoding not in FORMATS[fmt].options["encoding"]:
            fail(f"--label-encoding {label_encoding!r}: must be {' or '.join(FORMATS[fmt].options['encoding'])}")
        options["encoding"] = label_encoding
    cfg = load_config(config, root)
    store = open_store(root, writable=False)
    check_sequences(store, sequence or [], "--sequence")
    spec = FORMATS[fmt]
    if voxel_size is None and spec.default_voxel_size is None and not spec.finest_by_default:
        plan = remembered_plan(root)  # the voxel size the root was planned at (its finest)
        if plan is not None:
            voxel_size = min(plan.voxel_sizes)
            typer.echo(f"export {fmt}: --voxel-size {voxel_size_key(voxel_size)} (the root's remembered plan)", err=True)
    try:
        voxel_size = resolve_voxel_size(store, fmt, voxel_size)
        total = frame_count(store, voxel_size, sequence)
        with Progress(TextColumn(f"export {fmt}"), BarColumn(), MofNCompleteColumn(), TextColumn("frames"),
                      TimeElapsedColumn(), TimeRemainingColumn(), transient=True) as bar:
            task = bar.add_task(fmt, total=total)
            summary = export(store, cfg, fmt, voxel_size, out, sequence, progress=lambda n: bar.advance(task, n),
                             **options)
    except (StoreError, FormatError, ValueError) as exc:
        fail(exc)
    except OSError as exc:
        # name the file that failed: one of the root's (read) or one under --out (write)
        name = exc.filename
        if name and store.is_local and os.path.abspath(name).startswith(store.root.rstrip("/") + "/"):
            fail(f"cannot read {name}: {exc.strerror or exc} (a file of the dataset root {store.url}; it must be "
                 f"readable by you)", code=1)
        fail(f"--out {out}: cannot write{f' {name}' if name else ''}: {exc.strerror or exc}")
    typer.echo(f"wrote {summary.files:,} files for {summary.frames} frames of {summary.sequences} sequence(s) "
               f"in {fmt} layout under {out}")
    if summary.coverage is not None and summary.coverage < 1.0:
        from carlaocc.pipeline.commands.export.spec import outside_phrase

        typer.echo(f"warning: the built region covers {100 * summary.coverage:.1f} % of the {fmt} grid; voxels outside "
                   f"it are {outside_phrase(fmt)} (see grid.json coverage)", err=True)
    if fmt == "carlaocc-release":
        rates = {v["rate_hz"] for v in json.loads((out / "carlaocc_export.json").read_text())["sequences"].values()}
        if rates - {10.0}:
            typer.echo(f"note: the release's reader assumes 10 Hz (timestamp = frame * 0.1); these sequences run at "
                       f"{', '.join(f'{r:g}' for r in sorted(rates))} Hz (carlaocc_export.json records it; the paper "
                       f"preset is 10 Hz)", err=True)


@app.command("compare-voxel-sizes")
def compare_voxel_sizes(
    fine: Annotated[float, typer.Option("--fine", help="the finer built voxel size (m), e.g. 0.05")],
    coarse: Annotated[float, typer.Option("--coarse", help="a coarser built voxel size (m), an integer multiple, e.g. 0.2")],
    root: RootOpt = "data",
    config: ConfigOpt = None,
    sequence: Annotated[Optional[list[str]], typer.Option("--sequence", help="sequence id(s) (default: all)")] = None,
    json_out: Annotated[Optional[Path], typer.Option("--json", help="also write the per-frame figures as JSON")] = None,
) -> None:
    """Pool the fine grid onto the coarse one by class priority and count where the pooled grid
    and the coarse grid voxelized directly from the meshes disagree (occupancy and label)."""
    from carlaocc.catalog.occupancy import OccupancyStore
    from carlaocc.pipeline.commands.export.spec import voxelized_sequences
    from carlaocc.stages.voxelize.pooling import pool_to_grid, pooling_disagreement

    load_config(config, root)  # a bad --config is refused like everywhere else
    store = open_store(root, writable=False)
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
        fail(f"no sequence has both {voxel_size_key(fine)} m and {voxel_size_key(coarse)} m occupancy in {store.url}")
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
        write_bytes(json_out, json.dumps(rows, indent=1).encode())


# Earlier names of commands, refused with the one to use (exit 2, one line; nothing is read or
# written), as the retired stage name ``metrics`` is (``RETIRED_STAGES`` in pipeline/engine/runner.py).
RETIRED_COMMANDS = {"compare-resolutions": "compare-voxel-sizes"}


def _refuse_retired(old: str) -> None:
    new = RETIRED_COMMANDS[old]
    fail(f"{old} was renamed {new}: use carlaocc {new} ...")


@app.command("compare-resolutions", hidden=True, add_help_option=False,
             context_settings={"ignore_unknown_options": True, "allow_extra_args": True})
def compare_resolutions_retired(ctx: typer.Context) -> None:
    """Retired name of ``compare-voxel-sizes``: refused with the new name."""
    _refuse_retired("compare-resolutions")
