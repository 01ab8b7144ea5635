"""Train / val / test splits by sequence (stages/splits) and their files (catalog/splits.py)."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from carlaocc.catalog.splits import SplitStore
from carlaocc.catalog.store import StoreError
from carlaocc.stages.splits import assign_splits

IDS = st.lists(st.from_regex(r"town0[0-7]_(none|low|medium|high)_seq00[0-9]", fullmatch=True), min_size=1,
               max_size=40, unique=True)


@settings(max_examples=60, deadline=None)
@given(ids=IDS, seed=st.integers(0, 10**6), val=st.sampled_from([0.0, 0.1, 0.15, 0.3]),
       test=st.sampled_from([0.0, 0.1, 0.15, 0.3]))
def test_every_sequence_in_exactly_one_split_deterministically(ids, seed, val, test):
    a = assign_splits(ids, seed, val, test)
    assert set(a) == set(ids) and set(a.values()) <= {"train", "val", "test"}
    # the same whatever the order the ids come in
    assert assign_splits(list(reversed(ids)), seed, val, test) == a
    n = len(ids)
    counts = {s: sum(v == s for v in a.values()) for s in ("train", "val", "test")}
    assert counts["train"] >= 1
    for split, frac in (("val", val), ("test", test)):
        if frac == 0:
            assert counts[split] == 0
        elif n >= 3:
            assert counts[split] >= 1  # a requested split is never empty when there is room
        assert counts[split] <= max(1, round(n * frac))


def test_seed_changes_the_deal_and_edits_follow_their_parent():
    ids = [f"town00_high_seq{i:03d}" for i in range(20)]
    a, b = assign_splits(ids, 0, 0.2, 0.2), assign_splits(ids, 1, 0.2, 0.2)
    assert a != b and sorted(a.values()) == sorted(b.values())
    edited = ids + ["town00_high_seq003~swap-car-s3", "town00_high_seq007~swap-building-s1"]
    c = assign_splits(edited, 0, 0.2, 0.2)
    assert c["town00_high_seq003~swap-car-s3"] == c["town00_high_seq003"]
    assert c["town00_high_seq007~swap-building-s1"] == c["town00_high_seq007"]
    assert {k: c[k] for k in ids} == a  # an edit does not move any other sequence
    with pytest.raises(ValueError, match="below 1"):
        assign_splits(ids, 0, 0.5, 0.5)


def test_split_files_round_trip(store):
    splits = SplitStore(store)
    assert not splits.exists()
    with pytest.raises(StoreError, match="splits stage"):
        splits.load()
    a = {"s1": "train", "s2": "val", "s3": "test", "s4": "train"}
    written = splits.save(a)
    assert set(written) == {"splits/train.txt", "splits/val.txt", "splits/test.txt"}
    assert splits.load() == a
    assert store.read_bytes("splits/train.txt") == b"s1\ns4\n"
    with pytest.raises(ValueError, match="unknown split"):
        splits.save({"s1": "holdout"})
    store.write_bytes("splits/val.txt", b"s1\n")
    with pytest.raises(StoreError, match="s1 is also in"):
        splits.load()
