"""What every command shares: the common options, one-line errors (exit 2), config loading,
voxel-size parsing, the store, progress bars and atomic file output."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Optional

import typer
from pydantic import ValidationError

from carlaocc.catalog.store import Store, StoreError
from carlaocc.schemas.configs import DatasetConfig, parse_voxel_size_list


RootOpt = Annotated[str, typer.Option("--root", help="dataset root: a directory or an fsspec URL (memory://...)")]


VoxelSizeOpt = Annotated[str, typer.Option("--voxel-size", "--res", help="voxel size(s) in metres, comma-separated, e.g. 0.2 or 0.2,0.05 (--res is the short alias)")]


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


def parse_voxel_sizes(text: str, config: DatasetConfig) -> tuple[float, ...]:
    """``--voxel-size`` text -> voxel sizes in metres, each checked against the config's region
    (at least one voxel; at most :data:`MAX_FRAME_VOXELS` a frame); else a one-line error."""
    try:
        values = parse_voxel_size_list(text)
        for v in values:
            grid = config.voxelize.grid(v)  # the region must hold at least one voxel
            n = grid.shape[0] * grid.shape[1] * grid.shape[2]
            if n > MAX_FRAME_VOXELS:
                raise ValueError(f"{n:.3g} voxels a frame ({' x '.join(map(str, grid.shape))}) exceeds "
                                 f"the {MAX_FRAME_VOXELS:.0e} a worker holds in memory; use a larger "
                                 f"voxel or a smaller region")
    except ValidationError as exc:
        fail(f"--voxel-size {text}: {exc.errors()[0]['msg'].removeprefix('Value error, ')}")
    except ValueError as exc:
        fail(f"--voxel-size {text}: {exc}")
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


def _write_png(out: Path, image) -> None:
    from carlaocc.catalog.images import save_png

    if out.is_dir():
        fail(f"--out {out} is a directory; give a file name such as {out / 'asset.png'}")
    try:
        save_png(None, str(out), image)
    except (OSError, StoreError) as exc:
        fail(f"--out {out}: cannot write: {exc}")


def _write_bytes(out: Path, data: bytes) -> None:
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_name(out.name + ".tmp")
        tmp.write_bytes(data)
        tmp.replace(out)
    except OSError as exc:
        fail(f"cannot write {out}: {exc.strerror or exc}")
