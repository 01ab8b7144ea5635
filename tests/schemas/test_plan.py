"""schemas/plan.py: the remembered plan's model, its effective config and the names of the keys
two plans differ by."""

import pytest
from pydantic import ValidationError

from carlaocc.schemas.configs import DatasetConfig
from carlaocc.schemas.plan import Plan, PlanSlice, config_changes, describe_changes, flatten, plan_changes


def test_flatten_names_every_leaf_by_its_path():
    assert flatten({"a": {"b": 1, "c": [1, 2]}, "d": [{"e": 3}], "f": {}}) == {
        "a.b": 1, "a.c": [1, 2], "d[0].e": 3, "f": {}}


def test_effective_config_applies_the_frame_limit_only():
    cfg = DatasetConfig()
    plan = Plan(slice=PlanSlice(limit_frames=2), config=cfg)
    eff = plan.effective_config()
    assert eff.scenes.frame_count == 2
    assert config_changes(cfg, eff) == ["scenes.frame_count"]
    # a limit above the plan's frames keeps them all
    assert Plan(slice=PlanSlice(limit_frames=10_000), config=cfg).effective_config() == cfg
    assert Plan(config=cfg).effective_config() == cfg


def test_plan_changes_name_the_keys_in_file_order():
    old = Plan(slice=PlanSlice(limit_frames=2))
    new = Plan(voxel_sizes=(0.1,), config=DatasetConfig(taxonomy="carlaocc-v1"))
    changes = plan_changes(old, new)
    assert [k for k, _, _ in changes] == ["voxel_sizes", "slice.limit_frames", "config.taxonomy"]
    assert changes[1] == ("slice.limit_frames", 2, None)
    text = describe_changes(changes)
    assert text == "voxel_sizes: [0.2] -> [0.1], slice.limit_frames: 2 -> (unset), config.taxonomy: release -> carlaocc-v1"
    assert plan_changes(old, old) == []
    assert describe_changes(changes, limit=1).endswith("and 2 more")


def test_a_star_is_every_sequence_and_the_slice_describes_itself():
    assert PlanSlice(sequences=("*",)) == PlanSlice()
    s = PlanSlice(limit_frames=2, sequences=("town00_*",))
    assert s.matches("town00_low_seq000") and not s.matches("town01_low_seq000")
    assert s.describe(20) == "first 2 of 20 frames of sequences town00_*"
    assert PlanSlice().describe(20) == "all 20 frames of every sequence"


@pytest.mark.parametrize("bad", [{"voxel_sizes": []}, {"voxel_sizes": [0]}, {"slice": {"limit_frames": 1}},
                                 {"typo": 1}, {"config": {"scenes": {"nope": 1}}}])
def test_bad_plans_are_refused(bad):
    with pytest.raises(ValidationError):
        Plan.model_validate(bad)
