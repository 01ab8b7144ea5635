"""The scenes stage on a recorded town (``style: carla-recording``): reads the recording through
:mod:`carlaocc.catalog.carla_recording`, finds the ADMesh assets ``carlaocc ingest
carla-recording`` made of its vehicle models and walk cycle, and returns the town and its
sequences (:mod:`carlaocc.stages.scenes.recording`) with what had to be left out.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image

from carlaocc.catalog.carla_recording import (DEPTH_RANGE, RecordingError, decode_depth, decode_semantics, discover,
                                              model_key, read_actor_info, read_calib, read_mesh, read_poses,
                                              read_scans, read_traffic)
from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.sources.carla_recording import WALK_CYCLE, model_offset
from carlaocc.catalog.store import StoreError
from carlaocc.pipeline.tasks.partitions import town_key
from carlaocc.schemas.configs import DatasetConfig, ScenesConfig, TownSpec
from carlaocc.schemas.records import AssetRecord, FrameRecord
from carlaocc.schemas.rig import CameraSpec
from carlaocc.schemas.taxonomy import thing_ids
from carlaocc.stages.scenes.recording import RecordedAsset, RecordedFrame, WalkFrame, recorded_sequence, recorded_town
from carlaocc.stages.sensors import CameraMaps

__all__ = ["RecordedTown", "recorded_scenes", "recording_files", "rig_from_calib", "recorded_frames", "read_frame_images",
           "read_frame_lidar"]


@dataclass
class RecordedTown:
    town: object  # stages.scenes.network.Town
    sequences: list  # stages.scenes.recording.RecordedSequence
    skipped: list[tuple[str, str]] = field(default_factory=list)  # (file or item, reason)


def _map_of(rec, spec: TownSpec) -> str:
    towns = sorted({s.town for s in rec.sequences})
    if spec.map is not None:
        if spec.map not in towns:
            raise StoreError(f"recording {spec.recording}: no sequences of map {spec.map!r} (it has {', '.join(towns)})")
        return spec.map
    if len(towns) > 1:
        raise StoreError(f"recording {spec.recording} holds several towns ({', '.join(towns)}): give the town spec a "
                         f"map (one town spec per map)")  # fmt: skip
    return towns[0]


def recording_files(spec: TownSpec) -> tuple[str, ...]:
    """The files whose bytes define a recorded town (fingerprinted with its scenes partition):
    calibration, actor list and meshes, vehicle models and the walk cycle, pose files and traffic
    of its sequences (not the images: the sensors stage's frames name those)."""

    try:
        rec = discover(spec.recording)
        town = _map_of(rec, spec)
    except RecordingError as exc:
        raise StoreError(f"town recording: {exc}") from None
    files = [rec.calib]
    if town in rec.scene_meshes:
        scene = rec.scene_meshes[town]
        files += [scene / "actor_info.json", *sorted((scene / "bg_actors").glob("*.obj"))]
    fg = rec.root / "SceneMeshes" / "fg_actors"
    if fg.is_dir():  # the models' offsets and the walk cycle's bones come from these
        files += sorted(fg.rglob("*.obj")) + sorted(fg.rglob("*_bones.json"))
    for s in rec.sequences:
        if s.town == town:
            files += [s.path / "poses" / "lidar.txt", *sorted((s.path / "traffic_info").glob("*.yaml"))]
    return tuple(str(f) for f in files if Path(f).is_file())


def _wrap180(deg: float) -> float:
    """An angle in degrees in (-180, 180]; within 1e-6 of -180 counts as +180."""
    w = math.remainder(deg, 360.0)
    return 180.0 if w <= -180.0 + 1e-6 else w + 0.0


def rig_from_calib(calib, base):
    """The rig of a recording: the six cameras of its calibration (camera-to-LiDAR transforms,
    size, fov) on the LiDAR of ``base`` (a RigConfig, its LiDAR at (0, 0, z) on the ego, unturned,
    as the recording's; camera pitch and roll are not representable and must be 0)."""

    lidar_z = base.lidar.z
    cams = []
    for name, T in calib.cam_to_lidar.items():
        if abs(T[2, 2] - 1.0) > 1e-3:
            raise StoreError(f"calibration camera {name} is pitched or rolled against the LiDAR: the rig has level "
                             f"cameras only")  # fmt: skip
        # CARLA's yaw turns right: the negated heading, in (-180, 180] (a rear camera is +180)
        yaw = _wrap180(-math.degrees(math.atan2(T[1, 0], T[0, 0])))
        cams.append(CameraSpec(name=name.replace("cam_", "camera_"), x=float(T[0, 3]), y=float(-T[1, 3]),
                               z=float(T[2, 3] + lidar_z), yaw_deg=yaw, width=calib.width, height=calib.height,
                               hfov_deg=calib.fov_deg))  # fmt: skip
    return base.model_copy(update={"cameras": tuple(cams)})


def check_rig(rig, calib, label: str) -> None:
    """The config's rig must be the recording's (the voxelize masks and the sensors use it)."""
    want = rig_from_calib(calib, rig)
    mine = {c.name: c for c in rig.cameras}
    for c in want.cameras:
        have = mine.get(c.name)
        differs = have is None or (have.width, have.height) != (c.width, c.height) or any(
            abs(getattr(have, k) - getattr(c, k)) > 1e-3 for k in ("x", "y", "z", "hfov_deg")) or abs(
            math.remainder(have.yaw_deg - c.yaw_deg, 360.0)) > 1e-3
        if differs:
            raise StoreError(f"{label}: scenes.rig camera {c.name} differs from the recording's calib/calib.yaml "
                             f"(x {c.x:.3f}, y {c.y:.3f}, z {c.z:.3f}, yaw {c.yaw_deg:.2f} deg, {c.width}x{c.height}, "
                             f"fov {c.hfov_deg:.3f}): use the config `carlaocc ingest carla-recording` writes")  # fmt: skip


def _walk_cycle(rec, assets: dict[str, AssetRecord], skipped) -> list:
    folder = rec.root / "SceneMeshes" / "fg_actors" / WALK_CYCLE
    cycle = []
    rz90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    for obj in sorted(folder.glob("frame_*.obj")) if folder.is_dir() else []:
        key = f"fg_actors/{WALK_CYCLE}/{obj.name}"
        asset = assets.get(key)
        bones_file = obj.with_name(f"{obj.stem}_bones.json")
        if asset is None:
            skipped.append((str(obj), "walk-cycle frame not in ADMesh: run `carlaocc ingest carla-recording` first"))
            continue
        try:
            V, _ = read_mesh(obj)
            bones = {k: np.asarray(v, dtype=np.float64).reshape(4, 4) for k, v in json.loads(bones_file.read_text()).items()}
            # the gait signal: how far the left knee is ahead of the right; the mesh axes walk along +z
            stride = float(bones["crl_leg__L"][2, 3] - bones["crl_leg__R"][2, 3])
        except (RecordingError, OSError, ValueError, TypeError, KeyError) as exc:
            skipped.append((str(bones_file), f"walk-cycle frame unusable: {exc!r}"))
            continue
        # the component frame is the actor's turned -90 deg; the asset origin in the actor frame,
        # in metres whatever the frame's units were (standardization's scale)
        cycle.append(WalkFrame(asset=asset, offset=model_offset(V @ rz90.T) * asset.scale_applied, stride=stride))
    return cycle


def _frames_text(frames: list[int]) -> str:
    """``[0, 1, 2, 5]`` -> ``"0-2, 5"``."""
    runs, out = [], sorted(set(frames))
    for f in out:
        if runs and f == runs[-1][1] + 1:
            runs[-1][1] = f
        else:
            runs.append([f, f])
    return ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in runs)


def recorded_scenes(store, cfg: ScenesConfig, spec: TownSpec, index: int, name: str) -> RecordedTown:
    """Town ``name`` and its sequences from the recording of ``spec`` (see the module docstring).
    Items that cannot be read (a missing mesh, a bad pose line, an actor with a NaN transform, a
    blueprint without a model) are left out and listed in ``skipped``; a recording without any
    usable static mesh or frame raises StoreError naming it."""

    label = f"town {name} (recording {spec.recording})"
    try:
        rec = discover(spec.recording)
        town_name = _map_of(rec, spec)
        calib = read_calib(rec.calib)
        check_rig(cfg.rig, calib, label)
        if town_name not in rec.scene_meshes:
            raise RecordingError(f"{rec.root / 'SceneMeshes' / town_name}: missing (the town's exported meshes)")
        actors, skipped = read_actor_info(rec.scene_meshes[town_name])
    except RecordingError as exc:
        raise StoreError(f"{label}: {exc}") from None
    statics = []
    for a in actors:
        try:
            V, F = read_mesh(a.file)
        except RecordingError as exc:
            skipped.append((str(a.file), str(exc)))
            continue
        statics.append((a.name, a.semantic_id, V, F))
    try:
        town = recorded_town(name, index, str(rec.root), statics, frozenset(thing_ids(cfg.taxonomy)))
    except ValueError as exc:
        raise StoreError(f"{label}: {exc}") from None
    # the ADMesh assets of the recording's models, by source path
    assets = {a.source_path: a for a in ParquetTable(store, AssetRecord).load() if a.source == "carla-recording"}
    models = {}
    for bp, obj in rec.vehicle_models.items():
        asset = assets.get(f"fg_actors/{obj.parent.name}/{obj.name}")
        if asset is not None:
            try:
                models[bp] = RecordedAsset(asset=asset, offset=model_offset(read_mesh(obj)[0]) * asset.scale_applied)
            except RecordingError as exc:
                skipped.append((str(obj), str(exc)))
    cycle = _walk_cycle(rec, assets, skipped)
    sequences = []
    for s in rec.sequences:
        if s.town != town_name:
            continue
        try:
            poses, bad = read_poses(s.path / "poses" / "lidar.txt")
        except RecordingError as exc:
            skipped.append((str(s.path), f"sequence left out: {exc}"))
            continue
        skipped += [(str(s.path / "poses" / "lidar.txt"), reason) for _, reason in bad]
        frames = []
        for n in sorted(poses):
            path = s.path / "traffic_info" / f"{n:04d}.yaml"
            try:
                frames.append(RecordedFrame(number=n, lidar_pose=poses[n], traffic=read_traffic(path)))
            except RecordingError as exc:
                skipped.append((str(path), f"frame {n} left out: {exc}"))
        if not frames:
            skipped.append((str(s.path), "sequence left out: no frame has both a LiDAR pose and traffic"))
            continue
        types = {v.type for f in frames for v in f.traffic.vehicles} | {frames[0].traffic.ego.type}
        by_type = {t: models[model_key(t)] for t in types if model_key(t) in models}
        ego = by_type.get(frames[0].traffic.ego.type)
        seq = recorded_sequence(f"{name}_{s.name}", town, s.index, frames, cfg.rig, by_type, cycle,
                                ego.asset.asset_id if ego else "")  # fmt: skip
        # one row per (actor, reason) with the frames it covers, not one per frame
        grouped: dict[tuple[int, str], list[int]] = {}
        for fr, aid, reason in seq.skipped:
            grouped.setdefault((aid, reason), []).append(fr)
        skipped += [(f"{s.name} actor {aid}", f"{reason} (frames {_frames_text(frs)})")
                    for (aid, reason), frs in sorted(grouped.items())]  # fmt: skip
        sequences.append(seq)
    if not sequences:
        raise StoreError(f"{label}: no usable sequence of {town_name}"
                         + (f" ({skipped[-1][1]})" if skipped else ""))  # fmt: skip
    # paths relative to the recording's root (the town's source names it)
    base = f"{rec.root}/"
    skipped = [(where.replace(base, ""), why.replace(base, "")) for where, why in skipped]
    return RecordedTown(town=town, sequences=sequences, skipped=skipped)


def recording_config(recording: str, existing=None):
    """The dataset config that builds a recording: one ``carla-recording`` town per map of it and
    the rig of its calibration (the scenes stage adds the ``carla-recording`` ADMesh source for
    recorded towns; simulated towns keep drawing from ``asset_sources``). ``existing`` (a
    DatasetConfig) is extended: its towns of the same recording and map are replaced in place,
    others kept, new ones appended; its rig must be the recording's (StoreError otherwise)."""

    try:
        rec = discover(recording)
        calib = read_calib(rec.calib)
    except RecordingError as exc:
        raise StoreError(f"recording {recording}: {exc}") from None
    base = existing if existing is not None else DatasetConfig()
    rig = rig_from_calib(calib, base.scenes.rig)
    # one rig per dataset: a recording joins a dataset only when its calibration is the dataset's
    if existing is not None:
        check_rig(existing.scenes.rig, calib, f"recording {recording} (the dataset's scenes.rig)")
    root = str(Path(recording).resolve())
    maps = sorted({s.town for s in rec.sequences})
    new = {m: TownSpec(style="carla-recording", recording=root, map=m) for m in maps}
    towns = []
    for t in (existing.scenes.towns if existing is not None else ()):
        if t.style == "carla-recording" and t.recording == root and t.map in new:
            towns.append(new.pop(t.map))  # in place: town keys are positions
        else:
            towns.append(t)
    towns += list(new.values())
    scenes = base.scenes.model_copy(update={"towns": tuple(towns), "rig": rig})
    return base.model_copy(update={"scenes": scenes})


# ------------------------------------------------------------------ camera images of recorded frames

LIDAR_DIRS = ("lidar", "semantic_lidar")  # a recorded frame's scans, <dir>/<frame>.ply
IMAGE_DIRS = {"depth": ("depth_carla", "depth"), "semantic": ("semantics_carla", "semantics"), "rgb": ("rgb",)}


def recorded_frames(store, scenes: ScenesConfig, seq) -> list[dict] | None:
    """For a sequence of a recorded town: per frame (in order) its recorded frame number and the
    image files of each rig camera (``{"depth": path, "semantic": path, "rgb": path}``, the raw
    ``depth_carla``/``semantics_carla`` preferred over the release's rectified ``depth``/
    ``semantics``; files that do not exist left out) and its LiDAR scans (``{"lidar": path,
    "semantic_lidar": path}``, those that exist). None for simulated sequences, and for an edited
    copy of a recorded one (``scenes swap``): the recording shows the original actors, so the
    copy's maps and LiDAR are cast like a simulated sequence's."""

    if seq.parent_sequence_id is not None:
        return None
    spec = next((t for i, t in enumerate(scenes.towns) if town_key(i) == seq.town and t.style == "carla-recording"), None)
    if spec is None:
        return None
    try:
        rec = discover(spec.recording)
    except RecordingError as exc:
        raise StoreError(f"town {seq.town}: {exc}") from None
    name = seq.sequence_id[len(seq.town) + 1:]
    folder = next((s.path for s in rec.sequences if s.name == name), None)
    if folder is None:
        raise StoreError(f"sequence {seq.sequence_id}: {rec.root / name} is not in the recording any more")
    frames = sorted(ParquetTable(store, FrameRecord).load([seq.sequence_id]), key=lambda f: f.frame_index)
    out = []
    for f in frames:
        number = int(round(f.timestamp * seq.rate_hz))
        images = {}
        for cam in scenes.rig.cameras:
            sub = "image_" + cam.name.split("_")[-1]
            files = {}
            for kind, dirs in IMAGE_DIRS.items():
                for d in dirs:
                    path = folder / d / sub / f"{number:04d}.png"
                    if path.is_file():
                        files[kind] = str(path)
                        break
            images[cam.name] = files
        # the frame's LiDAR scans (the recording's ray_cast and ray_cast_semantic sensors)
        scans = {d: str(folder / d / f"{number:04d}.ply") for d in LIDAR_DIRS if (folder / d / f"{number:04d}.ply").is_file()}
        out.append({"number": number, "images": images, "lidar": scans})
    return out


def read_frame_lidar(files: dict) -> dict:
    """A recorded frame's LiDAR points (:func:`carlaocc.catalog.carla_recording.read_scans`) from
    its scan files (``{"lidar": path, "semantic_lidar": path}``, either may be absent);
    StoreError naming a malformed file."""
    try:
        return read_scans(files.get("lidar"), files.get("semantic_lidar"))
    except RecordingError as exc:
        raise StoreError(f"recorded LiDAR: {exc}") from None


def read_frame_images(files: dict, cam):
    """One camera's raw maps (``CameraMaps``: planar depth, 0 where the PNG saturates at 80 m;
    semantic ids, unknown colours 0) and RGB (None without a file) from its recorded PNGs.
    StoreError naming the camera when its depth or semantic image is missing or malformed."""

    missing = [k for k in ("depth", "semantic") if k not in files]
    if missing:
        raise StoreError(f"{cam.name}: the recording has no {' or '.join(missing)} image for this frame "
                         f"(depth_carla/ or depth/, semantics_carla/ or semantics/)")  # fmt: skip
    try:
        depth = decode_depth(np.asarray(Image.open(files["depth"])))
        semantic, _ = decode_semantics(np.asarray(Image.open(files["semantic"]).convert("RGB")))
        rgb = np.asarray(Image.open(files["rgb"]).convert("RGB")) if "rgb" in files else None
    except (OSError, RecordingError) as exc:
        raise StoreError(f"{cam.name}: unreadable recorded image ({exc})") from None
    shape = (cam.height, cam.width)
    for what, a in (("depth", depth), ("semantic", semantic), ("rgb", rgb)):
        if a is not None and a.shape[:2] != shape:
            raise StoreError(f"{files[what]}: {a.shape[1]}x{a.shape[0]} px, the camera is {cam.width}x{cam.height}")
    depth = np.where(depth >= np.float32(DEPTH_RANGE), np.float32(0.0), depth)  # saturated: nothing within range
    return CameraMaps(depth, semantic, None), rgb
