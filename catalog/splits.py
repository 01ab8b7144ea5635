"""``<root>/splits/{train,val,test}.txt``: the dataset's sequence splits, one sequence id per
line, sorted. The one place that reads and writes them (load / save / exists)."""

from __future__ import annotations

from carlaocc.catalog.store import Store, StoreError

SPLITS_DIR = "splits"
SPLIT_NAMES: tuple[str, ...] = ("train", "val", "test")


class SplitStore:
    """The split files of one dataset root."""

    def __init__(self, store: Store) -> None:
        self.store = store

    @staticmethod
    def path(split: str) -> str:
        return f"{SPLITS_DIR}/{split}.txt"

    def exists(self) -> bool:
        return all(self.store.exists(self.path(s)) for s in SPLIT_NAMES)

    def save(self, assignment: dict[str, str]) -> dict[str, str]:
        """Write the three files from ``{sequence id: split}``; returns ``{path: fingerprint}``."""
        bad = {v for v in assignment.values() if v not in SPLIT_NAMES}
        if bad:
            raise ValueError(f"unknown split(s) {sorted(bad)}; splits are {', '.join(SPLIT_NAMES)}")
        out = {}
        for split in SPLIT_NAMES:
            ids = sorted(s for s, v in assignment.items() if v == split)
            out[self.path(split)] = self.store.write_bytes(self.path(split), "".join(f"{s}\n" for s in ids).encode())
        return out

    def load(self) -> dict[str, str]:
        """``{sequence id: split}``; StoreError naming the root when the splits were never written
        or a sequence is listed twice."""
        if not self.exists():
            raise StoreError(f"{self.store.url} has no {SPLITS_DIR}/ (train/val/test.txt): run `carlaocc run` "
                             f"(the splits stage) first")
        out: dict[str, str] = {}
        for split in SPLIT_NAMES:
            for line in self.store.read_bytes(self.path(split)).decode().splitlines():
                s = line.strip()
                if not s:
                    continue
                if s in out:
                    raise StoreError(f"{self.store.url}/{self.path(split)}: {s} is also in {out[s]}.txt")
                out[s] = split
        return out
