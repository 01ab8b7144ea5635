"""The ``carlaocc`` command line, one module per command group.

* ``app``         — the Typer application and its groups
* ``common``      — shared options, one-line errors, config and voxel-size parsing, progress
* ``build``       — ``run``, ``ingest``, ``status``, ``stages``, ``config``
* ``query``       — ``catalog query`` (read-only SQL)
* ``show``        — ``admesh show|sheet``, ``show occupancy|sensors`` (PNG, headless)
* ``scene_tools`` — ``scenes town-mesh|frame-mesh|swap``
* ``files``       — ``voxelize`` (mesh files), ``export``, ``compare-resolutions``
* ``evaluate``    — ``eval ssc|panoptic|depth|det``
* ``audit`` (in ``carlaocc.pipeline.audit``) — quality scores of any dataset on disk

Exit codes: 0 ok, 1 a task failed (named with its partition), 2 a usage or input error (one line
naming the culprit; nothing in the dataset root is touched).
"""

from __future__ import annotations

import os

from carlaocc.pipeline.audit import audit_cli
from carlaocc.pipeline.cli import build, files, query, scene_tools, show  # noqa: F401  (register commands)
from carlaocc.pipeline.cli.app import app
from carlaocc.pipeline.cli.evaluate import eval_app

app.add_typer(eval_app, name="eval")
app.command("audit")(audit_cli)

__all__ = ["app", "main"]


def main() -> None:
    """Console-script entry point."""
    os.environ.setdefault("PYTHONWARNINGS", "ignore::DeprecationWarning")
    app()
