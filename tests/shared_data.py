"""Where the tests find the shared test data, and what they do when it is not there.

The data lives next to the repository, at ``<repo>/../shared/testdata``, found from this file's
location (never an absolute path: ``tests/test_shared_data.py`` forbids those).
``CARLAOCC_SHARED=<folder>`` points the tests at another folder holding ``testdata/`` instead
(e.g. ``CARLAOCC_SHARED=/nowhere CI=1`` to see that every test on the data fails loudly).

A test on the data never passes by skipping where it matters:

* without ``CI`` in the environment, a test whose data is missing is skipped, the reason naming
  the missing path (``-ra`` lists it);
* with ``CI`` set (any value but empty, ``0``, ``false`` or ``no``), it fails instead, with one
  line naming the missing path.

Use::

    from shared_data import needs, require, shared_path

    DATA = shared_path("opendrive")
    pytestmark = needs(DATA)              # a whole module, or @needs(DATA / "Town01.xodr") on one test

    def test_x():
        clip = require(shared_path("motion/clip.bvh"))   # inside a test or fixture

(``tests/`` is on ``sys.path`` through ``tests/conftest.py``, so ``shared_data`` imports from
any test folder.)
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
ENV_ROOT = "CARLAOCC_SHARED"
_FALSE = ("", "0", "false", "no")


def shared_root() -> Path:
    """The folder holding ``testdata/``: ``$CARLAOCC_SHARED`` if set, else ``<repo>/../shared``."""
    env = os.environ.get(ENV_ROOT)
    return Path(env) if env else REPO.parent / "shared"


def shared_path(rel: str | os.PathLike = "") -> Path:
    """``<shared root>/testdata/<rel>`` (whether it exists or not)."""
    return shared_root() / "testdata" / rel


def in_ci() -> bool:
    """True when the ``CI`` environment variable is set to a true-ish value."""
    return os.environ.get("CI", "").strip().lower() not in _FALSE


def _missing(paths) -> list[Path]:
    return [Path(p) for p in paths if not Path(p).exists()]


def _message(missing: list[Path]) -> str:
    names = ", ".join(str(p) for p in missing)
    return (f"shared test data missing: {names} (expected under <repo>/../shared/testdata, "
            f"or ${ENV_ROOT}/testdata)")


class _Absent:
    """The condition of the ``skipif`` that :func:`needs` returns, evaluated when the test is set up:
    False when every path exists (the test runs), True when one is missing (skipped), and under CI
    it fails the test instead (``pytest.fail`` raised from ``bool()`` ends the test's setup)."""

    def __init__(self, paths) -> None:
        self.paths = tuple(Path(p) for p in paths)

    def __bool__(self) -> bool:
        missing = _missing(self.paths)
        if missing and in_ci():
            pytest.fail(f"{_message(missing)}; CI is set, so this test fails rather than skips",
                        pytrace=False)
        return bool(missing)

    def __repr__(self) -> str:
        return f"shared data absent: {', '.join(map(str, self.paths))}"


def needs(*paths: str | os.PathLike) -> pytest.MarkDecorator:
    """A mark for a test (or ``pytestmark`` of a module) that reads ``paths``: skipped when one is
    missing locally, failed loudly naming it when ``CI`` is set."""
    if not paths:
        raise TypeError("needs() takes at least one path")
    return pytest.mark.skipif(_Absent(paths), reason=_message(list(map(Path, paths))))


def require(path: str | os.PathLike) -> Path:
    """``path`` as a Path if it exists; otherwise skip the calling test (locally) or fail it naming
    the path (under ``CI``). For use inside a test or fixture."""
    p = Path(path)
    if p.exists():
        return p
    if in_ci():
        pytest.fail(f"{_message([p])}; CI is set, so this test fails rather than skips", pytrace=False)
    pytest.skip(_message([p]))
