import numpy as np
import pytest
import zarr

from carlaocc.catalog.sensors import CAMERA_MAPS, LIDAR_COLUMNS, SENSOR_MAPS, LidarStore, SensorStore
from carlaocc.catalog.store import StoreError
from carlaocc.catalog.zarrio import zarr_store

W, H = 12, 8
K = [[10.0, 0.0, 6.0], [0.0, 10.0, 4.0], [0.0, 0.0, 1.0]]
POSE = [[1.0, 0.0, 0.0, 1.5], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 1.7], [0.0, 0.0, 0.0, 1.0]]


def _random(name: str, rng, shape=(H, W)) -> np.ndarray:
    dtype, _, trailing = SENSOR_MAPS[name]
    shape = (*shape, *trailing)
    if np.dtype(dtype).kind == "f":
        return rng.uniform(-1.0, 80.0, shape).astype(dtype)
    return rng.integers(1, np.iinfo(dtype).max, shape, endpoint=True).astype(dtype)


def _create(sensors, names=tuple(SENSOR_MAPS), width=W, height=H, frames=3):
    return sensors.create("seq", "cam_front", width, height, frames, names,
                          extra_attrs={"K": K, "camera_to_ego": POSE})


@pytest.mark.parametrize("name", list(SENSOR_MAPS))
def test_every_map_round_trips_through_zarr(store, name):
    sensors = SensorStore(store)
    assert _create(sensors) is False
    img = _random(name, np.random.default_rng(0))
    sensors.write_image("seq", "cam_front", 1, name, img)
    arr = zarr.open_group(store=zarr_store(store, "sensors.zarr"), mode="r")[f"seq/cam_front/{name}"]
    dtype, description, trailing = SENSOR_MAPS[name]
    assert arr.shape == (3, H, W, *trailing) and arr.chunks == (1, H, W, *trailing)
    assert arr.dtype == np.dtype(dtype)
    back = arr[1]
    assert back.dtype == img.dtype
    np.testing.assert_array_equal(back, img)
    np.testing.assert_array_equal(sensors.read_image("seq", "cam_front", 1, name), img)
    attrs = dict(arr.attrs)
    assert attrs == sensors.attrs("seq", "cam_front", name)
    assert list(attrs) == ["dims", "sequence_id", "camera", "taxonomy_version", "K", "camera_to_ego", "description"]
    assert attrs["camera"] == "cam_front" and attrs["description"] == description
    assert attrs["K"] == K and attrs["camera_to_ego"] == POSE
    # a frame exists once its image is stored (an unwritten frame has no chunk)
    assert sensors.exists("seq", "cam_front", name, 1) and not sensors.exists("seq", "cam_front", name, 0)


def test_map_table():
    assert CAMERA_MAPS == ("depth", "semantic", "instance", "normal")
    assert SENSOR_MAPS["normal"][2] == (3,)
    for raw in ("depth_raw", "semantic_raw", "instance_raw"):
        assert SENSOR_MAPS[raw][0] == SENSOR_MAPS[raw[:-4]][0]
        assert SENSOR_MAPS[raw][1].startswith("as the simulator delivers it (before rectification): ")


def test_create_compares_attributes_as_json_and_drops_unlisted(store):
    sensors = SensorStore(store)
    _create(sensors)
    img = _random("depth", np.random.default_rng(1))
    sensors.write_image("seq", "cam_front", 0, "depth", img)
    # K given as tuples is stored as JSON lists: the same spec, kept with its data
    assert sensors.create("seq", "cam_front", W, H, 3, tuple(SENSOR_MAPS),
                          extra_attrs={"K": tuple(map(tuple, K)), "camera_to_ego": POSE}) is False
    np.testing.assert_array_equal(sensors.read_image("seq", "cam_front", 0, "depth"), img)
    # the recorded path keeps the arrays it does not write (a recorder's *_raw input)
    assert sensors.create("seq", "cam_front", W, H, 3, ("depth",), extra_attrs={"K": K, "camera_to_ego": POSE},
                          keep_others=True) is False
    assert sensors.names("seq", "cam_front") == sorted(SENSOR_MAPS)
    assert _create(sensors, names=CAMERA_MAPS) is False
    assert sensors.names("seq", "cam_front") == sorted(CAMERA_MAPS)
    assert not sensors.exists("seq", "cam_front", "depth_raw")
    sensors.create("seq", "cam_left", W, H, 3, ("depth",))
    assert sensors.cameras("seq") == ["cam_front", "cam_left"]
    assert sensors.cameras("nope") == [] and sensors.names("seq", "nope") == []
    with pytest.raises(ValueError, match="unknown camera maps.*depth_raw"):
        sensors.create("seq", "cam_front", W, H, 3, ("colour",))


def test_empty_hierarchy(store):
    sensors = SensorStore(store)
    assert sensors.cameras("seq") == [] and not sensors.exists("seq", "cam", "depth", 0)
    with pytest.raises(ValueError, match="sensors.zarr/seq/cam/depth does not exist"):
        sensors.write_image("seq", "cam", 0, "depth", np.ones((H, W), np.float32))


def test_all_zero_image_removes_the_chunk(store):
    sensors = SensorStore(store)
    _create(sensors, names=("semantic", "normal"))
    sensors.write_image("seq", "cam_front", 2, "semantic", np.full((H, W), 7, np.uint8))
    assert sensors.exists("seq", "cam_front", "semantic", 2)
    sensors.write_image("seq", "cam_front", 2, "semantic", np.zeros((H, W), np.int64))
    assert not sensors.exists("seq", "cam_front", "semantic", 2)  # documented: no chunk, not "existing"
    assert not sensors.read_image("seq", "cam_front", 2, "semantic").any()


def test_write_image_rejects_wrong_shape_and_dtype(store):
    sensors = SensorStore(store)
    _create(sensors, names=("semantic", "depth"))
    with pytest.raises(ValueError, match="cam_front/semantic.*shape"):
        sensors.write_image("seq", "cam_front", 0, "semantic", np.zeros((W, H), np.uint8))
    with pytest.raises(ValueError, match="cam_front/semantic.*float32"):
        sensors.write_image("seq", "cam_front", 0, "semantic", np.ones((H, W), np.float32))
    with pytest.raises(ValueError, match="cam_front/semantic.*range"):
        sensors.write_image("seq", "cam_front", 0, "semantic", np.full((H, W), 300))
    with pytest.raises(ValueError, match="cam_front/depth.*frame"):
        sensors.write_image("seq", "cam_front", 3, "depth", np.ones((H, W), np.float32))
    # integer and wider float data of valid values is cast
    sensors.write_image("seq", "cam_front", 0, "semantic", np.full((H, W), 11))
    sensors.write_image("seq", "cam_front", 0, "depth", np.full((H, W), 2.5))
    assert sensors.read_image("seq", "cam_front", 0, "semantic").min() == 11
    assert sensors.read_image("seq", "cam_front", 0, "depth").dtype == np.float32


def _points(n: int, rng) -> dict[str, np.ndarray]:
    xyz = rng.normal(0.0, 20.0, (3, n))
    return {"x": xyz[0], "y": xyz[1], "z": xyz[2], "distance": np.linalg.norm(xyz, axis=0),
            "semantic": rng.integers(0, 30, n), "instance": rng.integers(0, 2**32 - 1, n, dtype=np.uint32),
            "channel": rng.integers(0, 128, n)}


def test_lidar_round_trip(store):
    lidar = LidarStore(store)
    rng = np.random.default_rng(3)
    pts = _points(500, rng)
    fp = lidar.save("seq", 7, pts, metadata={"lidar_to_ego": POSE, "channels": 128})
    assert lidar.path("seq", 7) == "lidar/seq/000007.parquet"
    assert fp == store.fingerprint("lidar/seq/000007.parquet")
    back = lidar.load("seq", 7)
    assert list(back) == list(LIDAR_COLUMNS)
    for c, (dtype, _) in LIDAR_COLUMNS.items():
        assert back[c].dtype == np.dtype(dtype), c
        np.testing.assert_array_equal(back[c], np.asarray(pts[c]).astype(dtype))
    meta = lidar.metadata("seq", 7)
    assert meta == {"sequence_id": "seq", "frame": 7, "frame_axes": "lidar: x forward, y left, z up",
                    "lidar_to_ego": POSE, "channels": 128}
    assert lidar.exists("seq", 7) and not lidar.exists("seq", 8)
    lidar.save("seq", 2, _points(0, rng))
    lidar.save("seq2", 1, _points(3, rng))
    assert lidar.frames("seq") == [2, 7] and lidar.frames("nope") == []
    assert all(len(v) == 0 for v in lidar.load("seq", 2).values())


def test_lidar_rejects_bad_points(store):
    lidar = LidarStore(store)
    rng = np.random.default_rng(4)
    pts = _points(10, rng)
    del pts["channel"]
    with pytest.raises(ValueError, match="channel"):
        lidar.save("seq", 0, pts)
    pts = _points(10, rng)
    pts["x"][3] = np.nan
    with pytest.raises(ValueError, match="column x"):
        lidar.save("seq", 0, pts)
    pts = _points(10, rng)
    pts["semantic"] = pts["semantic"][:5]
    with pytest.raises(ValueError, match="column semantic"):
        lidar.save("seq", 0, pts)
    pts = _points(10, rng)
    pts["instance"] = pts["instance"].astype(np.float64)
    with pytest.raises(ValueError, match="column instance"):
        lidar.save("seq", 0, pts)
    pts = _points(10, rng)
    pts["z"] = pts["z"].reshape(2, 5)
    with pytest.raises(ValueError, match="column z"):
        lidar.save("seq", 0, pts)
    assert not lidar.exists("seq", 0)
    with pytest.raises(StoreError, match="lidar/seq/000000.parquet"):
        lidar.load("seq", 0)
