"""A stage's code version, derived from what its wiring module actually imports.

The version is a hash of the source of every module of ours the stage's task can run: its wiring
module (``carlaocc.pipeline.tasks.<stage>``) and, transitively, each module it imports by name —
module-level and function-level imports alike. ``from P import name`` counts the submodule
``P.name`` when there is one, else the module that binds ``name`` in ``P``'s ``__init__``
(a package re-exporting a function counts the function's module, not its siblings). Packages a
module sits in count by their ``__init__.py`` alone. So editing the procedural town re-runs the
scenes stage, not every voxelize frame; editing the voxelizer re-runs voxelize, not sensors.

The engine itself (``carlaocc.pipeline.engine``: spec, registry, runner, executors, this module)
decides when a task runs, not what it writes, and is left out.
"""

from __future__ import annotations

import ast
import hashlib
import importlib.util
from functools import lru_cache

NAMESPACE = "carlaocc"
ENGINE = "carlaocc.pipeline.engine"  # the engine package: decides when a task runs, not what it writes


def _engine(module: str) -> bool:
    return module == ENGINE or module.startswith(ENGINE + ".")


@lru_cache(maxsize=None)
def _source(module: str) -> tuple[str, bool] | None:
    """(source file, is a package) of a module with Python source, None when there is none."""
    try:
        spec = importlib.util.find_spec(module)
    except (ImportError, AttributeError, ValueError):  # a parent that is a plain module
        return None
    if spec is None or not spec.origin or not spec.origin.endswith(".py"):
        return None
    return spec.origin, spec.submodule_search_locations is not None


@lru_cache(maxsize=None)
def _tree(path: str) -> ast.Module:
    with open(path, "rb") as fh:
        return ast.parse(fh.read(), filename=path)


_BLOCKS = ("body", "orelse", "finalbody", "handlers", "cases")  # the fields statements nest in


@lru_cache(maxsize=None)
def _import_nodes(path: str) -> tuple[ast.Import | ast.ImportFrom, ...]:
    """Every import statement of a file, at any depth (functions, classes, if/try/with blocks):
    statements nest only in statement lists, so expressions, most of a tree, are never visited."""
    out, todo = [], list(_tree(path).body)
    while todo:
        node = todo.pop()
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            out.append(node)
            continue
        for name in _BLOCKS:
            todo += getattr(node, name, None) or ()
    return tuple(out)


def _absolute(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    """The absolute module name of a (possibly relative) ``from ... import``."""
    if node.level == 0:
        return node.module or ""
    base = module if is_package else module.rpartition(".")[0]
    for _ in range(node.level - 1):
        base = base.rpartition(".")[0]
    return f"{base}.{node.module}" if node.module else base


def _binders(package: str, name: str) -> list[str]:
    """Modules that bind ``name`` in ``package``'s ``__init__`` by an import."""
    src = _source(package)
    if src is None:
        return []
    out = []
    for node in _import_nodes(src[0]):
        if isinstance(node, ast.ImportFrom) and any((a.asname or a.name) == name for a in node.names):
            target = _absolute(package, True, node)
            sub = f"{target}.{name}"
            out.append(sub if _source(sub) else target)
        elif isinstance(node, ast.Import) and any((a.asname or a.name) == name for a in node.names):
            out += [a.name for a in node.names if (a.asname or a.name) == name]
    return out


def _imports(module: str) -> tuple[set[str], set[str]]:
    """Our modules that ``module`` imports by name (followed further), and the packages it
    imports names from (whose ``__init__`` counts as a file; see the module docstring)."""
    src = _source(module)
    if src is None:
        return set(), set()
    path, is_package = src
    out: set[str] = set()
    packages: set[str] = set()
    for node in _import_nodes(path):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            target = _absolute(module, is_package, node)
            if not (_source(target) or ("", False))[1]:  # a module (or a missing one): all of it
                out.add(target)
                continue
            packages.add(target)
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                if _source(sub):
                    out.add(sub)  # a submodule
                elif binders := _binders(target, alias.name):
                    out |= set(binders)  # a re-export: the module that defines it
                else:
                    out.add(target)  # defined in the package's __init__: follow it
    missing = sorted(m for m in out | packages if _ours(m) and not _source(m))
    if missing:  # a stale import: the task would fail too, but say where
        raise ImportError(f"{module} imports {missing[0]}, which does not exist")
    return {m for m in out if _ours(m)}, {m for m in packages if _ours(m)}


def _ours(module: str) -> bool:
    return module == NAMESPACE or module.startswith(NAMESPACE + ".")


def _parents(module: str) -> list[str]:
    parts = module.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts))]


@lru_cache(maxsize=None)
def module_closure(root: str) -> tuple[str, ...]:
    """``root`` and every module of ours it runs, sorted: its imports followed transitively,
    plus the packages they sit in (whose own ``__init__`` code runs on import). ``root`` may be
    any module (a test's task module); only modules of ours are followed from it."""
    seen: set[str] = set()
    files: set[str] = set()  # packages counted by their __init__ file alone
    todo = [root]
    while todo:
        m = todo.pop()
        if m in seen or _engine(m) or _source(m) is None:
            continue
        seen.add(m)
        followed, packages = _imports(m)
        todo += sorted(followed - seen)
        files |= packages
    # the packages every module sits in: their __init__ code runs on import
    files |= {p for m in seen | files if _ours(m) for p in _parents(m) if _source(p)}
    return tuple(sorted(m for m in seen | files if not _engine(m)))


@lru_cache(maxsize=None)
def code_version(root: str) -> str:
    """Hash of the names and sources of every module in :func:`module_closure` of ``root``."""
    h = hashlib.sha256()
    for m in module_closure(root):
        with open(_source(m)[0], "rb") as fh:
            h.update(m.encode() + b"\0" + fh.read() + b"\0")
    return h.hexdigest()[:16]
