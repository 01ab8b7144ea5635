"""Train / val / test splits by sequence, deterministic from a seed.

Pure compute: sequence ids in, a split per sequence out. Edited sequences (``scenes swap``,
ids ``<parent>~<edit>``) copy their parent's trajectories, so they always share its split (no
leakage between train and test through an edit).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

__all__ = ["SPLITS", "parent_sequence", "assign_splits"]

SPLITS: tuple[str, ...] = ("train", "val", "test")


def parent_sequence(sequence_id: str) -> str:
    """The simulated sequence an edited one was copied from (itself when not edited)."""
    return sequence_id.split("~", 1)[0]


def assign_splits(sequence_ids: Iterable[str], seed: int, val_fraction: float, test_fraction: float) -> dict[str, str]:
    """``{sequence id: "train" | "val" | "test"}``.

    1. the parents (unedited ids) are sorted, then permuted by ``numpy.random.default_rng(seed)``;
    2. the first ``round(n * test_fraction)`` go to test, the next ``round(n * val_fraction)`` to
       val, the rest to train; a non-zero fraction gets at least one sequence while train keeps
       one (so three sequences make one of each);
    3. every edited sequence takes its parent's split.

    The result depends only on the set of parent ids, the seed and the fractions (not on order).
    """
    if not (0.0 <= val_fraction < 1.0 and 0.0 <= test_fraction < 1.0 and val_fraction + test_fraction < 1.0):
        raise ValueError(f"split fractions val {val_fraction} and test {test_fraction} must be in [0, 1) and sum "
                         f"below 1")
    ids = list(sequence_ids)
    parents = sorted({parent_sequence(s) for s in ids})
    n = len(parents)
    counts = []
    for frac in (test_fraction, val_fraction):
        k = int(round(n * frac))
        if frac > 0 and k == 0 and n - sum(counts) > 1:
            k = 1  # a requested split is never empty while train keeps a sequence
        counts.append(min(k, max(0, n - 1 - sum(counts))))
    order = [parents[i] for i in np.random.default_rng(seed).permutation(n)]
    n_test, n_val = counts
    of_parent = {p: "test" for p in order[:n_test]}
    of_parent |= {p: "val" for p in order[n_test:n_test + n_val]}
    of_parent |= {p: "train" for p in order[n_test + n_val:]}
    return {s: of_parent[parent_sequence(s)] for s in sorted(ids)}
