"""The detection metrics against nuscenes-devkit itself (tools/crosscheck_nuscenes.py): AP, the
five TP errors with the devkit's cone and barrier rules, and NDS agree to 1e-9 on random
fixtures with velocities and attributes. The devkit pins numpy<2, so `make venv` installs it
apart (.venv/nuscenes-devkit, --no-deps) and the script runs in a subprocess with it on its path."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DEVKIT = ROOT / ".venv" / "nuscenes-devkit"


def test_detection_metrics_and_nds_agree_with_nuscenes_devkit():
    if not (DEVKIT / "nuscenes").is_dir():
        if os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no"):
            pytest.fail(f"{DEVKIT} is missing: `make venv` installs nuscenes-devkit there")
        pytest.skip(f"{DEVKIT} missing (make venv installs it)")
    env = dict(os.environ, PYTHONPATH=str(DEVKIT))
    r = subprocess.run([sys.executable, str(ROOT / "tools" / "crosscheck_nuscenes.py"), "40"], env=env,
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "all agree (AP, the five TP errors, NDS)" in r.stdout
