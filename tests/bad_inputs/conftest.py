"""Shared by the bad-input tests: a good dataset root built once, a byte snapshot of it, and the
check every bad input must pass (its exit code, one clear line naming the input, no traceback)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
from typer.testing import CliRunner

from carlaocc.pipeline.cli import app


@pytest.fixture(scope="session")
def good_root(tmp_path_factory) -> Path:
    """A root holding the embedded default's library and scenes (ingest, scenes), built once.
    Tests must leave it as it is (``snapshot`` before, ``snapshot`` after)."""
    import carlaocc

    root = tmp_path_factory.mktemp("good") / "root"
    outcomes = carlaocc.run(str(root), stages=["ingest", "scenes"], scheduler="synchronous")
    assert all(not o.failed for o in outcomes)
    return root


def snapshot(root: Path) -> dict[str, str]:
    """Relative path -> SHA-256 of every file under ``root``."""
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def invoke(*args: str):
    """Run the CLI in-process; stdout and stderr apart."""
    return CliRunner().invoke(app, [str(a) for a in args])


def assert_clear_error(result, code: int, *names: str) -> str:
    """The command exited with ``code``, printed no traceback, and its error is one line starting
    with ``error:`` that names each of ``names`` (the input the user gave). Returns that line."""
    out = result.output
    assert result.exit_code == code, f"exit {result.exit_code} != {code}:\n{out}"
    assert "Traceback" not in out, out
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise AssertionError(f"unhandled {type(result.exception).__name__}: {result.exception}\n{out}")
    lines = [ln for ln in out.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1, f"expected one error line:\n{out}"
    for name in names:
        assert str(name) in lines[0], f"{name!r} not named in: {lines[0]}"
    return lines[0]
