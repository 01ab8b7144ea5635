"""Starting a command in a test as a terminal would: the stop signals at their defaults.

A suite started in the background by a non-interactive shell (``make test &``, a CI runner's
shell) inherits SIGINT ignored, and every carlaocc command rightly keeps an ignored stop signal
ignored (the ``nohup`` case, tests/pipeline/test_faults.py). A test of what Ctrl-C does therefore
starts its command with ``preexec_fn=from_a_terminal``."""

from __future__ import annotations

import signal

__all__ = ["from_a_terminal"]


def from_a_terminal() -> None:
    """In the child, before exec: SIGINT and SIGTERM back to their defaults."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_DFL)
