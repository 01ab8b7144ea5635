"""How the command line leaves the process: with the exit code the command decided, whatever
native threads are still alive.

A command's native thread pools (numba's, open3d's, BLAS, a Dask client's) are not joined when
CPython finalizes: tearing down the interpreter while one of their C++ threads is still joinable
aborts the process (``terminate called without an active exception``, SIGABRT, exit 134) after a
command that succeeded. So the entry point does the orderly part itself -- the ``atexit``
handlers (Dask clusters and clients, temporary folders, logging), then stdout and stderr flushed
-- and ends the process with ``os._exit``, which skips the interpreter's and the native
libraries' teardown. Every file the project writes is closed (and fsynced) before this point.
"""

from __future__ import annotations

import atexit
import os
import sys

__all__ = ["exit_code", "leave"]


def exit_code(exc: SystemExit) -> int:
    """The process exit code a ``SystemExit`` stands for (None: 0; a message: printed, 1)."""
    code = exc.code
    if code is None:
        return 0
    if isinstance(code, int):
        return code
    print(code, file=sys.stderr)
    return 1


def leave(code: int) -> None:
    """Run the ``atexit`` handlers, flush the standard streams, and end the process with ``code``
    without the interpreter's teardown (never returns)."""
    try:
        atexit._run_exitfuncs()  # what a normal exit would run first: our cleanups and the libraries'
    except BaseException:  # noqa: BLE001 -- a failing cleanup must not change a success into a crash
        code = code or 1
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe (carlaocc ... | head) or a closed stream
            pass
    os._exit(code)
