"""DESIGN.md: layers import downward only (pipeline -> stages, catalog -> schemas); stages never
import catalog, pipeline, distributed or the CLI library; schemas imports nothing of ours."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
OURS = {"schemas", "stages", "catalog", "pipeline"}
FORBIDDEN = {
    "schemas": OURS - {"schemas"} | {"numpy", "pyarrow", "zarr", "duckdb", "dask", "distributed", "typer", "trimesh"},
    "stages": {"catalog", "pipeline", "distributed", "dask", "typer", "zarr", "duckdb", "fsspec", "pyarrow"},
    "catalog": {"stages", "pipeline", "distributed", "dask", "typer"},
    "pipeline": set(),
}


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module.split(".")[0])
    return out


FILES = [(pkg, p) for pkg in OURS for p in sorted((ROOT / pkg).rglob("*.py"))]


@pytest.mark.parametrize("pkg, path", FILES, ids=[str(p.relative_to(ROOT)) for _, p in FILES])
def test_layering(pkg, path):
    bad = _imports(path) & FORBIDDEN[pkg]
    assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}"


def test_every_layer_has_modules():
    assert {pkg for pkg, _ in FILES} == OURS


def test_stages_never_open_paths():
    # compute knows no paths: no open(), no pathlib in stages/
    for path in sorted((ROOT / "stages").rglob("*.py")):
        tree = ast.parse(path.read_text())
        calls = {n.func.id for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)}
        assert "open" not in calls, f"{path} calls open()"
        assert "pathlib" not in _imports(path) and "os" not in _imports(path), f"{path} touches the filesystem"
