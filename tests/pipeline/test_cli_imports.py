"""The command line starts light: defining the commands imports none of the heavy libraries the
work needs (``carlaocc.pipeline.cli``, "Imports"), so ``carlaocc --help`` and a typo's error
stay fast. Checked in a fresh interpreter, by module, never by time."""

from __future__ import annotations

import json
import subprocess
import sys

HEAVY = ("zarr", "numba", "distributed", "dask", "scipy", "trimesh", "open3d", "duckdb", "matplotlib", "pyarrow",
         "torch", "PIL")


def _loaded_after(statement: str) -> set[str]:
    code = f"import sys, json\n{statement}\nprint(json.dumps(sorted({{m.split('.')[0] for m in sys.modules}})))"
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True)
    return set(json.loads(out.stdout.strip().splitlines()[-1]))


def test_defining_the_commands_imports_no_heavy_library():
    loaded = _loaded_after("from carlaocc.pipeline.cli import app")  # every command registered
    assert not loaded & set(HEAVY), sorted(loaded & set(HEAVY))


def test_the_check_sees_a_heavy_import():
    # the checker itself: the export registry pulls zarr and numba in
    assert {"zarr", "numba"} <= _loaded_after("import carlaocc.pipeline.commands.export")


def test_a_command_imports_only_its_own_module():
    # what `carlaocc --debug voxelize ...` registers before running: files' commands, no other module's
    code = ("import sys, json\nfrom carlaocc.pipeline import cli\ncli.load_commands(['--debug', 'voxelize', 'x.ply'])\n"
            "print(json.dumps(sorted(m for m in sys.modules if m.startswith('carlaocc.pipeline.cli.'))))")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True)
    modules = {m.rsplit(".", 1)[1] for m in json.loads(out.stdout.strip().splitlines()[-1])}
    assert "files" in modules
    assert not modules & {"build", "audit", "query", "scene_tools", "show", "view", "evaluate", "evaluate_rays"}, modules
    # and the command runs from there (its help through the real entry point)
    run = subprocess.run([sys.executable, "-m", "carlaocc", "voxelize", "--help"], capture_output=True, text=True)
    assert run.returncode == 0 and "--voxel-size" in run.stdout, run.stderr


def test_the_command_table_names_what_each_module_registers():
    import typer.main

    from carlaocc.pipeline.cli import COMMAND_MODULES, app

    registered: dict[str, set[str]] = {}  # top-level name -> the modules defining it or its commands
    for info in app.registered_commands:
        name = info.name or typer.main.get_command_name(info.callback.__name__)
        registered.setdefault(name, set()).add(info.callback.__module__.rsplit(".", 1)[1])
    for group in app.registered_groups:
        mods = {c.callback.__module__.rsplit(".", 1)[1] for c in group.typer_instance.registered_commands}
        registered.setdefault(group.name, set()).update(mods)
    table: dict[str, set[str]] = {}
    for module, names in COMMAND_MODULES.items():
        for name in names:
            table.setdefault(name, set()).add(module)
    # eval's group is added by the package once evaluate is loaded; its commands live in both modules
    assert registered == table
