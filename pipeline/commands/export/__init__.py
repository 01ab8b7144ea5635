"""``carlaocc export``: a dataset's occupancy in the layouts models train on.

One module per format family; each declares its formats as :class:`ExportFormat` (name, a line
for ``--help``, options, writer), and :data:`FORMATS` lists them in this order:

* ``grids``   — ``occ3d``, ``semantickitti``, ``sscbench-kitti360``, ``surroundocc``: ours
  resampled onto their grids by class priority (export from the finest voxel size built)
* ``npz``     — ``carlaocc-npz``: our own grid, labels ``semantic << 11 | instance`` (or decimal)
* ``release`` — ``carlaocc-release``: the official CarlaOcc release's folder layout
* ``infos``   — ``mmdet3d-infos``: the OpenMMLab pipelines' info files, images, LiDAR, Occ3D gts
* ``flow``    — ``openocc-v2``, ``uniocc``: semantics, instances and flow in those layouts
* ``detgt``   — ``det-gt``: ground-truth boxes in the nuScenes detection layout (``eval det``)
* ``spec``    — what a format is, and what every format shares (sequences, label table, splits)

What a format computes is pure and lives in :mod:`carlaocc.stages.export` (and
:mod:`carlaocc.stages.export.resample`); the files it writes are encoded in
:mod:`carlaocc.catalog.formats`. Every export writes ``grid.json`` (the grid its files index and
``centre = origin + (index + 0.5) * voxel_size``; :mod:`carlaocc.catalog.formats.manifest`; an
export onto another dataset's grid adds ``built_region`` and ``coverage``, the share of that grid
our region covers, and marks the voxels outside it unobserved: :class:`spec.Coverage`) and,
for a root with splits, ``splits/{train,val,test}.txt`` restricted to the exported sequences.
Files are written atomically, one frame at a time.

An export that refuses writes nothing: :func:`export` has the format write into a staging folder
beside ``OUT`` (``.<OUT name>.export-*``, same file system) and moves its files into ``OUT`` only
when the writer returned; a refusal (StoreError / ValueError / FormatError), or any other error
or an interrupt, removes the staging folder and leaves ``OUT`` as it was (absent, empty, or an
earlier export's files byte-identical). A writer reads what is already in ``OUT``
(``carlaocc-release`` adds sequences to an earlier export) from :attr:`ExportJob.dest`.

Export is a command, not a registered stage: it writes outside the root, into a folder the user
names and may move, merge into (``carlaocc-release`` adds sequences to an earlier export) or
delete, and the root's lineage only vouches for what lives under the root.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path

from carlaocc.catalog.samples import DatasetError, FrameSamples
from carlaocc.catalog.store import Store, StoreError
from carlaocc.pipeline.commands.export import detgt, flow, grids, infos, npz, release
from carlaocc.pipeline.commands.export.spec import ExportFormat, ExportJob, ExportSummary, voxelized_sequences
from carlaocc.schemas.configs import DatasetConfig
from carlaocc.schemas.grid import voxel_size_key

FORMATS: dict[str, ExportFormat] = {f.name: f for m in (grids, npz, release, infos, flow, detgt) for f in m.FORMATS}

__all__ = ["FORMATS", "ExportFormat", "ExportJob", "ExportSummary", "export", "frame_count", "resolve_voxel_size"]


def export_format(name: str) -> ExportFormat:
    """The format called ``name``; ValueError naming the formats otherwise."""
    if name not in FORMATS:
        raise ValueError(f"unknown format {name!r}; formats: {', '.join(FORMATS)}")
    return FORMATS[name]


def resolve_voxel_size(store: Store, fmt: str, voxel_size: float | None) -> float:
    """The built voxel size (m) an export of ``fmt`` reads: ``voxel_size`` when given, else the
    format's default, else the finest size built where the format allows it; ValueError when
    the format needs one."""
    spec = export_format(fmt)
    if voxel_size is not None and spec.default_voxel_size is not None:
        # a format with its own voxel size pools its grids from a size dividing it
        ratio = spec.default_voxel_size / voxel_size
        if ratio < 1 - 1e-6 or abs(ratio - round(ratio)) > 1e-6:
            d = voxel_size_key(spec.default_voxel_size)
            raise ValueError(f"export {fmt} pools its {d} m grids from occupancy built at {d} m or a voxel size "
                             f"dividing it, not {voxel_size_key(voxel_size)} m: build {d} m first (`carlaocc run "
                             f"--res {d} --root {store.url}`), then export with --res {d}")
    if voxel_size is not None:
        return voxel_size
    if spec.default_voxel_size is not None:
        return spec.default_voxel_size
    if not spec.finest_by_default:
        raise ValueError(f"export {fmt} needs --voxel-size (the built voxel size to export from)")
    try:  # boxes do not depend on it: the finest size built picks the frames
        return FrameSamples(store.url, occupancy="none", cameras=False, lidar=False, boxes=False).voxel_size
    except DatasetError as exc:
        raise StoreError(str(exc)) from None


def export(store: Store, config: DatasetConfig, fmt: str, voxel_size: float, out: Path,
           sequences: list[str] | None = None, progress: Callable[[int], None] | None = None,
           **options: str) -> ExportSummary:
    """Write every frame of every voxelized sequence (or ``sequences``) at ``voxel_size`` in
    ``fmt`` under ``out``. ``options``: the format's own (``encoding`` for the CarlaOcc layouts);
    one it does not declare, or a value it does not allow, is a ValueError."""
    spec = export_format(fmt)
    for key, value in options.items():
        if key not in spec.options:
            raise ValueError(f"export {fmt} takes no {key} option (its options: {', '.join(spec.options) or 'none'})")
        if value not in spec.options[key]:
            raise ValueError(f"{key} must be one of {', '.join(spec.options[key])}, got {value!r}")
    chosen = {k: allowed[0] for k, allowed in spec.options.items()} | options
    out = Path(out)
    staging = staging_folder(out)
    try:
        job = ExportJob(store, config, fmt, voxel_size, staging, tuple(sequences) if sequences else None, progress,
                        chosen, dest=out)
        n_seq, n_frames, n_files = spec.write(job)
        merge_into(staging, out)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return ExportSummary(fmt, n_seq, n_frames, n_files, out, written_coverage(out))


def written_coverage(out: Path) -> float | None:
    """``coverage`` of ``out/grid.json`` (the share of the target grid our built region covers),
    None for a format that writes our own grid."""
    try:
        value = json.loads((out / "grid.json").read_text()).get("coverage")
    except (OSError, ValueError, AttributeError):
        return None
    return float(value) if isinstance(value, (int, float)) else None


def staging_folder(out: Path) -> Path:
    """A new empty folder beside ``out`` (in its nearest existing ancestor, so no folder is
    created on the way to ``out`` before the export succeeds) on the same file system."""
    parent = out.absolute().parent
    while not parent.is_dir():
        parent = parent.parent
    return Path(tempfile.mkdtemp(prefix=f".{out.name}.export-", dir=parent))


def merge_into(staging: Path, out: Path) -> None:
    """Move every file of ``staging`` to the same relative path under ``out`` (replacing a file
    there, keeping the others: ``carlaocc-release`` adds sequences to an earlier export)."""
    for root, _, files in os.walk(staging):
        for name in sorted(files):
            src = Path(root) / name
            dst = out / src.relative_to(staging)
            dst.parent.mkdir(parents=True, exist_ok=True)
            try:
                os.replace(src, dst)
            except OSError:  # OUT on another file system (a mount point): copy, then drop the staged file
                shutil.copy2(src, dst)
                src.unlink()
    out.mkdir(parents=True, exist_ok=True)


def frame_count(store: Store, voxel_size: float, sequences: list[str] | None) -> int:
    """Frames an export would write (for a progress bar)."""
    return sum(n for _, _, n in voxelized_sequences(store, voxel_size, sequences))
