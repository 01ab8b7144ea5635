"""What a dataset root holds, read from the store without running anything (``carlaocc info``
and the last line of a build): its sequences, the frames voxelized at each voxel size, the
splits, the label table the occupancy was built under and its size on disk."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

from carlaocc.catalog.lineage import LineageLog
from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.splits import SplitStore
from carlaocc.catalog.usage import store_usage
from carlaocc.catalog.store import Store
from carlaocc.schemas.records import SequenceRecord


@dataclass(frozen=True)
class Inventory:
    """A dataset root's contents. ``frames_by_voxel_size``: voxel size key -> frames whose
    voxelize task completed (the latest lineage record of every ``<sequence>/<size>/<frame>``);
    ``sequences``: sequence id -> its record (frames planned, town, traffic level)."""

    url: str
    sequences: dict[str, SequenceRecord]
    frames_by_voxel_size: dict[str, int]
    sequences_by_voxel_size: dict[str, int]
    splits: dict[str, int]
    label_tables: tuple[str, ...]
    bytes: int
    files: int

    @property
    def voxel_sizes(self) -> tuple[str, ...]:
        return tuple(self.frames_by_voxel_size)

    @property
    def frames(self) -> int:
        """Frames voxelized at the finest voxel size built (0 when none)."""
        return self.frames_by_voxel_size[self.voxel_sizes[0]] if self.voxel_sizes else 0


def inventory(store: Store) -> Inventory:
    """The :class:`Inventory` of ``store`` (an empty one for a root with nothing built)."""
    table = ParquetTable(store, SequenceRecord)
    seqs = {s.sequence_id: s for s in sorted(table.load(), key=lambda s: s.sequence_id)} if table.paths() else {}
    # frames built: voxelize partitions whose latest record completed (key <sequence>/<size>/<frame>)
    frames: Counter[str] = Counter()
    seq_sets: dict[str, set[str]] = {}
    for key, rec in LineageLog(store).latest("voxelize").items():
        if rec.status != "completed" or key.count("/") != 2:
            continue
        seq, size, _ = key.split("/")
        frames[size] += 1
        seq_sets.setdefault(size, set()).add(seq)
    order = sorted(frames, key=float)
    # the label table recorded in the occupancy arrays (the data's own, not the config's)
    occ, tables = OccupancyStore(store), set()
    for size in order:
        for seq in sorted(seq_sets[size]):
            grid = occ.stored_grid(seq, float(size))
            if grid is not None:
                table_name = occ.attrs(seq, grid).get("label_table")
                if table_name:
                    tables.add(str(table_name))
    splits_store = SplitStore(store)
    splits = Counter(splits_store.load().values()) if splits_store.exists() else Counter()
    usage = store_usage(store)
    return Inventory(
        url=store.url, sequences=seqs,
        frames_by_voxel_size={k: frames[k] for k in order},
        sequences_by_voxel_size={k: len(seq_sets[k]) for k in order},
        splits={k: splits[k] for k in ("train", "val", "test") if k in splits},
        label_tables=tuple(sorted(tables)),
        bytes=sum(u.bytes for u in usage), files=sum(u.files for u in usage),
    )


__all__ = ["Inventory", "inventory"]
