"""The headless Chromium the browser tests use (the docs site's pictures, the viewer), found in one
place: ``chromium()`` inside a test or fixture returns its path; without one the test is skipped,
naming what to install, and **with ``CI`` set it fails instead** (as shared test data does:
``tests/shared_data.py``). ``make test`` installs it (``tools/setup_system.sh --test``).

The driver (the DevTools protocol over a websocket, no browser download) is
``tools/headless_chromium.py``; ``headless_chromium`` imports from here as a module."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from shared_data import in_ci

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
import headless_chromium  # noqa: E402  (tools/ is not a package)

MISSING = ("no headless Chromium on PATH (chromium, chromium-browser, google-chrome; or $CHROMIUM): "
           "install it with `sh tools/setup_system.sh --test` (Debian: apt-get install chromium)")


def chromium() -> str:
    """The Chromium executable; skips the calling test without one, or fails it under CI."""
    path = headless_chromium.find_chromium()
    if path is None:
        if in_ci():
            pytest.fail(f"{MISSING}; CI is set, so this test fails rather than skips", pytrace=False)
        pytest.skip(MISSING)
    return path
