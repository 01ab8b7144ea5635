"""The sensors stage: one task per (sequence, frame) ray-casts the rig's cameras (clean and raw
depth/semantic/instance maps, simulator artifacts) and LiDAR through the frame's scene — or reads
a recorder's raw maps — rectifies transparent and unlabelled regions guided by instances, adds
D2NT normals, and writes sensors.zarr, lidar/ and a rectification record per camera.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.carla_recording import NOT_RECORDED
from carlaocc.catalog.sensors import CAMERA_MAPS, LidarStore, RecordedLidarStore, SensorStore
from carlaocc.catalog.store import Store, StoreError
from carlaocc.pipeline.engine.spec import Context, Partition, StageSpec
from carlaocc.pipeline.tasks.frame import frame_inputs
from carlaocc.pipeline.tasks.partitions import INGEST_PARTITION, sequences
from carlaocc.pipeline.tasks.recording import read_frame_images, read_frame_lidar, recorded_frames
from carlaocc.schemas.configs import DatasetConfig, SensorsConfig
from carlaocc.schemas.records import LidarAgreementRecord, RectificationRecord
from carlaocc.schemas.rig import RigConfig
from carlaocc.stages.scenes.assembly import flatten
from carlaocc.stages.sensors import (CameraMaps, RayScene, camera_poses, recorded_stats, rectify_cameras, simulate_frame,
                                    to_float16)
from carlaocc.stages.sensors.recorded_lidar import lidar_agreement
from carlaocc.stages.threads import kernel_threads

if TYPE_CHECKING:
    from carlaocc.stages.sensors import CameraMaps


def sensors_config(config: DatasetConfig) -> SensorsConfig:
    """The sensors stage's config: ``sensors`` with the rig of ``scenes`` and the dataset's taxonomy."""
    return config.sensors.model_copy(update={"rig": config.scenes.rig, "taxonomy": config.taxonomy})


RECORDED_ARRAYS = ("depth_raw", "semantic_raw", "rgb")  # what a recorded sequence's frames bring


def sensors_partitions(ctx: Context) -> list[Partition]:
    """One per (sequence, frame). A frame of a recorded town (``carla-recording``) also names the
    recording's image and LiDAR files of that frame (fingerprinted: a changed file re-runs the frame)."""

    out = []
    for seq in sequences(ctx):
        recorded = recorded_frames(ctx.store, ctx.config.scenes, seq)
        for t in range(seq.frame_count):
            params = {"sequence_id": seq.sequence_id, "frame_index": t}
            files: tuple[str, ...] = ()
            if recorded is not None:
                params["recorded"] = recorded[t]
                files = tuple(f for f in recorded[t]["images"].values() for f in f.values())
                files += tuple(recorded[t]["lidar"].values())
            out.append(Partition(f"{seq.sequence_id}/{t:04d}", params, files=files,
                                 needs=(("ingest", INGEST_PARTITION), ("scenes", seq.town))))
    return out


def _sensors_prepare(ctx: Context, to_run: list[Partition], partitions: list[Partition]) -> set[str]:
    """Create the camera arrays of every sequence about to be written (intrinsics and extrinsics
    in their attributes); a replaced array invalidates every frame of its sequence. The recorded
    path creates only the arrays it writes and leaves the recorder's ``*_raw`` arrays alone."""

    cfg = sensors_config(ctx.config)
    rig = cfg.rig
    frames = {s.sequence_id: s.frame_count for s in sequences(ctx)}
    sensors = SensorStore(ctx.store)
    to_lidar = camera_poses(rig)
    invalid: set[str] = set()
    recorded = {p.params["sequence_id"] for p in to_run if "recorded" in p.params}
    for seq in sorted({p.params["sequence_id"] for p in to_run}):
        replaced = False
        source = "recorded" if seq in recorded else cfg.source
        names = CAMERA_MAPS + RECORDED_ARRAYS if seq in recorded else sensor_arrays(cfg)
        for cam in cfg.selected_cameras(rig):
            attrs = {"intrinsics": [list(r) for r in cam.intrinsics],
                     "camera_to_ego": [list(r) for r in cam.camera_to_ego()],
                     "camera_to_lidar": to_lidar[cam.name].tolist(),
                     "camera_frame": "opencv: x right, y down, z forward", "source": source,
                     "label_table": cfg.taxonomy}
            replaced |= sensors.create(seq, cam.name, cam.width, cam.height, frames[seq], names, extra_attrs=attrs,
                                       keep_others=cfg.source == "recorded" and seq not in recorded)
        if replaced:
            invalid |= {p.key for p in partitions if p.params["sequence_id"] == seq}
    return invalid


def sensor_region(cfg: SensorsConfig) -> tuple[np.ndarray, np.ndarray]:
    """The LiDAR-frame box whose scene the sensors see: ``scene_range`` around the LiDAR
    horizontally, 20 m below to ``scene_range / 2`` above it."""
    r = float(cfg.scene_range)
    return np.array([-r, -r, -20.0]), np.array([r, r, max(r / 2.0, 20.0)])


def sensor_arrays(cfg: SensorsConfig) -> tuple[str, ...]:
    """The camera arrays the sensors stage writes under ``cfg`` (the recorded path reads the raw
    ones, written by the recorder, and never writes them)."""

    raw = ("depth_raw", "semantic_raw", "instance_raw") if cfg.source == "raycast" else ()
    rgb = ("rgb",) if cfg.source == "raycast" and cfg.rgb else ()
    return CAMERA_MAPS + raw + rgb


def _recorded_raw(sensors, seq_id: str, frame_index: int, cam) -> "CameraMaps":
    """The raw maps a recorder wrote for one camera and frame (depth_raw and semantic_raw are
    required, instance_raw optional), with a clear error naming what is missing."""

    def read(name: str, required: bool):
        # a stored chunk is the recorder's image (an all-zero image has no chunk: for depth and
        # semantics of a road camera that is a frame the recorder did not write)
        if sensors.exists(seq_id, cam.name, name, frame_index):
            return sensors.read_image(seq_id, cam.name, frame_index, name)
        if required:
            raise StoreError(f"sensors.source is 'recorded' but sensors.zarr/{sensors.array_path(seq_id, cam.name, name)} "
                             f"has no frame {frame_index}: a recorder must write depth_raw and semantic_raw "
                             f"(see docs/concepts/sensors.md, 'Recorded sensor input')")
        return None

    return CameraMaps(read("depth_raw", True).astype(np.float32, copy=False),
                      read("semantic_raw", True).astype(np.uint8, copy=False), read("instance_raw", False))


def sensors_task(store: Store, cfg: SensorsConfig, part: Partition) -> dict[str, str]:
    """Camera maps and LiDAR of one frame into sensors.zarr and lidar/: the raycast path renders
    clean maps, simulates the raw ones and rectifies them; the recorded path rectifies the raw
    maps already in sensors.zarr. Both write the rectified depth/semantic/instance, the D2NT
    normals and a rectification record per camera."""

    seq_id, frame_index = part.params["sequence_id"], part.params["frame_index"]
    rig = cfg.rig or RigConfig()
    inputs = frame_inputs(store, seq_id, frame_index, sensor_region(cfg), cfg.taxonomy)
    sensors = SensorStore(store)
    cams = cfg.selected_cameras(rig)
    outputs: dict[str, str] = {}

    recorded = part.params.get("recorded")
    rgb: dict[str, np.ndarray] = {}
    source = "recorded" if recorded is not None else cfg.source
    if recorded is not None:
        # a recorded town's frame: the recording's raw maps (and RGB), rectified with its meshes
        raw = {}
        for cam in cams:
            raw[cam.name], image = read_frame_images(recorded["images"].get(cam.name, {}), cam)
            if image is not None:
                rgb[cam.name] = image
        rect = rectify_cameras(inputs.scene, rig, cfg, raw, nthreads=kernel_threads())
        per_camera = {name: (r, n, raw[name], recorded_stats(name, r, raw[name])) for name, (r, n) in rect.items()}
        frame = None
    elif cfg.source == "raycast":
        world_to_lidar = np.linalg.inv(np.asarray(inputs.frame.lidar_pose, dtype=np.float64).reshape(4, 4))
        frame = simulate_frame(inputs.scene, rig, cfg, nthreads=kernel_threads(), world_to_scene=world_to_lidar)
        per_camera = {name: (cf.rectification, cf.normal, cf.raw, cf.stats) for name, cf in frame.cameras.items()}
        rgb = {name: cf.rgb for name, cf in frame.cameras.items() if cf.rgb is not None}
    else:
        raw = {cam.name: _recorded_raw(sensors, seq_id, frame_index, cam) for cam in cams}
        rect = rectify_cameras(inputs.scene, rig, cfg, raw, nthreads=kernel_threads())
        per_camera = {name: (r, n, raw[name], recorded_stats(name, r, raw[name])) for name, (r, n) in rect.items()}
        frame = None
    records = []
    for cam in cams:
        rect, normal, raw, stats = per_camera[cam.name]
        images = {"depth": rect.maps.depth, "semantic": rect.maps.semantic, "normal": to_float16(normal)}
        if rect.maps.instance is not None:
            images["instance"] = rect.maps.instance
        if recorded is not None:
            images.update(depth_raw=raw.depth, semantic_raw=raw.semantic)
            if cam.name in rgb:
                images["rgb"] = rgb[cam.name]
        elif cfg.source == "raycast":
            images.update(depth_raw=raw.depth, semantic_raw=raw.semantic, instance_raw=raw.instance)
            if cam.name in rgb:
                images["rgb"] = rgb[cam.name]
        for name, data in images.items():
            sensors.write_image(seq_id, cam.name, frame_index, name, data)
        outputs.update(sensors.fingerprints(seq_id, cam.name, frame_index, tuple(images)))
        records.append(RectificationRecord(sequence_id=seq_id, frame_index=frame_index, source=source,
                                           **dataclasses.asdict(stats)))
    if frame is not None and frame.lidar is not None:
        lidar = LidarStore(store)
        meta = {"lidar_to_world": inputs.frame.lidar_pose, "timestamp": inputs.frame.timestamp,
                "channels": rig.lidar.channels, "range_m": rig.lidar.range_m}
        outputs[lidar.path(seq_id, frame_index)] = lidar.save(seq_id, frame_index, frame.lidar, meta)
    table = ParquetTable(store, RectificationRecord)
    key = f"{seq_id}/{frame_index:04d}"
    outputs[table.path(key)] = table.save(key, records)
    if recorded is not None and recorded.get("lidar"):
        outputs.update(_recorded_lidar(store, seq_id, frame_index, inputs, recorded))
    return outputs


def _recorded_lidar(store: Store, seq_id: str, frame_index: int, inputs, recorded: dict) -> dict[str, str]:
    """A recorded frame's LiDAR scans into lidar_recorded/ with our range along each beam through
    the frame's scene (cut to ``sensors.scene_range``, 120 m by default: past the recording's
    80 m LiDAR range) and their agreement into metrics/lidar_agreement/."""
    points = read_frame_lidar(recorded["lidar"])
    xyz = np.column_stack([points["x"], points["y"], points["z"]])
    scene = RayScene(flatten(inputs.scene), nthreads=kernel_threads())
    ours, summary = lidar_agreement(scene, xyz, points["semantic"], NOT_RECORDED, nthreads=kernel_threads())
    lidar = RecordedLidarStore(store)
    meta = {"lidar_to_world": inputs.frame.lidar_pose, "timestamp": inputs.frame.timestamp,
            "recorded_frame": recorded["number"], "files": sorted(recorded["lidar"])}
    out = {lidar.path(seq_id, frame_index): lidar.save(seq_id, frame_index, {**points, "raycast_distance": ours}, meta)}
    table = ParquetTable(store, LidarAgreementRecord)
    key = f"{seq_id}/{frame_index:04d}"
    out[table.path(key)] = table.save(key, [LidarAgreementRecord(sequence_id=seq_id, frame_index=frame_index,
                                                                 **dataclasses.asdict(summary))])
    return out


SPEC = StageSpec(
    name="sensors",
    description="ray-cast camera maps and LiDAR, simulator artifacts, instance-guided rectification, normals",
    upstream=("ingest", "scenes"),
    reads=("admesh/", "scenes/", "sensors.zarr/<seq>/<cam>/*_raw (recorded source)",
           "a recorded town's camera PNGs (depth_carla, semantics_carla, rgb) and LiDAR PLYs (lidar, semantic_lidar)"),
    writes=("sensors.zarr/<seq>/<cam>/{depth,semantic,instance,normal}[_raw]", "sensors.zarr/<seq>/<cam>/rgb",
            "lidar/<seq>/", "lidar_recorded/<seq>/ (recorded towns)",
            "metrics/rectification/", "metrics/lidar_agreement/ (recorded towns)"),
    partitions=sensors_partitions,
    task=sensors_task,
    prepare=_sensors_prepare,
    config_of=sensors_config,
)
