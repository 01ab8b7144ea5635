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
    loaded = _loaded_after("import carlaocc.pipeline.cli")
    assert not loaded & set(HEAVY), sorted(loaded & set(HEAVY))


def test_the_check_sees_a_heavy_import():
    # the checker itself: the export registry pulls zarr and numba in
    assert {"zarr", "numba"} <= _loaded_after("import carlaocc.pipeline.commands.export")
