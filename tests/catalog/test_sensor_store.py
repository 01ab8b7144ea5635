import numpy as np
import pytest
import zarr

from carlaocc.catalog.sensors import CAMERA_MAPS, LIDAR_COLUMNS, SENSOR_MAPS, LidarStore, SensorStore
from carlaocc.catalog.store import StoreError
from carlaocc.catalog.zarrio import frame_fingerprint, parse_frame_key, zarr_store
from carlaocc.pipeline.runner import outputs_intact
from carlaocc.schemas.taxonomy import TAXONOMY_VERSION

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
    assert not arr[0].any() and not arr[2].any()
    np.testing.assert_array_equal(sensors.read_image("seq", "cam_front", 1, name), img)
    attrs = dict(arr.attrs)
    assert attrs == sensors.attrs("seq", "cam_front", name)
    assert attrs["dims"] == ["frame", "v", "u", *(["component"] if trailing else [])]
    assert attrs["sequence_id"] == "seq" and attrs["camera"] == "cam_front"
    assert attrs["taxonomy_version"] == TAXONOMY_VERSION
    assert attrs["description"] == description
    assert attrs["K"] == K and attrs["camera_to_ego"] == POSE
    assert sensors.exists("seq", "cam_front", name, 1) and not sensors.exists("seq", "cam_front", name, 0)
    assert not sensors.exists("seq", "cam_front", name, 3)


def test_map_table():
    assert CAMERA_MAPS == ("depth", "semantic", "instance", "normal")
    assert SENSOR_MAPS["normal"][2] == (3,)
    for raw in ("depth_raw", "semantic_raw", "instance_raw"):
        assert SENSOR_MAPS[raw][0] == SENSOR_MAPS[raw[:-4]][0]
        assert SENSOR_MAPS[raw][1].startswith("as the simulator delivers it (before rectification): ")


def test_create_keeps_identical_replaces_differing_and_drops_unlisted(store):
    sensors = SensorStore(store)
    _create(sensors)
    img = _random("depth", np.random.default_rng(1))
    sensors.write_image("seq", "cam_front", 0, "depth", img)
    assert _create(sensors) is False  # identical (K given as lists, stored as JSON): kept with its data
    np.testing.assert_array_equal(sensors.read_image("seq", "cam_front", 0, "depth"), img)
    assert sensors.create("seq", "cam_front", W, H, 3, tuple(SENSOR_MAPS),
                          extra_attrs={"K": tuple(map(tuple, K)), "camera_to_ego": POSE}) is False
    assert _create(sensors, width=W + 4) is True  # another size: replaced, old data gone
    assert sensors.read_image("seq", "cam_front", 0, "depth").shape == (H, W + 4)
    assert not sensors.read_image("seq", "cam_front", 0, "depth").any()
    assert not sensors.exists("seq", "cam_front", "depth", 0)
    assert _create(sensors, names=CAMERA_MAPS, width=W + 4) is False
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
    with pytest.raises(ValueError, match="does not exist"):
        sensors.write_image("seq", "cam", 0, "depth", np.ones((H, W), np.float32))


def test_all_zero_image_removes_the_chunk(store):
    sensors = SensorStore(store)
    _create(sensors, names=("semantic", "normal"))
    sensors.write_image("seq", "cam_front", 2, "semantic", np.full((H, W), 7, np.uint8))
    assert sensors.exists("seq", "cam_front", "semantic", 2)
    sensors.write_image("seq", "cam_front", 2, "semantic", np.zeros((H, W), np.int64))
    assert not sensors.exists("seq", "cam_front", "semantic", 2)  # documented: no chunk, not "existing"
    assert not sensors.read_image("seq", "cam_front", 2, "semantic").any()
    neg = np.zeros((H, W, 3), np.float16)
    neg[0, 0, 0] = -0.0  # bitwise data: kept
    sensors.write_image("seq", "cam_front", 0, "normal", neg)
    assert np.signbit(sensors.read_image("seq", "cam_front", 0, "normal")[0, 0, 0])


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


def test_fingerprints_track_the_stored_chunk(store):
    sensors = SensorStore(store)
    _create(sensors, names=("depth", "normal"))
    rng = np.random.default_rng(2)
    depth, normal = _random("depth", rng), _random("normal", rng)
    sensors.write_image("seq", "cam_front", 1, "depth", depth)
    sensors.write_image("seq", "cam_front", 1, "normal", normal)
    fps = sensors.fingerprints("seq", "cam_front", 1, ("depth", "normal"))
    key = "sensors.zarr/seq/cam_front/depth[1]"
    assert set(fps) == {key, "sensors.zarr/seq/cam_front/normal[1]"}
    assert sensors.output_key("seq", "cam_front", "depth", 1) == key
    assert parse_frame_key(key) == ("sensors.zarr", "seq/cam_front/depth", 1)
    assert frame_fingerprint(store, "sensors.zarr", "seq/cam_front/depth", 1) == fps[key]
    sensors.write_image("seq", "cam_front", 1, "depth", depth.copy())  # identical: same fingerprint
    assert sensors.fingerprints("seq", "cam_front", 1, ("depth",))[key] == fps[key]
    # a temporary file left in the chunk directory is not part of the frame
    store.fs.pipe_file(store.path("sensors.zarr/seq/cam_front/depth/c/1/.chunk-crashed"), b"junk")
    assert sensors.fingerprints("seq", "cam_front", 1, ("depth",))[key] == fps[key]
    depth[0, 0] += 1.0
    sensors.write_image("seq", "cam_front", 1, "depth", depth)
    assert sensors.fingerprints("seq", "cam_front", 1, ("depth",))[key] != fps[key]
    assert frame_fingerprint(store, "sensors.zarr", "seq/cam_front/nope", 1) is None


def test_outputs_intact_checks_sensor_frames(store):
    sensors = SensorStore(store)
    _create(sensors, names=("semantic",))
    img = np.full((H, W), 4, np.uint8)
    sensors.write_image("seq", "cam_front", 0, "semantic", img)
    outputs = sensors.fingerprints("seq", "cam_front", 0, ("semantic",))
    assert outputs_intact(store, outputs)
    img[3, 3] = 5
    sensors.write_image("seq", "cam_front", 0, "semantic", img)
    assert not outputs_intact(store, outputs)


def test_parse_frame_key():
    from carlaocc.catalog.occupancy import parse_output_key

    assert parse_frame_key("occupancy.zarr/s/0.25/semantic[12]") == ("occupancy.zarr", "s/0.25/semantic", 12)
    assert parse_output_key("occupancy.zarr/s/0.25/semantic[12]") == ("s/0.25/semantic", 12)
    assert parse_output_key("sensors.zarr/s/cam/depth[3]") is None
    for plain in ("lidar/s/000001.parquet", "scenes/frames/s.parquet", "x.zarr[1]", "a/b[1]", "x.zarr/[1]"):
        assert parse_frame_key(plain) is None


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
