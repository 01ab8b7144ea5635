"""The default dataset at 0.05 m (several minutes on 2 cores): marked slow, run by `make test-all`.
The default `make test` exercises every stage end to end at 0.4 m (tests/test_end_to_end.py)."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.sql import query
from carlaocc.catalog.store import Store
from carlaocc.pipeline.cli import app
from carlaocc.schemas import taxonomy
from carlaocc.schemas.grid import GridSpec

pytestmark = pytest.mark.slow


def test_default_dataset_at_5cm(tmp_path):
    root = tmp_path / "data"
    r = CliRunner().invoke(app, ["run", "--res", "0.05", "--root", str(root)])
    assert r.exit_code == 0, r.output
    store, grid = Store(str(root)), GridSpec(voxel_size=0.05)
    seq = query(store, "SELECT min(sequence_id) FROM sequences")[1][0][0]
    sem = OccupancyStore(store).open(seq, grid, "semantic")
    assert sem.shape[1:] == (1536, 1024, 260)
    frame = sem[10]
    present = {taxonomy.by_id(int(c)).name for c in np.unique(frame) if c}
    assert {"Road", "Sidewalk", "Building", "Car", "Vegetation"} <= present
    _, rows = query(store, "SELECT value FROM quality WHERE frame_index IS NULL")
    assert len(rows) >= 3 and all(0.95 < r[0] <= 1.0 for r in rows)
