"""Shared by the benchmarks that time pipeline tasks in a fresh process on the embedded default."""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator


@contextlib.contextmanager
def default_scenes_root(python: str | None = None) -> Iterator[str]:
    """A temporary store holding the embedded default's ingest and scenes stages, built
    synchronously by ``python`` (an installation of carlaocc; default: this one; the time is
    printed), removed afterwards. Another code base builds its own: its tables may not read
    another version's."""
    with tempfile.TemporaryDirectory() as tmp:
        root = f"{tmp}/data"
        t0 = time.perf_counter()
        subprocess.run([python or sys.executable, "-m", "carlaocc", "run", "--stages", "ingest,scenes", "--root", root,
                        "--scheduler", "synchronous"], check=True, capture_output=True, cwd="/")
        print(f"ingest + scenes of the embedded default{'' if python is None else ' by ' + python}: "
              f"{time.perf_counter() - t0:.1f} s")
        yield root


def run_case(code: str, *args) -> dict:
    """Run ``python -c code args...`` in a fresh process; its last stdout line is a JSON object."""
    out = subprocess.run([sys.executable, "-c", code, *map(str, args)], check=True, capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def save_json(argv: list[str], index: int, data: dict) -> None:
    """Write ``data`` to the path ``argv[index]`` when the command line gave one."""
    if len(argv) > index:
        with open(argv[index], "w") as fh:
            json.dump(data, fh, indent=2)
