"""One name for the voxel size (the voxel edge length, metres): ``voxel_size`` (``voxel_sizes``,
``voxel_size_key`` for its store key) in code, ``--voxel-size`` on the command line.

Its earlier names -- ``resolution``, ``res``, ``vs`` -- must not creep back: no function
parameter, assigned name, attribute, keyword argument, imported alias or exception name in our
code is called ``resolution``, ``resolutions``, ``res`` or ``vs``, except the few below that are
not voxel sizes at all. The Parquet files keep the column name ``resolution``
(``Record.STORED_NAMES``, tested in tests/catalog/test_stored_names.py); that is a stored string,
not a name in code. ``--res`` (and the benchmarks' ``--long-res``) exist only as the short alias
declared beside ``--voxel-size`` (``--long-voxel-size``).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCANNED = ("schemas", "stages", "catalog", "pipeline", "carlaocc", "benchmarks", "tools")
BANNED = {"resolution", "resolutions", "res", "vs"}

# (file, name) pairs that are not voxel sizes, each with why
ALLOWED = {
    ("pipeline/engine/runner.py", "res"): "a task's TaskResult",
    ("pipeline/cli/evaluate.py", "res"): "an evaluation accumulator's result",
    ("stages/voxelize/pooling.py", "res"): "a slab view of the pooled output volume",
    ("catalog/sources/_collada.py", "vs"): "a COLLADA <visual_scene> element",
    ("benchmarks/bench_scenes.py", "res"): "a simulated sequence (simulate_sequence's result)",
    ("tools/make_hills_figure.py", "res"): "a simulated sequence (simulate_sequence's result)",
    ("tools/crosscheck_nuscenes.py", "res"): "the detection accumulator's result",
}

# short option aliases and the long option they must be declared with
ALIASES = {"--res": "--voxel-size", "--long-res": "--long-voxel-size"}


def _files() -> list[Path]:
    return sorted(p for d in SCANNED for p in (ROOT / d).rglob("*.py"))


def _names(tree: ast.AST):
    """(line, kind, name) of every name the code binds or reads as an attribute."""
    for node in ast.walk(tree):
        if isinstance(node, ast.arg):
            yield node.lineno, "parameter", node.arg
        elif isinstance(node, ast.Name) and isinstance(node.ctx, (ast.Store, ast.Del)):
            yield node.lineno, "assigned name", node.id
        elif isinstance(node, ast.Attribute):
            yield node.lineno, "attribute", node.attr
        elif isinstance(node, ast.keyword) and node.arg is not None:
            yield node.lineno, "keyword argument", node.arg
        elif isinstance(node, ast.alias) and node.asname:
            yield node.lineno, "import alias", node.asname
        elif isinstance(node, ast.ExceptHandler) and node.name:
            yield node.lineno, "exception name", node.name
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            yield node.lineno, "definition", node.name


def test_no_other_name_for_the_voxel_size():
    found, used = [], set()
    for path in _files():
        rel = path.relative_to(ROOT).as_posix()
        for line, kind, name in _names(ast.parse(path.read_text(), filename=rel)):
            if name not in BANNED:
                continue
            if (rel, name) in ALLOWED:
                used.add((rel, name))
                continue
            found.append(f"{rel}:{line}: {kind} {name!r}")
    assert not found, ("the voxel size is named voxel_size (voxel_sizes, voxel_size_key); rename these, "
                       "or allow-list them in tests/test_names.py if they are not voxel sizes:\n"
                       + "\n".join(found))
    # every allow-list entry still names something (a stale entry would let a voxel size back in)
    assert used == set(ALLOWED), f"stale allow-list entries: {sorted(set(ALLOWED) - used)}"


def test_short_voxel_size_options_are_only_aliases():
    found = []
    for path in _files():
        rel = path.relative_to(ROOT).as_posix()
        for node in ast.walk(ast.parse(path.read_text(), filename=rel)):
            if not isinstance(node, ast.Call):
                continue
            strings = {a.value for a in node.args if isinstance(a, ast.Constant) and isinstance(a.value, str)}
            for short, long in ALIASES.items():
                if short in strings and long not in strings:
                    found.append(f"{rel}:{node.lineno}: {short} without {long}")
    assert not found, "\n".join(found)


def test_the_cli_says_voxel_size():
    from typer.main import get_command

    from carlaocc.pipeline.cli import app

    def walk(cmd, path=()):
        yield path, cmd
        for name, sub in getattr(cmd, "commands", {}).items():
            yield from walk(sub, (*path, name))

    for path, cmd in walk(get_command(app)):
        if getattr(cmd, "hidden", False):  # the retired compare-resolutions
            continue
        for p in cmd.params:
            opts = set(p.opts) | set(p.secondary_opts)
            if "--res" in opts:
                assert "--voxel-size" in opts, (path, p.opts)
            assert "resolution" not in (getattr(p, "help", "") or "").lower().replace("image resolution", ""), (path, p.opts)
        assert "compare-resolutions" not in path
