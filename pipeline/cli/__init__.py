"""The ``carlaocc`` command line, one module per command group.

* ``app``         — the Typer application and its groups
* ``common``      — shared options, one-line errors, config and voxel-size parsing, progress
* ``build``       — ``run``, ``ingest``, ``status``, ``info``, ``verify``, ``stages``, ``config``
* ``query``       — ``catalog query`` (read-only SQL)
* ``show``        — ``admesh show|sheet``, ``show occupancy|sensors`` (PNG, headless)
* ``scene_tools`` — ``scenes town-mesh|frame-mesh|swap``
* ``files``       — ``voxelize`` (mesh files), ``export``, ``compare-voxel-sizes`` (and the refusal of its old name)
* ``evaluate``    — ``eval ssc|panoptic|depth|det``
* ``evaluate_rays`` — ``eval rayiou|raypq``
* ``audit``       — ``audit``: quality scores of any dataset on disk

Imports: a command module imports at its top what defining its commands needs (Typer, the app,
the shared options, light schemas); the work a command does is imported inside the command when
it runs. Importing all of it (the engine with Dask, Zarr, numba kernels, scipy, DuckDB,
matplotlib) at start-up took ``carlaocc --help`` from 0.5 s to 2-4 s on this machine (measured
with ``python -X importtime``); ``tests/pipeline/test_cli_imports.py`` keeps them out. The
command line itself (``main``) registers only the module of the command it runs
(``COMMAND_MODULES``): ``carlaocc voxelize`` imports 0.37 s of this package instead of 0.54 (the
other modules' option definitions and what they import); ``carlaocc --help``, a mistyped command
and ``from carlaocc.pipeline.cli import app`` register every command. Below the CLI (the engine,
the wiring, the commands' work), imports are at module top.

Exit codes: 0 ok, 1 a task failed (named with its partition) or work failed, 2 a usage or input
error (one line naming the culprit; nothing in the dataset root is touched). Every error is one
line starting with ``error:``; ``carlaocc --debug`` (or ``CARLAOCC_DEBUG=1``) prints its traceback.
"""

from __future__ import annotations

import importlib
import os
import signal
import sys
import traceback

from carlaocc.pipeline.cli import app as app_module  # the Typer application (typer, the error path)
from carlaocc.pipeline.cli.common import DEBUG_HINT, debug_enabled, one_line
from carlaocc.pipeline.cli.exit import exit_code, leave

# The command modules, in the order ``carlaocc --help`` lists their commands, and the top-level
# command names (commands and groups) each one registers. ``main`` imports only the modules of
# the command it runs (``carlaocc voxelize`` needs none of the engine's option parsing:
# ``python -X importtime``); ``--help``, a mistyped command and ``from carlaocc.pipeline.cli
# import app`` load them all. ``tests/pipeline/test_cli_imports.py`` checks this table against
# what the modules register.
COMMAND_MODULES: dict[str, tuple[str, ...]] = {
    "build": ("run", "ingest", "status", "info", "verify", "stages", "config"),
    "files": ("voxelize", "export", "compare-voxel-sizes", "compare-resolutions"),
    "audit": ("audit",),
    "query": ("catalog",),
    "scene_tools": ("scenes",),
    "show": ("admesh", "show"),
    "view": ("view",),
    "evaluate_rays": ("eval",),
    "evaluate": ("eval",),  # registers the eval group itself, after evaluate_rays added its commands
}

# `from carlaocc.pipeline.cli import app` is the Typer application with every command (see
# __getattr__): the submodule's attribute, which the import above set, is removed
del app  # noqa: F821 -- the package attribute the import of the submodule .app set


def load_commands(args: list[str] | None = None) -> None:
    """Register the commands: those of the module that defines ``args``' command (its first
    argument that is not an option of ``carlaocc`` itself), or every one when ``args`` is None
    or names no known command (``--help``, a typo: the error lists the closest)."""
    name = next((a for a in args if not a.startswith("-")), None) if args is not None else None
    wanted = [m for m, names in COMMAND_MODULES.items() if name in names] or list(COMMAND_MODULES)
    for module in wanted:
        if module in _LOADED:
            continue
        _LOADED.add(module)
        importlib.import_module(f"carlaocc.pipeline.cli.{module}")
        if module == "evaluate":
            from carlaocc.pipeline.cli.evaluate import eval_app

            app_module.app.add_typer(eval_app, name="eval")


_LOADED: set[str] = set()


def __getattr__(name: str):
    if name == "app":
        load_commands()
        return app_module.app
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["Stopped", "app", "install_stop_handlers", "load_commands", "main", "COMMAND_MODULES"]

# the signals that stop a command: each becomes an exception in the main thread, so the work in
# flight is wound down (a LocalCluster's workers closed, their semaphores released, lineage of the
# finished tasks flushed) and the command ends with one line
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class Stopped(BaseException):
    """A stop signal arrived (SIGINT, SIGTERM, SIGHUP): not an error of the command's own."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


_STOPPED: list[int] = []  # the stop signals received so far


def install_stop_handlers() -> None:
    """Each stop signal becomes :class:`Stopped`, unless it is ignored (``nohup``, a script's
    background job): what the caller chose to ignore stays ignored."""
    for sig in STOP_SIGNALS:
        if signal.getsignal(sig) is not signal.SIG_IGN:
            signal.signal(sig, _on_stop_signal)


def _on_stop_signal(signum, frame) -> None:
    # once: a second signal while winding down (the last lineage flush, the cluster closing)
    # ends the process as it would by default, and the closing line says what that may cost
    _STOPPED.append(signum)
    for sig in STOP_SIGNALS:
        if signal.getsignal(sig) is _on_stop_signal:
            signal.signal(sig, signal.default_int_handler if sig == signal.SIGINT else signal.SIG_DFL)
    raise Stopped(signum)


def main() -> None:
    """Console-script entry point: the app, and below it a last net so that even an exception
    outside any command (or in the error path itself) is one line and exit 1; the process then
    leaves with that code whatever native threads are still alive (:mod:`.exit`)."""
    os.environ.setdefault("PYTHONWARNINGS", "ignore::DeprecationWarning")
    install_stop_handlers()
    try:
        load_commands(sys.argv[1:])
        app_module.app()
        code = 0
    except SystemExit as exc:
        code = exit_code(exc)
    except (Stopped, KeyboardInterrupt) as exc:
        signum = exc.signum if isinstance(exc, Stopped) else signal.SIGINT
        if isinstance(exc, KeyboardInterrupt) and _STOPPED:  # a second Ctrl-C cut the winding down short
            print("error: stopped by a second SIGINT while winding down: the tasks finished in the last seconds "
                  "may not be recorded and run again; the same command resumes", file=sys.stderr)
        else:
            print(f"error: stopped by {signal.Signals(signum).name}: what finished is recorded; the same command "
                  "resumes from there", file=sys.stderr)
        code = 128 + signum
    except BaseException as exc:  # noqa: BLE001 -- the last net: one line, never a traceback
        if debug_enabled() or "--debug" in sys.argv[1:]:
            traceback.print_exception(type(exc), exc, exc.__traceback__)
        print(f"error: unexpected {type(exc).__name__}: {one_line(exc)} ({DEBUG_HINT})", file=sys.stderr)
        code = 1
    leave(code)
