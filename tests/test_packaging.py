"""The installed distribution is one namespace: ``carlaocc.*`` and nothing else in site-packages.

The wheel is built offline from this checkout (no build isolation: the test environment's
setuptools) and its top-level names and modules are checked against the source tree."""

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LAYERS = ("schemas", "stages", "catalog", "pipeline")


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> zipfile.ZipFile:
    # built from a copy of the sources: setuptools builds in-tree (build/), where modules deleted
    # from the source would linger and be packed
    src = tmp_path_factory.mktemp("src")
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, src / name)
    for name in (*LAYERS, "carlaocc"):
        shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__"))
    out = tmp_path_factory.mktemp("wheel")
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index",
                        "-q", "-w", str(out), str(src)], capture_output=True, text=True, env=_env())
    assert r.returncode == 0, r.stderr[-3000:]
    (whl,) = out.glob("carlaocc-*.whl")
    return zipfile.ZipFile(whl)


def _env() -> dict:
    import os

    return {k: v for k, v in os.environ.items() if not k.startswith("PIP_")}


def test_wheel_has_one_top_level_package(wheel):
    tops = {n.split("/")[0] for n in wheel.namelist()}
    dist_info = {t for t in tops if t.endswith(".dist-info")}
    assert tops - dist_info == {"carlaocc"}, sorted(tops)
    for name in LAYERS:
        assert not any(n.startswith(f"{name}/") for n in wheel.namelist())


def test_wheel_holds_every_module_and_the_towns(wheel):
    names = set(wheel.namelist())
    expected = {f"carlaocc/{p.relative_to(ROOT).as_posix()}" for layer in LAYERS
                for p in (ROOT / layer).rglob("*.py")}
    expected |= {f"carlaocc/{p.name}" for p in (ROOT / "carlaocc").glob("*.py")}
    missing = sorted(expected - names)
    assert not missing, f"modules left out of the wheel (add their package to pyproject.toml): {missing[:5]}"
    xodr = {p.name for p in (ROOT / "catalog" / "towns").glob("*.xodr")}
    assert xodr and {f"carlaocc/catalog/towns/{x}" for x in xodr} <= names
    presets = {p.name for p in (ROOT / "catalog" / "presets").glob("*.yaml")}
    assert presets and {f"carlaocc/catalog/presets/{x}" for x in presets} <= names


def test_entry_point_names_the_namespace(wheel):
    (ep,) = [n for n in wheel.namelist() if n.endswith("entry_points.txt")]
    text = wheel.read(ep).decode()
    assert "carlaocc = carlaocc.pipeline.cli:main" in text


def test_public_api_is_lazy_and_complete():
    # importing a stage must not pull the pipeline in through carlaocc/__init__.py
    code = ("import sys, carlaocc.stages.geometry; "
            "assert not any(m.startswith(('carlaocc.pipeline', 'distributed', 'typer')) for m in sys.modules), "
            "sorted(m for m in sys.modules if m.startswith('carlaocc')); "
            "import carlaocc; [getattr(carlaocc, n) for n in carlaocc.__all__]; print('ok')")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT.parent)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr[-2000:]
