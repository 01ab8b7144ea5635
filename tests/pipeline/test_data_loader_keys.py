"""The keys of a carlaocc.data.CarlaOccDataset sample (issue 36): over every combination of options,
each key has the shape and dtype the module doc gives it, the keys are exactly those the options
plan, and no two parts of a sample share one (the camera maps are ``cam_<map>``, so a dense
``semantic`` / ``instance`` grid is never replaced by the camera map of that name); options under
which two parts would share a key are refused. On the shared built root (``default_01``, 0.1 m,
one camera)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from carlaocc.data import CAMERA_MAPS, OCCUPANCY_MODES, CarlaOccDataset, DatasetError

CROP = ((2.0, -6.0, -2.5), (14.3, 6.0, 1.0))
FRAME = 1  # a frame with boxes

# key -> (shape with symbols, dtype); X, Y, Z the grid (or crop), N occupied voxels, C cameras,
# H, W the image, P LiDAR points, M boxes
FRAME_KEYS = {"ego_pose": ((4, 4), np.float64), "lidar_pose": ((4, 4), np.float64),
              "lidar_to_ego": ((4, 4), np.float64), "grid_origin": ((3,), np.float64),
              "grid_shape": ((3,), np.int64)}
SPARSE = {"occ": (("N", 4), np.int32), "occ_instance": (("N",), np.uint32), "occ_flow": (("N", 3), np.float32),
          "occ_mask_camera": (("N",), np.bool_), "occ_mask_lidar": (("N",), np.bool_)}
DENSE = {"semantic": (("X", "Y", "Z"), np.uint8), "instance": (("X", "Y", "Z"), np.uint32),
         "flow": (("X", "Y", "Z", 3), np.float32), "mask_camera": (("X", "Y", "Z"), np.bool_),
         "mask_lidar": (("X", "Y", "Z"), np.bool_)}
CAMERAS = {"cam_intrinsics": (("C", 3, 3), np.float64), "cam_to_lidar": (("C", 4, 4), np.float64),
           "cam_to_ego": (("C", 4, 4), np.float64)}
IMAGES = {"images": (("C", "H", "W", 3), np.uint8)}
MAPS = {"cam_depth": (("C", "H", "W"), np.float32), "cam_semantic": (("C", "H", "W"), np.uint8),
        "cam_instance": (("C", "H", "W"), np.uint32), "cam_normal": (("C", "H", "W", 3), np.float16)}
LIDAR = {"points": (("P", 3), np.float32), "points_semantic": (("P",), np.uint8),
         "points_instance": (("P",), np.uint32), "points_channel": (("P",), np.uint8)}
BOXES = {"boxes": (("M", 7), np.float32), "box_pose": (("M", 4, 4), np.float64),
         "box_velocity": (("M", 3), np.float32), "box_instance": (("M",), np.uint32),
         "box_semantic": (("M",), np.uint8)}
HW = (376, 1408)


def _expected(occupancy, cameras, camera_maps, lidar, boxes) -> dict[str, dict]:
    """The parts a sample holds under these options, each {key: (shape, dtype)}."""
    parts = {"frame": dict(FRAME_KEYS)}
    if occupancy == "sparse":
        parts["occupancy"] = dict(SPARSE)
    elif occupancy == "dense":
        parts["occupancy"] = dict(DENSE)
    elif occupancy == "crop":
        parts["occupancy"] = {**DENSE, "crop_offset": ((3,), np.int64)}
    if cameras or camera_maps:
        parts["cameras"] = {**CAMERAS, **(IMAGES if cameras else {}),
                            **{f"cam_{m}": MAPS[f"cam_{m}"] for m in camera_maps}}
    if lidar:
        parts["lidar"] = dict(LIDAR)
    if boxes:
        parts["boxes"] = dict(BOXES)
    return parts


def _check(sample: dict, parts: dict[str, dict], grid_shape) -> None:
    keys = [k for p in parts.values() for k in p]
    assert len(keys) == len(set(keys)), "two parts share a key"
    scalars = {"sequence_id", "frame_index", "timestamp", "voxel_size", "camera_names"}
    assert set(sample) - scalars == set(keys)
    assert isinstance(sample["sequence_id"], str) and isinstance(sample["frame_index"], int)
    assert isinstance(sample["timestamp"], float) and isinstance(sample["voxel_size"], float)
    assert ("camera_names" in sample) == ("cameras" in parts)
    dims: dict[str, int] = {"H": HW[0], "W": HW[1]}
    if "camera_names" in sample:
        dims["C"] = len(sample["camera_names"])
    if "crop_offset" in sample:
        dims.update(zip("XYZ", sample["semantic"].shape))  # checked against the grid below
        assert np.all(sample["crop_offset"] + sample["semantic"].shape <= grid_shape)
    else:
        dims.update(zip("XYZ", (int(v) for v in grid_shape)))
    for part in parts.values():
        for key, (shape, dtype) in part.items():
            value = sample[key]
            assert isinstance(value, np.ndarray) and value.dtype == dtype, (key, getattr(value, "dtype", type(value)))
            assert value.ndim == len(shape), (key, value.shape, shape)
            for axis, (want, got) in enumerate(zip(shape, value.shape)):
                if isinstance(want, str):
                    assert dims.setdefault(want, got) == got, (key, axis, want, dims[want], got)
                else:
                    assert want == got, (key, value.shape, shape)


@pytest.fixture(scope="module")
def grid_shape(default_01):
    return CarlaOccDataset(default_01.url, occupancy="none", cameras=False, lidar=False, boxes=False)[FRAME]["grid_shape"]


@settings(max_examples=12, deadline=None)  # a dense 0.1 m sample takes ~1.7 s
@given(occupancy=st.sampled_from(OCCUPANCY_MODES), cameras=st.booleans(),
       camera_maps=st.lists(st.sampled_from(CAMERA_MAPS), unique=True, max_size=len(CAMERA_MAPS)),
       lidar=st.booleans(), boxes=st.booleans())
def test_every_key_has_its_shape_and_dtype_and_no_two_parts_share_one(default_01, grid_shape, occupancy, cameras,
                                                                     camera_maps, lidar, boxes):
    ds = CarlaOccDataset(default_01.url, occupancy=occupancy, crop=CROP if occupancy == "crop" else None,
                         cameras=cameras, camera_maps=tuple(camera_maps), lidar=lidar, boxes=boxes)
    parts = _expected(occupancy, cameras, camera_maps, lidar, boxes)
    # the dataset's own plan is these parts, disjoint
    want = {p: set(k) for p, k in parts.items()}
    want["frame"] |= {"sequence_id", "frame_index", "timestamp", "voxel_size"}
    if "cameras" in want:
        want["cameras"].add("camera_names")
    assert {p: set(k) for p, k in ds.key_plan().items()} == want
    _check(ds[FRAME], parts, grid_shape)


def test_dense_grids_keep_their_names_beside_the_camera_maps(default_01, grid_shape):
    """The issue: dense + camera_maps=("semantic", "instance") returned the (C, H, W) camera maps
    under ``semantic`` / ``instance``, the 3D grids silently dropped."""
    s = CarlaOccDataset(default_01.url, occupancy="dense", camera_maps=("semantic", "instance"), lidar=False,
                        boxes=False)[FRAME]
    grid = CarlaOccDataset(default_01.url, occupancy="dense", cameras=False, lidar=False, boxes=False)[FRAME]
    assert s["semantic"].shape == s["instance"].shape == tuple(grid_shape)
    assert s["semantic"].dtype == np.uint8 and s["instance"].dtype == np.uint32
    np.testing.assert_array_equal(s["semantic"], grid["semantic"])
    np.testing.assert_array_equal(s["instance"], grid["instance"])
    assert s["cam_semantic"].shape == s["cam_instance"].shape == (len(s["camera_names"]), *HW)
    assert s["cam_semantic"].dtype == np.uint8 and s["cam_instance"].dtype == np.uint32
    assert s["cam_instance"].any() and s["semantic"].any()


def test_options_under_which_two_parts_would_share_a_key_are_refused(default_01):
    class Clashing(CarlaOccDataset):  # a future part that forgot the existing names
        def key_plan(self):
            return {**super().key_plan(), "extra": frozenset({"semantic"})}

    with pytest.raises(DatasetError, match=r"sample keys \['semantic'\] would be given by both occupancy and extra"):
        Clashing(default_01.url, occupancy="dense", cameras=False, lidar=False)
    Clashing(default_01.url, occupancy="sparse", cameras=False, lidar=False)  # no grid named semantic: no clash
