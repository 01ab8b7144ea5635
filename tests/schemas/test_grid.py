import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from carlaocc.schemas.grid import GridSpec, voxel_size_key


@pytest.mark.parametrize(
    "voxel_size, shape",
    [(0.05, (1536, 1024, 260)), (0.1, (768, 512, 130)), (0.2, (384, 256, 65)), (0.4, (192, 128, 33))],
)
def test_default_region_shapes(voxel_size, shape):
    g = GridSpec(voxel_size=voxel_size)
    assert g.shape == shape


def test_half_metre_grows_region_and_keeps_origin():
    g = GridSpec(voxel_size=0.5)
    # 76.8 / 0.5 = 153.6 and 51.2 / 0.5 = 102.4 voxels: rounded up, origin kept
    assert g.shape == (154, 103, 26)
    assert g.origin == (-25.6, -25.6, -3.0)
    assert g.effective_max == pytest.approx((51.4, 25.9, 10.0))
    assert g.grown
    attrs = g.attrs()
    assert attrs["effective_region"][1] == pytest.approx([51.4, 25.9, 10.0])
    assert attrs["region"][1] == [51.2, 25.6, 10.0]


def test_whole_grid_not_grown():
    assert not GridSpec(voxel_size=0.1).grown


@pytest.mark.parametrize("voxel_size", [0.0, -0.1, math.inf, math.nan])
def test_bad_voxel_size(voxel_size):
    with pytest.raises(ValidationError, match="voxel size"):
        GridSpec(voxel_size=voxel_size)


def test_region_smaller_than_voxel():
    with pytest.raises(ValidationError, match="region z extent .* smaller than one voxel"):
        GridSpec(region_min=(0, 0, 0), region_max=(10, 10, 0.01), voxel_size=0.05)


def test_unknown_field_refused():
    with pytest.raises(ValidationError):
        GridSpec(voxel_size=0.1, colour="red")


@settings(max_examples=200, deadline=None)
@given(voxel_size=st.floats(0.01, 2.0), ext=st.tuples(*[st.floats(2.0, 100.0)] * 3))
def test_effective_region_covers_region_within_one_voxel(voxel_size, ext):
    g = GridSpec(region_min=(0.0, 0.0, 0.0), region_max=ext, voxel_size=voxel_size)
    for hi, eff in zip(ext, g.effective_max):
        assert eff >= hi - 1e-6 * voxel_size
        assert eff < hi + voxel_size + 1e-9


def test_voxel_size_key():
    assert voxel_size_key(0.05) == "0.05"
    assert voxel_size_key(0.2) == "0.2"
    assert voxel_size_key(1.0) == "1"
    assert voxel_size_key(0.1 + 0.2 - 0.2) == "0.1"
