import pytest
from pydantic import ValidationError

from carlaocc.schemas.configs import DatasetConfig, parse_voxel_size_list


def test_unknown_key_refused_at_every_level():
    with pytest.raises(ValidationError, match="extra"):
        DatasetConfig.model_validate({"scenes": {"frame_cont": 3}})
    with pytest.raises(ValidationError, match="extra"):
        DatasetConfig.model_validate({"voxelise": {}})


def test_configs_are_frozen():
    cfg = DatasetConfig()
    with pytest.raises(ValidationError):
        cfg.scenes.frame_count = 3


def test_default_sequence_is_20_frames_at_20hz():
    cfg = DatasetConfig()
    assert cfg.scenes.frame_count >= 20 and cfg.scenes.rate_hz == 20.0


@pytest.mark.parametrize("text, expected", [("0.2", (0.2,)), ("0.2,0.05", (0.2, 0.05)), (" 0.1 , 0.1", (0.1,)),
                                            ("0.4,0.4000001", (0.4,))])
def test_parse_voxel_sizes(text, expected):
    assert parse_voxel_size_list(text) == expected


@pytest.mark.parametrize("text", ["", "abc", "0", "-0.1", "inf", "nan", "0.2,x", "1e-7"])
def test_parse_voxel_sizes_rejects(text):
    with pytest.raises(ValueError):
        parse_voxel_size_list(text)


def test_region_must_be_ordered():
    with pytest.raises(ValidationError, match="max > min"):
        DatasetConfig.model_validate({"voxelize": {"region_min": [0, 0, 0], "region_max": [1, -1, 1]}})


def test_default_dataset_has_a_procedural_and_an_opendrive_town_at_several_levels():
    towns = DatasetConfig().scenes.towns
    styles = [t.style for t in towns]
    assert "opendrive" in styles and any(s != "opendrive" for s in styles)
    assert len({lvl for t in towns for lvl in t.traffic_levels}) >= 2


def test_town_spec_checks():
    from carlaocc.schemas.configs import TownSpec

    with pytest.raises(ValidationError, match="opendrive file exactly"):
        TownSpec(style="opendrive")
    with pytest.raises(ValidationError, match="opendrive file exactly"):
        TownSpec(style="suburb", opendrive="x.xodr")
    with pytest.raises(ValidationError, match="repeats"):
        TownSpec(traffic_levels=("low", "low"))
    with pytest.raises(ValidationError):
        TownSpec(style="village")
    with pytest.raises(ValidationError, match="extra"):
        DatasetConfig.model_validate({"scenes": {"towns": [{"style": "suburb", "blockz": 3}]}})
    cfg = DatasetConfig.model_validate({"scenes": {"towns": [{"style": "arterial", "traffic_levels": ["high"]}]}})
    assert cfg.scenes.towns[0].style == "arterial" and cfg.scenes.rig.lidar.channels == 32


def test_camera_ray_stride_defaults_to_every_pixel_and_null_means_it_too():
    from carlaocc.schemas.configs import VoxelizeConfig

    assert VoxelizeConfig().camera_ray_stride == 1
    assert VoxelizeConfig(camera_ray_stride=None).camera_ray_stride == 1
    with pytest.raises(ValueError):
        VoxelizeConfig(camera_ray_stride=0)
