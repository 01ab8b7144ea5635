"""What every command shares: the common options, the one error path (one line, exit 2 for bad
input, 1 for a failure during work, a traceback only with ``--debug``), config loading and the
up-front checks of what it references, voxel-size parsing, the store, progress bars and atomic
file output."""

from __future__ import annotations

import json
import os
import sys
import traceback
from pathlib import Path
from typing import Annotated, Any, Optional

import typer
from pydantic import ValidationError
from typer.core import TyperGroup

from carlaocc.catalog.store import Store, StoreError
from carlaocc.schemas.configs import DatasetConfig, parse_voxel_size_list


RootOpt = Annotated[str, typer.Option("--root", help="dataset root: a directory or an fsspec URL (memory://...)")]


VoxelSizeOpt = Annotated[str, typer.Option("--voxel-size", "--res", help="voxel size(s) in metres, comma-separated, e.g. 0.2 or 0.2,0.05 (--res is the short alias)")]


ConfigOpt = Annotated[Optional[Path], typer.Option("--config", help="YAML or JSON dataset config (see `carlaocc config`)")]
PresetOpt = Annotated[Optional[str], typer.Option("--preset", help="a shipped dataset plan instead of --config: paper (the CarlaOcc paper's 104 sequences x 1,000 frames)")]
MapsOpt = Annotated[Optional[Path], typer.Option("--maps", help="a folder of OpenDRIVE maps (e.g. CARLA's Town01..Town10HD .xodr): they replace the plan's towns, one town each, with the first town's traffic levels and sequence counts")]
TaxonomyOpt = Annotated[Optional[str], typer.Option("--taxonomy", help="label table: release (the official CarlaOcc release's utils/labels.py, the default) | carlaocc-v1 (Building a thing; poles, lights, signs stuff); overrides the config's taxonomy")]
SequencesOpt = Annotated[Optional[str], typer.Option("--sequences", help="build only the sequences matching these comma-separated patterns (fnmatch on sequence ids, e.g. 'town00_*' or 'town0?_high_00'); scenes and splits still cover every sequence")]
LimitFramesOpt = Annotated[Optional[int], typer.Option("--limit-frames", min=2, help="build only the first N frames of every sequence (a slice of the plan: the same poses as the whole plan)")]
# run / status / stage: what is not given comes from the root's remembered plan (<root>/plan.yaml)
PlanVoxelSizeOpt = Annotated[Optional[str], typer.Option("--voxel-size", "--res", help="voxel size(s) in metres, comma-separated, e.g. 0.2 or 0.2,0.05 (--res is the short alias; default: the root's remembered plan's, else 0.2)")]
PlanLimitFramesOpt = Annotated[Optional[int], typer.Option("--limit-frames", min=2, help="build only the first N frames of every sequence (a slice of the plan: the same poses as the whole plan; default: the remembered plan's slice)")]
PlanSequencesOpt = Annotated[Optional[str], typer.Option("--sequences", help="build only the sequences matching these comma-separated patterns (fnmatch on sequence ids, e.g. 'town00_*' or 'town0?_high_00'; '*': all); scenes and splits still cover every sequence (default: the remembered plan's slice)")]
DefaultPlanOpt = Annotated[bool, typer.Option("--default-plan", help="start from the default plan (the root's dataset.yaml, else the embedded default; every frame of every sequence at 0.2 m) instead of the root's remembered plan (<root>/plan.yaml); other options apply on top")]


DEBUG_ENV = "CARLAOCC_DEBUG"
_debug = False
DEBUG_HINT = "re-run with --debug for the traceback"


def set_debug(on: bool) -> None:
    """``carlaocc --debug``: errors print their traceback before their one line."""
    global _debug
    _debug = bool(on)


def debug_enabled() -> bool:
    return _debug or os.environ.get(DEBUG_ENV, "").strip().lower() not in ("", "0", "false", "no")


def fail(message: str | BaseException, code: int = 2) -> None:
    """Print a one-line error and exit (with ``--debug``, the traceback of the exception being
    handled first). ``message`` may be the exception itself (a pydantic error becomes its first
    error's line)."""
    if debug_enabled() and sys.exc_info()[1] is not None:
        traceback.print_exc()
    text = pydantic_message(message) if isinstance(message, ValidationError) else one_line(message)
    typer.echo(f"error: {text}", err=True)
    raise typer.Exit(code)


def one_line(text: Any) -> str:
    """``text`` on one line: its lines joined (a multi-line message keeps its content)."""
    lines = [ln.strip() for ln in str(text).splitlines() if ln.strip()]
    return "; ".join(lines) if lines else "(no message)"


def pydantic_message(exc: ValidationError, names: dict[str, str] | None = None) -> str:
    """The first error of a pydantic ValidationError in one line, its field named by ``names``
    (field -> the option the user typed, e.g. ``region_min`` -> ``--origin``) when given."""
    err = exc.errors()[0]
    loc = ".".join(str(p) for p in err["loc"])
    field = (names or {}).get(str(err["loc"][0]) if err["loc"] else "", loc)
    msg = str(err["msg"]).removeprefix("Value error, ").removeprefix("Assertion failed, ")
    more = len(exc.errors()) - 1
    return one_line(f"{field + ': ' if field else ''}{msg}" + (f" (and {more} more)" if more else ""))


def _known_errors() -> tuple[type[BaseException], ...]:
    from carlaocc.pipeline.engine.runner import PlanError

    return (PlanError, StoreError, ValidationError, ValueError, OSError, LookupError)


def error_line(exc: BaseException) -> tuple[str, int]:
    """The one line and exit code of an exception no command handled: bad input the plan refuses
    (a PlanError, an invalid value) exit 2; anything else is a failure during work, exit 1;
    an exception of no known kind also says how to see its traceback."""
    from carlaocc.pipeline.engine.runner import PlanError

    if isinstance(exc, ValidationError):
        return pydantic_message(exc), 2
    if isinstance(exc, PlanError):
        return one_line(exc), 2
    if isinstance(exc, OSError) and exc.strerror and getattr(exc, "filename", None):
        return f"{exc.filename}: {exc.strerror}", 1
    if isinstance(exc, _known_errors()) and str(exc).strip():
        return one_line(exc), 1
    return f"{type(exc).__name__}: {one_line(exc)} ({DEBUG_HINT})", 1


def did_you_mean(word: str, choices, prefix: str = "") -> str:
    """``" (did you mean X?)"`` naming the choice closest to a mistyped ``word`` (one a prefix of
    the other counts as close: ``--resolution`` -> ``--res``), else ``""``. ``prefix`` is ignored
    when comparing (``--`` of options)."""
    import difflib

    names = [str(c) for c in choices]
    bare = word[len(prefix):] if prefix and word.startswith(prefix) else word
    stems = {c: c[len(prefix):] if prefix and c.startswith(prefix) else c for c in names}
    # a choice whose stem starts the word or the other way round, or holds it whole (--frames in
    # --limit-frames): those first; otherwise the closest spellings (of the stems, not the '--')
    near = [c for c, st in stems.items() if len(st) >= 3 and len(bare) >= 3
            and (bare.startswith(st) or st.startswith(bare) or (len(bare) >= 4 and bare in st))]
    if not near:
        by_stem = {st: c for c, st in stems.items()}
        near = [by_stem[m] for m in difflib.get_close_matches(bare, list(by_stem), n=2, cutoff=0.6)]
    return f" (did you mean {' or '.join(near[:2])}?)" if near else ""


def check_sequences(store: Store, ids, option: str) -> None:
    """Every sequence id in ``ids`` is one of the root's, else one line naming it, the closest
    id and how to list them (exit 2)."""
    from carlaocc.catalog.parquet import ParquetTable
    from carlaocc.schemas.records import SequenceRecord

    if not ids:
        return
    table = ParquetTable(store, SequenceRecord)
    known = sorted(s.sequence_id for s in table.load()) if table.paths() else []
    for sid in ids:
        if sid not in known:
            fail(f"{option} {sid}: no such sequence in {store.url}{did_you_mean(sid, known)}; "
                 f"`carlaocc info --root {store.url} -v` lists them")


def unknown_option_line(exc, command_path: str) -> str:
    """The one line for an option the command does not take, naming the closest it does take
    (with its aliases: ``--voxel-size / --res``)."""
    cmd = exc.ctx.command if exc.ctx is not None else None
    params = [p for p in getattr(cmd, "params", []) if getattr(p, "opts", None) and p.param_type_name == "option"]
    longs = {o: p for p in params for o in (*p.opts, *p.secondary_opts) if o.startswith("--")}
    hint = did_you_mean(exc.option_name, longs, prefix="--")
    if hint:
        picked = {id(longs[o]): longs[o] for o in hint.removeprefix(" (did you mean ").removesuffix("?)").split(" or ")}
        hint = " (did you mean " + " or ".join(" / ".join(p.opts) for p in picked.values()) + "?)"
    return f"no such option {exc.option_name} for `{command_path}`{hint}; `{command_path} --help` lists its options"


def report_exception(exc: BaseException) -> None:
    """Print ``exc`` as the one error line (its traceback first with ``--debug``) and exit."""
    if debug_enabled():
        traceback.print_exception(type(exc), exc, exc.__traceback__)
    message, code = error_line(exc)
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(code)


class CommandGroup(TyperGroup):
    """A command group whose mistyped commands and options are one line naming the closest ones
    (exit 2), not click's usage block: ``carlaocc`` and its sub-groups (``catalog``, ``show``...)."""

    def parse_args(self, ctx, args):
        # an option of `carlaocc` itself mistyped (--verison): one line, as for a command's
        try:
            return super().parse_args(ctx, args)
        except Exception as exc:
            if type(exc).__name__ != "NoSuchOption" or not hasattr(exc, "option_name"):
                raise
            typer.echo(f"error: {unknown_option_line(exc, ctx.command_path)}", err=True)
            raise typer.Exit(2) from None

    def resolve_command(self, ctx, args):
        # a mistyped command (carlaocc stauts): one line naming the closest commands
        name = args[0] if args else ""
        if name and not name.startswith("-") and self.get_command(ctx, name) is None:
            commands = self.list_commands(ctx)
            typer.echo(f"error: no such command {name!r}{did_you_mean(name, commands)}; `{ctx.command_path} "
                       f"--help` lists the commands", err=True)
            raise typer.Exit(2)
        return super().resolve_command(ctx, args)


class ErrorGroup(CommandGroup):
    """The ``carlaocc`` group: every command runs inside the one error path -- an exception no
    command turned into its own error line becomes one (:func:`error_line`), never a traceback
    unless ``--debug``. Typer's own exits and usage errors pass through. Output piped into a
    reader that stopped reading (``carlaocc stages | head -1``) ends the command quietly, exit 0,
    as it ends other command-line tools."""

    def invoke(self, ctx):
        from typer.exceptions import TyperException

        try:
            try:
                return super().invoke(ctx)
            except Exception as exc:
                # an option the command does not take (click's NoSuchOption, vendored by Typer as
                # typer._click): one line with the right hint, not click's usage block
                if type(exc).__name__ != "NoSuchOption" or not hasattr(exc, "option_name"):
                    raise
                sub = getattr(exc, "ctx", None)
                typer.echo(f"error: {unknown_option_line(exc, sub.command_path if sub else ctx.command_path)}",
                           err=True)
                raise typer.Exit(2) from None
        except (TyperException, typer.Exit, typer.Abort, KeyboardInterrupt, SystemExit):
            raise
        except BrokenPipeError:
            # the reader is gone: nothing more can be said to it, and the final flush must not fail
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
            raise typer.Exit(0) from None
        except Exception as exc:
            report_exception(exc)


def validation_message(source: str, exc: ValidationError) -> str:
    err = exc.errors()[0]
    loc = ".".join(str(p) for p in err["loc"]) or "(top level)"
    if err["type"] == "extra_forbidden":
        return f"{source}: unknown key {loc!r}"
    msg = err["msg"].removeprefix("Value error, ")  # a validator's own sentence, without pydantic's prefix
    return f"{source}: {loc}: {msg}"


DATASET_CONFIG = "dataset.yaml"  # a dataset root's own config (``carlaocc ingest carla-recording`` writes it)


def root_config(root: str | None) -> Path | None:
    """``<root>/dataset.yaml`` when the (local) dataset root has one, else None."""
    if not root or "://" in str(root):
        return None
    path = Path(root) / DATASET_CONFIG
    return path if path.is_file() else None


def plan_config(path: Path | None, root: str | None, preset: str | None, maps: Path | None = None,
                limit_frames: int | None = None, taxonomy: str | None = None,
                base: DatasetConfig | None = None) -> DatasetConfig:
    """:func:`load_config` of ``--config`` or ``--preset`` (not both; neither: ``base`` when
    given), then ``--maps`` (the folder's .xodr files as the towns), ``--limit-frames`` and
    ``--taxonomy`` applied."""
    if preset is not None:
        from carlaocc.catalog.presets import preset_path

        if path is not None:
            fail("give --config or --preset, not both")
        try:
            path = preset_path(preset)
        except ValueError as exc:
            fail(f"--preset: {exc}")
    cfg = base if base is not None and path is None else load_config(path, root)
    scenes = cfg.scenes
    if maps is not None:
        files = sorted(maps.glob("*.xodr")) if maps.is_dir() else []
        if not files:
            fail(f"--maps {maps}: " + ("no .xodr files in it" if maps.is_dir() else "is not a folder"))
        first = scenes.towns[0]
        towns = tuple(first.model_copy(update={"style": "opendrive", "opendrive": str(f.resolve()), "recording": None,
                                               "map": None}) for f in files)  # fmt: skip
        scenes = scenes.model_copy(update={"towns": towns})
    if limit_frames is not None:
        scenes = scenes.model_copy(update={"frame_count": min(int(limit_frames), scenes.frame_count)})
    update: dict = {"scenes": scenes}
    if taxonomy is not None:
        from carlaocc.schemas.taxonomy import LABEL_TABLES

        if taxonomy not in LABEL_TABLES:
            fail(f"--taxonomy {taxonomy!r}: unknown label table; valid: {', '.join(LABEL_TABLES)}")
        update["taxonomy"] = taxonomy
    try:
        return DatasetConfig.model_validate(cfg.model_copy(update=update).model_dump())
    except ValidationError as exc:
        fail(validation_message("config", exc))


def resolve_plan(store: Store, root: str, *, config: Path | None, preset: str | None, maps: Path | None,
                 limit_frames: int | None, sequences: str | None, taxonomy: str | None, voxel_size: str | None,
                 default_plan: bool):
    """The plan a ``run`` or ``status`` works on, and the root's remembered one (None without):
    the remembered plan (or, with ``default_plan`` or none remembered, the default plan: the
    root's ``dataset.yaml`` or the embedded default, 0.2 m, no slice), with the keys the options
    name replaced. Bad options are one-line errors (exit 2)."""
    from carlaocc.catalog.plan import PlanStore
    from carlaocc.schemas.plan import DEFAULT_VOXEL_SIZES, Plan, PlanSlice

    try:
        remembered = PlanStore(store).load()
    except StoreError as exc:
        if not default_plan:
            fail(exc)
        remembered = None  # --default-plan is the way past an unreadable plan file
    start = remembered if remembered is not None and not default_plan else None
    base = start.config if start is not None else load_config(None, root, plan=False)
    cfg = plan_config(config, root, preset, maps, None, taxonomy, base=base)
    text = voxel_size if voxel_size is not None else ",".join(
        str(v) for v in (start.voxel_sizes if start is not None else DEFAULT_VOXEL_SIZES))
    voxel_sizes = parse_voxel_sizes(text, cfg)
    old = start.slice if start is not None else PlanSlice()
    cut = PlanSlice(limit_frames=limit_frames if limit_frames is not None else old.limit_frames,
                    sequences=sequence_patterns(sequences) if sequences is not None else old.sequences)
    return Plan(voxel_sizes=voxel_sizes, slice=cut, config=cfg), remembered


def sequence_patterns(text: str | None) -> tuple[str, ...]:
    """``--sequences`` as a tuple of fnmatch patterns (empty: every sequence)."""
    return tuple(p.strip() for p in (text or "").split(",") if p.strip())


def remembered_plan(root: str | None):
    """The root's remembered plan (:class:`~carlaocc.schemas.plan.Plan`), None when it has none
    (or there is no root there yet); a plan file that cannot be read is a one-line error."""
    from carlaocc.catalog.plan import PlanStore

    if not root:
        return None
    try:
        return PlanStore(Store(root)).load()
    except StoreError as exc:
        fail(exc)
    except (ValueError, ImportError, OSError):  # not a usable root: the command's own check says so
        return None


def load_config(path: Path | None, root: str | None = None, plan: bool = True) -> DatasetConfig:
    """The dataset config from a YAML/JSON file; without one, the config of the root's
    remembered plan (``plan``, the default), else the root's own ``dataset.yaml`` when it has
    one (said on stderr), else the embedded default."""
    if path is None and plan:
        remembered = remembered_plan(root)
        if remembered is not None:
            return remembered.effective_config()
    if path is None:
        path = root_config(root)
        if path is None:
            return DatasetConfig()
        typer.echo(f"config: {path} (the dataset root's own; --config overrides it)", err=True)
    if not path.is_file():
        fail(f"--config {path} " + ("is a directory, not a YAML or JSON file" if path.is_dir() else "does not exist"))
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        fail(f"--config {path}: cannot read it as text: {getattr(exc, 'strerror', None) or exc}")
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
        fail(validation_message(f"config file {path}", exc))


MAX_FRAME_VOXELS = 1_000_000_000


def check_towns(cfg: DatasetConfig) -> None:
    """Every OpenDRIVE town is one the scenes stage can drive in, checked before any task runs:
    its file exists and parses, has roads, and the scenes stage's own lane graph builds from it
    (driving lanes, a drivable cycle: :func:`build_opendrive_network`); else a one-line error
    naming the file (exit 2)."""
    from carlaocc.catalog.opendrive import read_opendrive
    from carlaocc.catalog.towns import resolve_opendrive
    from carlaocc.stages.scenes.opendrive.network import build_opendrive_network

    for i, spec in enumerate(cfg.scenes.towns):
        if spec.opendrive is None:
            continue
        where = f"scenes.towns[{i}].opendrive"
        try:
            path = resolve_opendrive(spec.opendrive)
            odr = read_opendrive(path)
        except (OSError, ValueError) as exc:  # the messages name the file
            fail(f"{where}: {one_line(exc)}")
        try:
            if not odr.roads:
                raise ValueError(f"{path}: no roads")
            build_opendrive_network(odr, cfg.scenes.curb_height, str(path))
        except ValueError as exc:  # names the file
            fail(f"{where}: {one_line(exc)}; the scenes stage needs driving lanes it can drive around "
                 f"in: fix the file or drop the town")
        except Exception as exc:  # anything else the scenes task would trip over
            fail(f"{where}: {path}: cannot build its road network ({type(exc).__name__}: {one_line(exc)}); "
                 f"fix the file or drop the town")


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


def open_store(root: str, writable: bool) -> Store:
    """The dataset root of ``--root``: one that can be written (``writable``; it may not exist
    yet), or -- for commands that read -- one that exists and is a directory, else a one-line
    error naming it (exit 2) rather than the answer of an empty dataset."""
    try:
        store = Store(root)
        fs, path = store.fs, store.root
    except (ValueError, ImportError, OSError) as exc:  # an unknown fsspec protocol...
        fail(f"--root {root}: not a usable dataset root ({one_line(exc)})")
    if writable:
        try:
            store.check_writable()
        except StoreError as exc:
            fail(str(exc))
        return store
    try:
        exists, is_dir = fs.exists(path), fs.isdir(path)
    except OSError as exc:
        fail(f"--root {root}: cannot read the dataset root: {exc.strerror or one_line(exc)}")
    if not exists:
        fail(f"--root {root}: no dataset root there ({store.url} does not exist); give the root of a "
             f"built dataset, or build one with `carlaocc run --root {root}`")
    if not is_dir:
        fail(f"--root {root}: {store.url} is a file, not a dataset root directory")
    return store


class RichProgress:
    """A progress bar per stage: tasks done / total and elapsed time. ``on_start`` is called once,
    before the first stage's bar (when the run's up-front checks have passed and work starts)."""

    def __init__(self, on_start=None) -> None:
        self._on_start = on_start
        from rich.console import Console
        from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                                   TimeElapsedColumn, TimeRemainingColumn)

        # one line per stage however many tasks it has (100 K at the paper's scale): done/total,
        # elapsed, and the time left at the rate so far
        self._progress = Progress(
            TextColumn("{task.description:<9}"), BarColumn(), MofNCompleteColumn(),
            TextColumn("tasks"), TimeElapsedColumn(), TextColumn("left"), TimeRemainingColumn(),
            console=Console(stderr=True),
        )
        self._tasks: dict[str, int] = {}

    def start(self, stage: str, total: int) -> None:
        if self._on_start is not None:
            self._on_start()
            self._on_start = None
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
            self._tasks.clear()


def parse_floats(text: Optional[str], name: str, kind=float) -> Optional[tuple]:
    if text is None:
        return None
    what = "integers" if kind is int else "numbers"
    try:
        vals = tuple(kind(v) for v in text.split(","))
    except ValueError:
        fail(f"{name} must be three comma-separated {what}, got {text!r}")
    if len(vals) != 3:
        fail(f"{name} must be three comma-separated {what}, got {text!r}")
    return vals


def write_png(out: Path, image) -> None:
    from carlaocc.catalog.images import save_png

    if out.is_dir():
        fail(f"--out {out} is a directory; give a file name such as {out / 'asset.png'}")
    try:
        save_png(None, str(out), image)
    except (OSError, StoreError) as exc:
        fail(f"--out {out}: cannot write: {exc}")


def write_bytes(out: Path, data: bytes) -> None:
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_name(out.name + ".tmp")
        tmp.write_bytes(data)
        tmp.replace(out)
    except OSError as exc:
        fail(f"cannot write {out}: {exc.strerror or exc}")
