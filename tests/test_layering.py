"""docs/architecture.md "Layers": layers import downward only (carlaocc -> pipeline -> stages,
catalog -> schemas); stages never import catalog, pipeline, distributed or the CLI library;
schemas imports nothing of ours; the public API package ``carlaocc/`` (``carlaocc.data``,
``carlaocc.run``...) is the top layer, which nothing below imports. Inside pipeline/, the engine
imports no command, and the stages' wiring neither. Names starting with ``_`` stay in their module.

Everything of ours is imported through the one ``carlaocc`` namespace: a bare ``import stages``
(or schemas, catalog, pipeline) would load a second copy of each module beside ``carlaocc.stages``,
so it is refused everywhere, tests and benchmarks included.
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LAYERS = ("schemas", "stages", "catalog", "pipeline")
OURS = set(LAYERS)
TOP = "carlaocc"  # the public API package: carlaocc/__init__.py, carlaocc/data.py...
FORBIDDEN = {
    "schemas": OURS - {"schemas"} | {TOP, "pyarrow", "zarr", "duckdb", "dask", "distributed", "typer", "trimesh"},
    "stages": {TOP, "catalog", "pipeline", "distributed", "dask", "typer", "zarr", "duckdb", "fsspec", "pyarrow"},
    "catalog": {TOP, "stages", "pipeline", "distributed", "dask", "typer"},
    "pipeline": {TOP},
    TOP: set(),
}
# inside pipeline/: the commands (the CLI and what it calls) sit on top of the engine and the wiring
COMMANDS = ("carlaocc.pipeline.cli", "carlaocc.pipeline.commands")
BELOW_COMMANDS = ("pipeline/engine", "pipeline/tasks")
# every folder of Python code in the repository, whatever imports it
CODE_DIRS = (*LAYERS, TOP, "tests", "benchmarks", "tools")


def _modules(path: Path) -> list[str]:
    """Absolute module names imported by ``path`` (relative imports are not ours to check)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.append(node.module)
    return out


def _imports(path: Path) -> set[str]:
    """Top-level names imported by ``path``; ``carlaocc.<layer>...`` counts as ``<layer>``, and
    ``carlaocc`` or ``carlaocc.<anything else>`` as the top layer ``carlaocc``."""
    out = set()
    for name in _modules(path):
        parts = name.split(".")
        if parts[0] == TOP:
            out.add(parts[1] if len(parts) > 1 and parts[1] in OURS else TOP)
        else:
            out.add(parts[0])
    return out


FILES = [(pkg, p) for pkg in (*LAYERS, TOP) for p in sorted((ROOT / pkg).rglob("*.py"))]
ALL_FILES = [p for d in CODE_DIRS for p in sorted((ROOT / d).rglob("*.py"))]


@pytest.mark.parametrize("pkg, path", FILES, ids=[str(p.relative_to(ROOT)) for _, p in FILES])
def test_layering(pkg, path):
    bad = _imports(path) & FORBIDDEN[pkg]
    assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}"


@pytest.mark.parametrize("path", ALL_FILES, ids=[str(p.relative_to(ROOT)) for p in ALL_FILES])
def test_one_namespace(path):
    bare = sorted({m for m in _modules(path) if m.split(".")[0] in OURS})
    assert not bare, f"{path.relative_to(ROOT)} imports {bare} by the bare name: use carlaocc.{bare[0]}"


def test_every_layer_has_modules():
    assert {pkg for pkg, _ in FILES} == OURS | {TOP}


def test_the_rule_catches_what_it_forbids(tmp_path):
    # the checker itself: a stage importing the catalog through the namespace, and a bare import
    f = tmp_path / "m.py"
    f.write_text("from carlaocc.catalog.store import Store\nimport stages.geometry as g\n")
    assert _imports(f) == {"catalog", "stages"}
    assert {m for m in _modules(f) if m.split(".")[0] in OURS} == {"stages.geometry"}
    # the top layer, however it is reached
    for line in ("from carlaocc.data import CarlaOccDataset", "import carlaocc", "from carlaocc import run"):
        f.write_text(line + "\n")
        assert _imports(f) == {TOP}, line


ENGINE_AND_WIRING = [p for d in BELOW_COMMANDS for p in sorted((ROOT / d).rglob("*.py"))]


@pytest.mark.parametrize("path", ENGINE_AND_WIRING, ids=[str(p.relative_to(ROOT)) for p in ENGINE_AND_WIRING])
def test_engine_and_wiring_import_no_command(path):
    bad = sorted(m for m in _modules(path) if m.startswith(COMMANDS))
    assert not bad, f"{path.relative_to(ROOT)} imports the command module(s) {bad}: commands sit on top"


def _private_imports(path: Path, module: str | None = None, names_only: bool = False) -> list[str]:
    """``module:name`` of every ``_name`` of ours that ``path`` takes from another module: by
    ``from M import _name``, by ``M._name`` on a module it imported, or by importing a private
    module (``_common``) from outside its package. Dunders are public. ``names_only``: only the
    first kind (a test may still set a module's private constant, or test a private module)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    # the module's own dotted name (e.g. carlaocc.stages.geometry): its package may use its private modules
    here = module or ".".join(("carlaocc", *path.relative_to(ROOT).with_suffix("").parts))
    here_pkg = here.rpartition(".")[0]

    def private(name: str) -> bool:
        return name.startswith("_") and not name.startswith("__")

    def ours(module: str) -> bool:
        return module == TOP or module.startswith(TOP + ".")

    out, modules = [], {}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0 and ours(node.module):
            for a in node.names:
                if private(a.name):
                    out.append(f"{node.module}:{a.name}")
                else:
                    modules[a.asname or a.name] = f"{node.module}.{a.name}"
            if not names_only and any(private(p) for p in node.module.split(".")) \
                    and node.module.rpartition(".")[0] != here_pkg:
                out.append(node.module)
        elif isinstance(node, ast.Import):
            for a in node.names:
                if ours(a.name):
                    modules[a.asname or a.name.split(".")[0]] = a.name if a.asname else a.name.split(".")[0]
    for node in ast.walk(tree) if not names_only else ():
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in modules \
                and private(node.attr):
            out.append(f"{modules[node.value.id]}:{node.attr}")
    return out


CODE_FILES = [p for d in (*LAYERS, TOP, "benchmarks", "tools", "tests") for p in sorted((ROOT / d).rglob("*.py"))]


@pytest.mark.parametrize("path", CODE_FILES, ids=[str(p.relative_to(ROOT)) for p in CODE_FILES])
def test_no_private_names_across_modules(path):
    # a helper two modules use (a test is one of them) is public and lives where both can see it
    if path.name == "test_layering.py":
        return  # the planted examples of the checker's own test
    bad = _private_imports(path, names_only=path.parts[len(ROOT.parts)] == "tests")
    assert not bad, f"{path.relative_to(ROOT)} takes private {bad[:5]}: make it public where both modules see it"


def test_the_private_rule_catches_what_it_forbids(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("from carlaocc.stages.voxelize.visibility import _slab, axis\n"
                 "from carlaocc.stages import geometry as g\n"
                 "g._hidden(1)\nfrom carlaocc.catalog.sources._common import drop\n")
    found = _private_imports(f, "carlaocc.stages.evaluation.m")
    assert "carlaocc.stages.voxelize.visibility:_slab" in found
    assert "carlaocc.stages.geometry:_hidden" in found
    assert "carlaocc.catalog.sources._common" in found
    assert not [x for x in found if x.endswith(":axis")]  # public names pass
    # inside its own package, a private module is the package's business
    assert "carlaocc.catalog.sources._common" not in _private_imports(f, "carlaocc.catalog.sources.folder")
    # in tests: only the imported names count
    assert _private_imports(f, "tests.m", names_only=True) == ["carlaocc.stages.voxelize.visibility:_slab"]


def test_stages_never_open_paths():
    # compute knows no paths: no open(), no pathlib in stages/
    for path in sorted((ROOT / "stages").rglob("*.py")):
        tree = ast.parse(path.read_text())
        calls = {n.func.id for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)}
        assert "open" not in calls, f"{path} calls open()"
        assert "pathlib" not in _imports(path) and "os" not in _imports(path), f"{path} touches the filesystem"


# the in-memory contracts have one home in schemas/ (catalog readers return them, stages accept
# them typed); these names may be defined nowhere else, and the duplicates and bridges they
# replaced may not come back anywhere
CONTRACT_MODULES = ("meshes", "motion", "opendrive")
RETIRED = {"RawAsset", "RawPart", "MeshPartLike", "BvhClip", "_raw_asset", "SHARED_CODE", "code_modules"}


def _contract_names() -> set[str]:
    names = set()
    for mod in CONTRACT_MODULES:
        tree = ast.parse((ROOT / "schemas" / f"{mod}.py").read_text())
        for node in tree.body:
            if isinstance(node, ast.ClassDef):
                names.add(node.name)
            elif isinstance(node, ast.Assign):
                names |= {t.id for t in node.targets if isinstance(t, ast.Name) and not t.id.isupper() and not t.id.startswith("__")}
    return names


def _definitions(path: Path) -> set[str]:
    """Classes, functions, module-level names and keyword arguments defined in ``path``."""
    tree = ast.parse(path.read_text())
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.ClassDef, ast.FunctionDef)):
            out.add(node.name)
        elif isinstance(node, ast.keyword) and node.arg:
            out.add(node.arg)
    for node in tree.body:
        if isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            out |= {t.id for t in targets if isinstance(t, ast.Name)}
    return out


def test_contracts_are_defined_once_in_schemas():
    contracts = _contract_names()
    assert {"MeshPart", "SceneMesh", "AssetGeometry", "SourceAsset", "SourcePart", "Axis", "Units", "MotionClip",
            "Road", "OpenDriveNetwork"} <= contracts
    for layer in ("stages", "catalog", "pipeline"):
        for path in sorted((ROOT / layer).rglob("*.py")):
            again = _definitions(path) & contracts
            assert not again, f"{path.relative_to(ROOT)} defines {sorted(again)}: import them from carlaocc.schemas"


@pytest.mark.parametrize("path", ALL_FILES, ids=[str(p.relative_to(ROOT)) for p in ALL_FILES])
def test_retired_duplicates_stay_gone(path):
    if path.name in ("test_layering.py", "test_meshes.py"):
        return  # the lists of what may not come back
    back = _definitions(path) & RETIRED
    assert not back, f"{path.relative_to(ROOT)} brings back {sorted(back)}"
