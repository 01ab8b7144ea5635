"""docs/architecture.md's "Where things are" map (README's until the manual became a site)
matches the tree: every folder it names exists, and every package folder (and every top-level
code folder) is named."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CODE_DIRS = ("carlaocc", "schemas", "stages", "catalog", "pipeline", "tests", "benchmarks", "tools")


def _map_folders() -> set[str]:
    text = (ROOT / "docs" / "architecture.md").read_text()
    start = text.index("## Where things are")
    end = text.find("\n## ", start + 1)
    end = len(text) if end < 0 else end
    rows = [ln for ln in text[start:end].splitlines() if ln.startswith("| `")]
    return {re.match(r"\| `([^`]+)/`", ln).group(1) for ln in rows}


def test_every_folder_named_exists():
    for folder in _map_folders():
        assert (ROOT / folder).is_dir(), f"docs/architecture.md names {folder}/, which is not in the tree"


def test_every_package_and_code_folder_is_named():
    named = _map_folders()
    expected = set(CODE_DIRS)
    for layer in ("schemas", "stages", "catalog", "pipeline"):
        expected |= {p.parent.relative_to(ROOT).as_posix() for p in (ROOT / layer).rglob("__init__.py")}
    missing = sorted(expected - named)
    assert not missing, f"docs/architecture.md's map does not name {missing}"
