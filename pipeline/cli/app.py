"""The ``carlaocc`` Typer application and its command groups; each command module registers
its commands on them. The application's group runs every command inside the one error path
(:class:`carlaocc.pipeline.cli.common.ErrorGroup`); ``carlaocc --debug`` (or ``CARLAOCC_DEBUG=1``)
shows tracebacks."""

from __future__ import annotations

from typing import Annotated

import typer

from carlaocc.pipeline.cli.common import DEBUG_ENV, CommandGroup, ErrorGroup, set_debug

app = typer.Typer(
    cls=ErrorGroup,
    name="carlaocc",
    help="Build instance-centric panoptic occupancy datasets from 3D meshes.\n\n"
    "Stages (carlaocc run runs them in this order; --stages a,b runs some alone):\n\n"
    "ingest: the procedural ADMesh library (carlaocc ingest adds external sources)\n\n"
    "scenes: towns, traffic, ego sequences, rig poses, actors\n\n"
    "splits: train / val / test by sequence (seeded), used by every export\n\n"
    "voxelize: exact panoptic occupancy of every frame, flow, camera/LiDAR visibility masks\n\n"
    "sensors: ray-cast camera maps and LiDAR, rectification, normals\n\n"
    "quality: quality scores (spatial continuity, temporal consistency) and class statistics per frame\n\n"
    "aggregate: the scores and statistics of every sequence, summed from the frames'\n\n"
    "report: plots and metrics/report.html from the aggregates\n\n"
    "Every stage is Dask tasks over partitions; unchanged work is skipped (lineage in "
    "<root>/catalog/runs). `carlaocc stages` lists what each reads and writes.\n\n"
    "Errors are one line starting with 'error:'; exit code 2: bad input, refused before any work; "
    "1: a failure during work; --debug shows the traceback.",
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)


def _print_version(value: bool) -> None:
    if value:
        from importlib.metadata import PackageNotFoundError, version

        try:
            typer.echo(f"carlaocc {version('carlaocc')}")
        except PackageNotFoundError:  # run from a source tree that was never installed
            typer.echo("carlaocc (not installed: no version recorded)")
        raise typer.Exit(0)


@app.callback()
def _options(
    debug: Annotated[bool, typer.Option("--debug", envvar=DEBUG_ENV, show_envvar=True,
                                        help="on an error, print the full traceback before the one-line error")] = False,
    version: Annotated[bool, typer.Option("--version", is_eager=True, callback=_print_version,
                                          help="print carlaocc's version and exit")] = False,
) -> None:
    set_debug(debug)


catalog_app = typer.Typer(cls=CommandGroup, help="Read-only SQL over the dataset catalog (DuckDB).", no_args_is_help=True,
                          rich_markup_mode=None)
app.add_typer(catalog_app, name="catalog")
admesh_app = typer.Typer(cls=CommandGroup, help="Look at the ADMesh library: render assets to PNG (headless).",
                         no_args_is_help=True, rich_markup_mode=None)
app.add_typer(admesh_app, name="admesh")
scenes_app = typer.Typer(cls=CommandGroup, help="Towns and sequences: export meshes, edit sequences.", no_args_is_help=True,
                         rich_markup_mode=None)
app.add_typer(scenes_app, name="scenes")
show_app = typer.Typer(cls=CommandGroup, help="Look at the dataset: render frames to PNG (headless).", no_args_is_help=True,
                       rich_markup_mode=None)
app.add_typer(show_app, name="show")
