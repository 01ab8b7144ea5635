"""What an export format is, and what every format shares: the sequences built at a voxel size,
the one label table they were built under, their splits, and the frames as loader samples.

A format declares an :class:`ExportFormat` (its name, a line for ``--help``, its options and its
writer), the way a stage declares a ``StageSpec``; the package's ``FORMATS`` lists them. A writer
takes an :class:`ExportJob` and returns ``(sequences, frames, files)`` written.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from carlaocc.catalog.formats.carlaocc_release import release_instance_ids
from carlaocc.catalog.formats.manifest import save_split_lists
from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.samples import DatasetError, FrameSamples
from carlaocc.catalog.splits import SPLIT_NAMES, SplitStore
from carlaocc.catalog.store import Store, StoreError
from carlaocc.schemas.configs import DatasetConfig
from carlaocc.schemas.grid import GridSpec, voxel_size_key
from carlaocc.schemas.records import ActorStateRecord, SequenceRecord, TownRecord
from carlaocc.stages.export.boxes import grid_coverage, region_in_target
from carlaocc.stages.geometry import boxes_in_frame


@dataclass(frozen=True)
class ExportJob:
    """One ``carlaocc export``: the root, its config, the built voxel size (m) to export from,
    where to write (``out``: a staging folder moved into ``dest`` once the writer returned, so a
    refusal writes nothing), the sequences (None: every voxelized one), a progress callback
    (frames), the format's options (its declared defaults filled in) and ``dest``, the folder
    the user named, where a writer reads what an earlier export left (None: ``out``)."""

    store: Store
    config: DatasetConfig
    format: str
    voxel_size: float
    out: Path
    sequences: tuple[str, ...] | None = None
    progress: Callable[[int], None] | None = None
    options: Mapping[str, str] = field(default_factory=dict)
    dest: Path | None = None

    @property
    def target(self) -> Path:
        """The folder the export ends up in (``dest``, else ``out``)."""
        return self.dest if self.dest is not None else self.out

    def advance(self, frames: int = 1) -> None:
        if self.progress:
            self.progress(frames)


@dataclass(frozen=True)
class ExportFormat:
    """A format ``carlaocc export`` writes. ``options``: option name -> allowed values, the first
    the default; ``default_voxel_size``: the size exported from when none is given (None: the
    voxel size is required, unless ``finest_by_default``: the finest size built)."""

    name: str
    description: str
    write: Callable[[ExportJob], tuple[int, int, int]]
    options: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    default_voxel_size: float | None = None
    finest_by_default: bool = False


@dataclass(frozen=True)
class ExportSummary:
    format: str
    sequences: int
    frames: int
    files: int
    out: Path
    coverage: float | None = None  # grid.json's: the share of the target grid our built region covers


# what each format writes where the target grid lies outside our built region
OUTSIDE_REGION = {
    "occ3d": "free (17) with mask_lidar and mask_camera 0",
    "mmdet3d-infos": "free (17) with mask_lidar and mask_camera 0",
    "semantickitti": "unlabeled (0), empty, .invalid and .occluded set",
    "sscbench-kitti360": "255 (unobserved, the ignore label)",
    "uniocc": "free (10) with occ_mask_camera 0",
    "surroundocc": "no row (free): the format has no mask, so this is not told apart from free space",
    "openocc-v2": "free (16): the format has no mask, so this is not told apart from free space",
}


class Coverage:
    """Which voxels of ``target`` (a ``TargetGrid``) our built region covers, per sequence
    (:func:`carlaocc.stages.export.boxes.grid_coverage`, computed once per grid and transform),
    and what ``grid.json`` says of it (:meth:`notes`)."""

    def __init__(self, target, fmt: str) -> None:
        self.target, self.format = target, fmt
        self._cache: dict = {}
        self.seen: dict[str, dict] = {}

    def inside(self, seq: str, grid: GridSpec, to_target) -> np.ndarray:
        """bool ``target.shape``: the voxels whose centre lies inside ``seq``'s region."""
        to_target = np.asarray(to_target, np.float64)
        key = (grid.model_dump_json(), to_target.round(9).tobytes())
        if key not in self._cache:
            inside = grid_coverage(self.target, grid, to_target)
            lo, hi = region_in_target(grid, to_target)
            self._cache[key] = inside, {"min": lo, "max": hi, "coverage": round(float(inside.mean()), 6)}
        inside, entry = self._cache[key]
        self.seen[seq] = entry
        return inside

    def notes(self) -> dict:
        """``grid.json`` keys: ``built_region`` (our region in the target frame: ``min`` / ``max``,
        or one per sequence when they differ), ``coverage`` (0..1, the share of the target's
        voxels whose centre lies inside it; the least over the sequences) and what the voxels
        outside it hold."""
        if not self.seen:
            return {}
        entries = list(self.seen.values())
        region: dict = {"frame": self.target.frame}
        if all(e == entries[0] for e in entries):
            region |= {"min": entries[0]["min"], "max": entries[0]["max"]}
        else:
            region["sequences"] = dict(sorted(self.seen.items()))
        return {"built_region": region, "coverage": min(e["coverage"] for e in entries),
                "coverage_definition": "share of the grid's voxels whose centre lies inside built_region",
                "outside_built_region": OUTSIDE_REGION.get(self.format, "unobserved")}


def outside_phrase(fmt: str) -> str:
    """How the CLI's warning says what lies outside the built region."""
    text = OUTSIDE_REGION.get(fmt, "")
    return "written free (the format has no mask)" if "no mask" in text else "marked unobserved"


def voxelized_sequences(store: Store, voxel_size: float,
                        sequences: tuple[str, ...] | list[str] | None) -> Iterator[tuple[str, GridSpec, int]]:
    """(sequence, the grid it was voxelized on at ``voxel_size``, frames) of every voxelized
    sequence (or of ``sequences``, refusing those not voxelized)."""
    seqs = sorted(ParquetTable(store, SequenceRecord).load(), key=lambda s: s.sequence_id)
    known = {s.sequence_id for s in seqs}
    for s in sequences or []:
        if s not in known:
            raise StoreError(f"sequence {s!r} is not in {store.url}")
    occ = OccupancyStore(store)
    for s in seqs:
        if sequences and s.sequence_id not in sequences:
            continue
        grid = occ.stored_grid(s.sequence_id, voxel_size)
        if grid is None:
            if sequences:
                key = voxel_size_key(voxel_size)
                raise StoreError(f"{s.sequence_id} has no occupancy at {key} m: run "
                                 f"`carlaocc run --stages voxelize --voxel-size {key}` first")
            continue
        yield s.sequence_id, grid, occ.open(s.sequence_id, grid, "semantic").shape[0]


def voxelized_export(job: ExportJob) -> tuple[list[tuple[str, GridSpec, int]], dict[str, str], str]:
    """What an export of our grids reads: the voxelized sequences (:func:`voxelized_or_refuse`),
    their splits (``{}`` for a root built before splits) and the one label table they were built
    under."""
    todo = voxelized_or_refuse(job.store, job.voxel_size, job.sequences)
    splits = sequence_splits(job.store, [s for s, _, _ in todo], required=False)
    return todo, splits, one_label_table(job.store, {s: g for s, g, _ in todo})


def voxelized_or_refuse(store: Store, voxel_size: float, sequences) -> list[tuple[str, GridSpec, int]]:
    """:func:`voxelized_sequences` as a list; StoreError when there is none."""
    todo = list(voxelized_sequences(store, voxel_size, sequences))
    if not todo:
        key = voxel_size_key(voxel_size)
        raise StoreError(f"no voxelized sequence at {key} m in {store.url}: run `carlaocc run --voxel-size {key}` first")
    return todo


def actor_ids(store: Store, seq: str) -> set[int]:
    """Instance ids of the sequence's simulated actors (the actors table)."""
    t = ParquetTable(store, ActorStateRecord)
    return set(t.load_arrow([seq])["instance_id"].to_pylist()) if t.exists(seq) else set()


def sequence_release_ids(occ: OccupancyStore, seq: str, grid: GridSpec, frame_count: int, moving=(),
                         encoding: str = "bits") -> dict[tuple[int, int], int]:
    """The exported instance id of every (class, instance) of a sequence's frames
    (:func:`carlaocc.catalog.formats.carlaocc_release.release_instance_ids`; ``moving``: the
    actors' ids), read one frame at a time."""
    pairs: set[tuple[int, int]] = set()
    for t in range(frame_count):
        data = occ.read_frame(seq, grid, t, ("semantic", "instance"))
        nz = data["instance"] != 0
        if nz.any():
            keys = np.unique((data["semantic"][nz].astype(np.int64) << 32) | data["instance"][nz].astype(np.int64))
            pairs |= {(int(k >> 32), int(k & 0xFFFFFFFF)) for k in keys.tolist()}
    if not pairs:
        return {}
    arr = np.array(sorted(pairs), dtype=np.int64)
    try:
        return release_instance_ids(arr[:, 0], arr[:, 1], moving, encoding, seq)
    except ValueError as exc:
        raise StoreError(str(exc)) from None


def sequence_splits(store: Store, sequences: list[str], required: bool = True) -> dict[str, str]:
    """The dataset's split of each of ``sequences``; StoreError when one is in none (the splits
    were written before it existed: re-run). Not ``required``: ``{}`` for a dataset built before
    splits existed."""
    if not required and not SplitStore(store).exists():
        return {}
    splits = SplitStore(store).load()
    missing = [s for s in sequences if s not in splits]
    if missing:
        raise StoreError(f"{missing[0]} is in no split of {store.url}/splits: re-run `carlaocc run` (the splits stage)")
    return {s: splits[s] for s in sequences}


def split_assignment(store: Store) -> dict[str, str]:
    """``{sequence id: split}`` of the root, ``{}`` when it has no readable splits."""
    try:
        return SplitStore(store).load()
    except StoreError:
        return {}


def save_sequence_splits(out: Path, sequences: list[str], assignment: Mapping[str, str]) -> int:
    """``out/splits/{train,val,test}.txt``: the exported sequences of each split (none written
    for a root built before splits existed); returns the files written."""
    if not assignment:
        return 0
    return save_split_lists(out, {split: sorted(s for s in sequences if assignment.get(s) == split)
                                  for split in SPLIT_NAMES})


def built_label_table(occ: OccupancyStore, seq: str, grid: GridSpec, scenes_table: str) -> str:
    """The label table a sequence's arrays were built under (arrays from before the table was
    recorded: ``carlaocc-v1``); StoreError when it is not ``scenes_table``, the one its town's
    scenes (instance ids) were last built under: a dataset never mixes two tables."""
    built = occ.attrs(seq, grid).get("label_table") or "carlaocc-v1"
    if built != scenes_table:
        raise StoreError(f"{seq} at {grid.key} m was voxelized under label table {built!r} but its scenes were rebuilt "
                         f"under {scenes_table!r}: re-run `carlaocc run --voxel-size {grid.key}` with that taxonomy")
    return built


def scenes_label_tables(store: Store) -> dict[str, str]:
    """``{sequence id: label table}``: the table each sequence's town was built under."""
    towns = {t.town: t.label_table for t in ParquetTable(store, TownRecord).load()}
    return {s.sequence_id: towns.get(s.town, "carlaocc-v1") for s in ParquetTable(store, SequenceRecord).load()}


def one_label_table(store: Store, grids: Mapping[str, GridSpec]) -> str:
    """The one label table the sequences of ``grids`` (sequence id -> grid) were built under;
    StoreError for two (a dataset export never mixes them)."""
    occ = OccupancyStore(store)
    scenes_tables = scenes_label_tables(store)
    tables = {built_label_table(occ, s, g, scenes_tables[s]) for s, g in grids.items()}
    if len(tables) > 1:
        raise StoreError(f"the sequences to export were built under different label tables "
                         f"({', '.join(sorted(tables))}): export them apart, or rebuild them under one taxonomy")
    return next(iter(tables))


def sample_with_boxes(ds: FrameSamples, index: int) -> dict:
    """Sample ``index`` of ``ds`` with its actors' boxes in the LiDAR frame (the loader's keys:
    ``boxes``, ``box_pose``, ``box_velocity``, ``box_instance``, ``box_semantic``)."""
    sample = ds[index]
    return sample | boxes_in_frame(ds.actor_rows(index), np.linalg.inv(sample["lidar_pose"]))


def frame_samples(store: Store, voxel_size: float | None, sequences, **options) -> FrameSamples:
    """The frames an export writes as loader samples (:class:`carlaocc.catalog.samples.FrameSamples`
    over the store; ``options`` its keyword options, occupancy left out: the formats read it
    themselves); StoreError when there is none."""
    try:
        return FrameSamples(store.url, voxel_size=voxel_size, occupancy="none",
                            sequences=list(sequences) if sequences else None, **options)
    except DatasetError as exc:
        raise StoreError(str(exc)) from None
