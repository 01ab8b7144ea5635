"""docs/architecture.md "Layers": layers import downward only (pipeline -> stages, catalog ->
schemas); stages never import catalog, pipeline, distributed or the CLI library; schemas imports
nothing of ours.

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
FORBIDDEN = {
    "schemas": OURS - {"schemas"} | {"pyarrow", "zarr", "duckdb", "dask", "distributed", "typer", "trimesh"},
    "stages": {"catalog", "pipeline", "distributed", "dask", "typer", "zarr", "duckdb", "fsspec", "pyarrow"},
    "catalog": {"stages", "pipeline", "distributed", "dask", "typer"},
    "pipeline": set(),
}
# every folder of Python code in the repository, whatever imports it
CODE_DIRS = (*LAYERS, "carlaocc", "tests", "benchmarks", "tools")


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
    """Top-level names imported by ``path``; ``carlaocc.<layer>...`` counts as ``<layer>``."""
    out = set()
    for name in _modules(path):
        parts = name.split(".")
        out.add(parts[1] if parts[0] == "carlaocc" and len(parts) > 1 else parts[0])
    return out


FILES = [(pkg, p) for pkg in LAYERS for p in sorted((ROOT / pkg).rglob("*.py"))]
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
    assert {pkg for pkg, _ in FILES} == OURS


def test_the_rule_catches_what_it_forbids(tmp_path):
    # the checker itself: a stage importing the catalog through the namespace, and a bare import
    f = tmp_path / "m.py"
    f.write_text("from carlaocc.catalog.store import Store\nimport stages.geometry as g\n")
    assert _imports(f) == {"catalog", "stages"}
    assert {m for m in _modules(f) if m.split(".")[0] in OURS} == {"stages.geometry"}


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
