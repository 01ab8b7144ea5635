"""A built root shared by the modules that only read it: the embedded default at 0.1 m, two
frames a sequence, one camera (``camera_00``), stages up to sensors."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from carlaocc.catalog.store import Store
from carlaocc.pipeline.cli import app

DEFAULT_01_FRAMES = 2
DEFAULT_01_CONFIG = {"sensors": {"cameras": ["camera_00"]}}


@pytest.fixture(scope="session")
def default_01_config(tmp_path_factory) -> str:
    path = tmp_path_factory.mktemp("default_01_config") / "cfg.json"
    path.write_text(json.dumps(DEFAULT_01_CONFIG))
    return str(path)


@pytest.fixture(scope="session")
def default_01(tmp_path_factory, default_01_config) -> Store:
    """Read-only: a test that changes a root copies this one first."""
    root = tmp_path_factory.mktemp("default_01") / "data"
    r = CliRunner().invoke(app, ["run", "--res", "0.1", "--limit-frames", str(DEFAULT_01_FRAMES), "--root", str(root),
                                 "--config", default_01_config, "--stages", "ingest,scenes,splits,voxelize,sensors",
                                 "--scheduler", "synchronous"])
    assert r.exit_code == 0, r.output
    return Store(str(root))


@pytest.fixture(scope="session")
def infos_01(default_01, tmp_path_factory):
    """``carlaocc export mmdet3d-infos`` of :func:`default_01` (read-only)."""
    out = tmp_path_factory.mktemp("infos_01") / "infos"
    r = CliRunner().invoke(app, ["export", "mmdet3d-infos", "--res", "0.1", "--root", default_01.url, "--out", str(out)])
    assert r.exit_code == 0, r.output
    return out


@pytest.fixture(scope="session")
def openocc_01(default_01, tmp_path_factory):
    """``carlaocc export openocc-v2`` of :func:`default_01`'s busiest sequence (read-only)."""
    out = tmp_path_factory.mktemp("openocc_01") / "openocc"
    r = CliRunner().invoke(app, ["export", "openocc-v2", "--res", "0.1", "--root", default_01.url, "--out", str(out),
                                 "--sequence", "town00_high_seq000"])
    assert r.exit_code == 0, r.output
    return out


@pytest.fixture(scope="session")
def release_01(default_01, tmp_path_factory, default_01_config):
    """``carlaocc export carlaocc-release`` of :func:`default_01` at 0.1 m (read-only)."""
    out = tmp_path_factory.mktemp("release_01") / "CarlaOcc"
    r = CliRunner().invoke(app, ["export", "carlaocc-release", "--root", default_01.url, "--out", str(out),
                                 "--config", default_01_config])
    assert r.exit_code == 0, r.output
    return out
