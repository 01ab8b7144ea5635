"""The shared test data is found relative to the repository, never by a machine's absolute path,
and a test on it skips only off CI: with ``CI`` set and the data missing it fails, naming the path."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

import shared_data
from shared_data import needs, require, shared_path, shared_root

REPO = Path(__file__).resolve().parents[1]
SCANNED = ["tests", "benchmarks", "tools", "schemas", "stages", "catalog", "pipeline", ".ci",
           "Makefile", "pyproject.toml", "README.md", "docs", "mkdocs.yml"]  # fmt: skip
SKIPPED_DIRS = {"__pycache__", ".hypothesis", ".pytest_cache", ".ruff_cache"}
# the strings are split so that this file does not match itself
ONE_MACHINE = "/work" + "/shared"
TAIL = "shared" + "/" + "testdata"
# an absolute path: a "/" at the start of a token, then components other than "." and "..", ending
# in shared/testdata ("<repo>/../shared/testdata" and "../shared/testdata" are relative: fine)
ABSOLUTE = re.compile(r"""(?:^|(?<=[\s"'`(\[=,:]))/(?:(?!\.\.?/)[^\s"'`/]+/)*""" + re.escape(TAIL))
# in tests/, the data's folder is built by shared_data alone (no ad-hoc `... / "shared" / ...`)
HAND_BUILT = re.compile(r"""/\s*["']""" + "shared" + r"""["']""")


def _texts():
    for name in SCANNED:
        top = REPO / name
        files = [top] if top.is_file() else sorted(top.rglob("*")) if top.is_dir() else []
        for f in files:
            if not f.is_file() or SKIPPED_DIRS & set(f.relative_to(REPO).parts):
                continue
            raw = f.read_bytes()
            if b"\0" in raw:
                continue
            try:
                yield f.relative_to(REPO).as_posix(), raw.decode("utf-8")
            except UnicodeDecodeError:
                continue


def test_the_abs_path_pattern():
    bad = [f'Path("{ONE_MACHINE}/testdata/x")', f"# see /data/{TAIL}/meshes", f"x=/{TAIL}",
           f"open('/home/me/{TAIL}')", f"/{TAIL}"]  # fmt: skip
    good = [f"<repo>/../{TAIL}", f"`../{TAIL}/occupancy`", "$CARLAOCC_SHARED/testdata", f"{{root}}/{TAIL}",
            f"parents[2] / '..' / {TAIL!r}"]  # fmt: skip
    assert all(ABSOLUTE.search(s) for s in bad), [s for s in bad if not ABSOLUTE.search(s)]
    assert not any(ABSOLUTE.search(s) for s in good), [s for s in good if ABSOLUTE.search(s)]


def test_no_absolute_path_to_the_shared_data():
    offenders = []
    for rel, text in _texts():
        for n, line in enumerate(text.splitlines(), 1):
            if ONE_MACHINE in line or ABSOLUTE.search(line):
                offenders.append(f"{rel}:{n}: {line.strip()}")
    assert not offenders, "absolute paths to the shared data (use tests/shared_data.py):\n" + "\n".join(offenders)


def test_tests_find_the_data_through_the_helper_only():
    offenders = []
    for rel, text in _texts():
        if not rel.startswith("tests/") or rel in ("tests/shared_data.py", "tests/test_shared_data.py"):
            continue
        for n, line in enumerate(text.splitlines(), 1):
            if HAND_BUILT.search(line):
                offenders.append(f"{rel}:{n}: {line.strip()}")
    assert not offenders, "shared data paths built by hand (use shared_data.shared_path):\n" + "\n".join(offenders)


# ------------------------------------------------------------------------------- the helper


def test_root_is_next_to_the_repository(monkeypatch):
    monkeypatch.delenv(shared_data.ENV_ROOT, raising=False)
    assert shared_root() == REPO.parent / "shared"
    assert shared_path("opendrive/Town01.xodr") == REPO.parent / "shared" / "testdata" / "opendrive" / "Town01.xodr"
    monkeypatch.setenv(shared_data.ENV_ROOT, "/elsewhere")
    assert shared_path("motion") == Path("/elsewhere/testdata/motion")


@pytest.mark.parametrize("value, ci", [(None, False), ("", False), ("0", False), ("false", False), ("no", False),
                                       ("1", True), ("true", True), ("yes", True)])  # fmt: skip
def test_in_ci(monkeypatch, value, ci):
    if value is None:
        monkeypatch.delenv("CI", raising=False)
    else:
        monkeypatch.setenv("CI", value)
    assert shared_data.in_ci() is ci


def test_require_returns_a_present_path(tmp_path, monkeypatch):
    monkeypatch.setenv("CI", "1")
    assert require(str(tmp_path)) == tmp_path


def test_require_skips_without_ci(tmp_path, monkeypatch):
    monkeypatch.delenv("CI", raising=False)
    missing = tmp_path / "nope" / "clip.bvh"
    with pytest.raises(pytest.skip.Exception, match=re.escape(str(missing))):
        require(missing)


def test_require_fails_under_ci(tmp_path, monkeypatch):
    monkeypatch.setenv("CI", "true")
    missing = tmp_path / "nope" / "clip.bvh"
    with pytest.raises(pytest.fail.Exception, match=re.escape(str(missing))):
        require(missing)


def test_needs_mark(tmp_path, monkeypatch):
    missing = tmp_path / "nope"
    mark = needs(missing).mark
    assert mark.name == "skipif" and str(missing) in mark.kwargs["reason"]
    (condition,) = mark.args
    monkeypatch.delenv("CI", raising=False)
    assert bool(condition) is True  # skipped locally
    monkeypatch.setenv("CI", "1")
    with pytest.raises(pytest.fail.Exception, match=re.escape(str(missing))):
        bool(condition)  # fails under CI
    missing.mkdir()
    assert bool(condition) is False  # present: runs, CI or not
    with pytest.raises(TypeError):
        needs()


PROBE = """
from shared_data import needs, require, shared_path

MISSING = shared_path("no-such-file.bin")


@needs(MISSING)
def test_marked():
    pass


def test_required():
    require(shared_path("motion/absent.bvh"))
"""


def _probe(tmp_path: Path, ci: str | None) -> subprocess.CompletedProcess:
    (tmp_path / "test_probe.py").write_text(PROBE)
    (tmp_path / "pytest.ini").write_text("[pytest]\n")
    env = {k: v for k, v in os.environ.items() if k not in ("CI", "PYTEST_ADDOPTS")}
    env["PYTHONPATH"] = str(REPO / "tests")
    env[shared_data.ENV_ROOT] = str(tmp_path / "wrong-root")
    if ci is not None:
        env["CI"] = ci
    args = ["-q", "-ra", "-p", "no:cacheprovider", "-p", "no:dash", "-c", str(tmp_path / "pytest.ini")]
    return subprocess.run([sys.executable, "-m", "pytest", *args, str(tmp_path / "test_probe.py")],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)  # fmt: skip


def test_a_run_without_ci_skips_naming_the_path(tmp_path):
    r = _probe(tmp_path, None)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "2 skipped" in r.stdout and "no-such-file.bin" in r.stdout, r.stdout
    assert "wrong-root" in r.stdout


def test_a_run_under_ci_fails_naming_the_path(tmp_path):
    r = _probe(tmp_path, "1")
    assert r.returncode == 1, r.stdout + r.stderr
    assert "skipped" not in r.stdout, r.stdout
    out = r.stdout
    assert "no-such-file.bin" in out and "motion/absent.bvh" in out and "CI is set" in out, out
    assert "1 failed" in out and "1 error" in out, out  # require fails the test, needs its setup
