"""Digest of a dataset root's artefacts, to show two builds are byte-identical.

Every file under the root is hashed (SHA-256) except what records a run rather than its data:
the lineage log (``catalog/runs/``, run ids, times, code versions), the report page
(``metrics/report.html``, which embeds that lineage and the build's timings), PNG plots
(matplotlib stamps its version), the remembered plan (``plan.yaml``: what was asked for, which a
root built through the Python API has none of) and a writer's lock file. Usage::

    python tools/dataset_digest.py ROOT              # one line per file, then the total
    python tools/dataset_digest.py ROOT_A ROOT_B     # the files that differ; exit 1 if any
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

SKIPPED_DIRS = ("catalog/runs/",)
# the report page; the lock file (empty, held by a writer); the remembered plan (what was asked, not built)
SKIPPED_FILES = ("metrics/report.html", ".carlaocc.lock", "plan.yaml")
SKIPPED_SUFFIXES = (".png",)


def digests(root: Path) -> dict[str, str]:
    """Relative path -> SHA-256 of every compared file under ``root``."""
    if not root.is_dir():
        raise SystemExit(f"error: dataset root {root} is not a directory")
    out = {}
    for path in sorted(p for p in root.rglob("*") if p.is_file()):
        rel = path.relative_to(root).as_posix()
        if rel.startswith(SKIPPED_DIRS) or rel in SKIPPED_FILES or rel.endswith(SKIPPED_SUFFIXES):
            continue
        out[rel] = hashlib.sha256(path.read_bytes()).hexdigest()
    return out


def total(d: dict[str, str]) -> str:
    return hashlib.sha256("".join(f"{k} {v}\n" for k, v in sorted(d.items())).encode()).hexdigest()


def main(argv: list[str]) -> int:
    if len(argv) == 1:
        d = digests(Path(argv[0]))
        for k, v in d.items():
            print(f"{v}  {k}")
        print(f"{len(d)} files, total {total(d)}")
        return 0
    if len(argv) == 2:
        a, b = digests(Path(argv[0])), digests(Path(argv[1]))
        differ = sorted(k for k in a.keys() & b.keys() if a[k] != b[k])
        only_a, only_b = sorted(a.keys() - b.keys()), sorted(b.keys() - a.keys())
        for k in differ:
            print(f"differs: {k}")
        for k in only_a:
            print(f"only in {argv[0]}: {k}")
        for k in only_b:
            print(f"only in {argv[1]}: {k}")
        same = not (differ or only_a or only_b)
        print(f"{len(a)} / {len(b)} files; total {total(a)[:16]} / {total(b)[:16]}: "
              f"{'identical' if same else 'DIFFERENT'}")
        return 0 if same else 1
    print(__doc__)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
