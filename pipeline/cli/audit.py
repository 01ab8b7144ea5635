"""``carlaocc audit``: the paper's quality scores of other occupancy datasets on disk (the work
is :mod:`carlaocc.pipeline.commands.audit`, imported when the command runs: see
``carlaocc.pipeline.cli``, "Imports")."""

from __future__ import annotations

from typing import Annotated, Optional

import typer

from carlaocc.catalog.formats import FORMATS, DatasetInputError
from carlaocc.pipeline.cli.app import app
from carlaocc.pipeline.cli.common import fail


@app.command("audit")
def audit_cli(
    fmt: Annotated[str, typer.Argument(metavar="FORMAT", help=f"one of: {', '.join(FORMATS)}")],
    paths: Annotated[list[str], typer.Argument(metavar="PATH...", help="files of the format or directories "
                                               "(searched recursively, sorted by path)")],
    poses: Annotated[Optional[str], typer.Option("--poses", help="grid-frame-to-world 4x4 poses; enables s_tc. "
                                                 "Keyed: .json list of {\"frame\": sample token or path relative "
                                                 "to PATH, \"pose\": 4x4 or 16/12 numbers} in time order (needed "
                                                 "for occ3d scenes of several frames). Or one pose per frame in the "
                                                 "order the files are listed: .npy (N,4,4)/(N,3,4), .json, or text "
                                                 "with 12/16 numbers a line; a longer list for one numbered "
                                                 "sequence is indexed by frame number (KITTI poses.txt: one pose "
                                                 "per scan, SemanticKITTI voxels every 5th scan)")] = None,
    calib: Annotated[Optional[str], typer.Option("--calib", help="KITTI calib.txt: turn camera-0 --poses into "
                                                 "LiDAR poses with its Tr")] = None,
    json_out: Annotated[Optional[str], typer.Option("--json", help="write the scores (per frame, pair, class) "
                                                    "as JSON here")] = None,
    per_frame: Annotated[bool, typer.Option("--per-frame", help="print a row per frame too")] = False,
) -> None:
    """Quality scores of another dataset: spatial continuity s_sc, and temporal consistency s_tc
    with --poses (paper section 4.2, Table 4). Formats: occ3d, semantickitti, surroundocc,
    carlaocc-npz.

    s_tc pairs consecutive frames only within one sequence and sums the counts over sequences. A
    sequence is: occ3d, the scene directory (gts/SCENE/TOKEN/labels.npz); semantickitti, the
    voxels directory; surroundocc and carlaocc-npz, the file's directory. In a sequence, files
    named by frame numbers (semantickitti, surroundocc, carlaocc-npz) are in numeric order; occ3d
    sample tokens carry no time order, so its frames take the order of the keyed --poses list.
    Frames without a keyed pose are left out of s_tc (the summary line counts them)."""
    from carlaocc.pipeline.commands.audit import audit_command

    try:
        _, table = audit_command(fmt, paths, poses, calib, json_out, per_frame)
    except DatasetInputError as exc:
        fail(exc)
    typer.echo(table)
