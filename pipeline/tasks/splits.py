"""The splits stage: one task over the dataset assigns every sequence to train, val or test
(deterministic from ``splits.seed``) and writes ``<root>/splits/{train,val,test}.txt``. Every
export and the loader read them through :class:`carlaocc.catalog.splits.SplitStore`."""

from __future__ import annotations

from carlaocc.catalog.splits import SplitStore
from carlaocc.catalog.store import Store
from carlaocc.pipeline.engine.spec import Context, Partition, StageSpec
from carlaocc.pipeline.tasks.partitions import sequences, town_key
from carlaocc.schemas.configs import SplitsConfig
from carlaocc.stages.splits import assign_splits


def splits_partitions(ctx: Context) -> list[Partition]:
    """One partition: it reads every town's sequences (the scenes partitions)."""
    # every sequence, whatever a run selects: a slice never changes the splits
    ids = [s.sequence_id for s in sequences(ctx, selected=False)]
    needs = tuple(("scenes", town_key(i)) for i in range(len(ctx.config.scenes.towns)))
    return [Partition("dataset", {"sequences": ids}, needs=needs)]


def splits_task(store: Store, cfg: SplitsConfig, part: Partition) -> dict[str, str]:
    """Assign the partition's sequences and write the three split files."""

    assignment = assign_splits(part.params["sequences"], cfg.seed, cfg.val_fraction, cfg.test_fraction)
    return SplitStore(store).save(assignment)


SPEC = StageSpec(
    name="splits",
    description="train / val / test by sequence, deterministic from a seed (edited sequences follow their parent)",
    upstream=("scenes",),
    reads=("scenes/sequences/",),
    writes=("splits/train.txt", "splits/val.txt", "splits/test.txt"),
    partitions=splits_partitions,
    task=splits_task,
)
