"""catalog/plan.py: ``<root>/plan.yaml`` round trip (local and in memory), readable by a person,
and a damaged file refused naming it and the way past it."""

import pytest
import yaml

from carlaocc.catalog.plan import PlanStore
from carlaocc.catalog.store import PLAN_FILE, StoreError
from carlaocc.schemas.configs import DatasetConfig
from carlaocc.schemas.plan import Plan, PlanSlice


def test_round_trip(store):
    plans = PlanStore(store)
    assert not plans.exists() and plans.load() is None
    plan = Plan(voxel_sizes=(0.2, 0.1), slice=PlanSlice(limit_frames=3, sequences=("town00_*",)),
                config=DatasetConfig(taxonomy="carlaocc-v1"))
    plans.save(plan)
    assert plans.exists() and plans.load() == plan
    text = store.read_bytes(PLAN_FILE).decode()
    assert text.startswith("# ") and "--default-plan" in text  # says what it is and the way back
    data = yaml.safe_load(text)
    assert data["slice"] == {"limit_frames": 3, "sequences": ["town00_*"]}
    assert data["config"]["taxonomy"] == "carlaocc-v1" and data["voxel_sizes"] == [0.2, 0.1]


@pytest.mark.parametrize("body, says", [(b"voxel_sizes: [0.2\n", "not YAML"),
                                        (b"voxel_sizes: [0.2]\nslice: {limit_frames: 1}\n", "slice.limit_frames"),
                                        (b"colour: blue\n", "colour: unknown key")])
def test_a_damaged_plan_is_refused_naming_the_file(store, body, says):
    store.write_bytes(PLAN_FILE, body)
    with pytest.raises(StoreError) as err:
        PlanStore(store).load()
    assert PLAN_FILE in str(err.value) and says in str(err.value) and "--default-plan" in str(err.value)
