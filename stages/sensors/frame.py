"""One frame of the rig's sensors, from the frame's panoptic scene (LiDAR frame, metres).

Two paths share :func:`rectify_cameras`:

* **raycast** (:func:`simulate_frame`): cast the whole scene for clean maps, derive the raw maps
  a simulator would deliver (:mod:`carlaocc.stages.sensors.artifacts`), rectify those, compute normals
  from the rectified depth, cast the LiDAR, and measure how far the rectified maps are from the
  clean ones (:class:`CameraStats`);
* **recorded**: the caller reads raw maps a recorder wrote and calls :func:`rectify_cameras`
  with the frame's scene.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from carlaocc.schemas.configs import SensorsConfig
from carlaocc.schemas.meshes import SceneMesh
from carlaocc.schemas.rig import CameraSpec, RigConfig
from carlaocc.stages.scenes.assembly import flatten
from carlaocc.stages.sensors.artifacts import unlabelled_meshes
from carlaocc.stages.sensors.normals import depth_normals
from carlaocc.stages.sensors.raycast import CameraMaps, RayScene, lidar_scan, rig_camera_rays, render_camera
from carlaocc.stages.sensors.rectify import Rectification, compact_mesh, rectify
from carlaocc.stages.sensors.shading import base_colours, face_normals, render_rgb, sun_direction
from carlaocc.stages.voxelize.visibility import sensor_to_lidar


@dataclass(frozen=True)
class CameraStats:
    """What rectification did to one image, and (raycast path) how it compares with the clean
    ray-cast maps. Pixel counts."""

    camera: str
    pixels: int
    transparency: int  # Omega_t
    omission: int  # Omega_s
    relabelled: int  # pixels whose semantic or instance label rectification changed
    depth_changed: int  # pixels whose depth rectification changed
    raw_semantic_wrong: int = -1  # raw semantic != clean (-1: no clean maps, recorded path)
    semantic_mismatch: int = -1  # rectified semantic != clean
    instance_mismatch: int = -1  # rectified instance != clean
    depth_mismatch: int = -1  # |rectified depth - clean| > 1 mm


@dataclass(frozen=True)
class CameraFrame:
    """One camera's outputs: rectified maps + normals, the raw maps, the repair regions."""

    camera: CameraSpec
    rectification: Rectification
    normal: np.ndarray  # (H, W, 3) float32, OpenCV camera frame
    raw: CameraMaps
    stats: CameraStats
    rgb: np.ndarray | None = None  # (H, W, 3) uint8, shaded from the scene (raycast path, cfg.rgb)

    @property
    def maps(self) -> CameraMaps:
        return self.rectification.maps


@dataclass(frozen=True)
class SensorFrame:
    cameras: dict[str, CameraFrame]
    lidar: dict[str, np.ndarray] | None


def camera_poses(rig: RigConfig) -> dict[str, np.ndarray]:
    """4x4 pose of each camera's OpenCV optical frame in the LiDAR frame."""

    return sensor_to_lidar(rig)


def rectify_cameras(scene: Sequence[SceneMesh], rig: RigConfig, cfg: SensorsConfig,
                    raw: Mapping[str, CameraMaps], nthreads: int = 0) -> dict[str, tuple[Rectification, np.ndarray]]:
    """Rectify the raw maps of each camera in ``raw`` (by camera name) with the frame's compact
    mesh (transparent parts and unlabelled assets, per ``cfg.artifacts``), and compute the
    normals of the rectified depth: camera name -> (rectification, normals)."""
    cams = {c.name: c for c in rig.cameras}
    poses = camera_poses(rig)
    # 1. the compact mesh M, built once for all cameras
    flags = unlabelled_meshes(scene, cfg.artifacts)
    m = compact_mesh(scene, flags)
    compact = RayScene(m, nthreads=nthreads)
    out = {}
    for name, maps in raw.items():
        if name not in cams:
            raise ValueError(f"raw maps of {name!r}, which is not a camera of the rig ({', '.join(cams)})")
        cam = cams[name]
        if maps.depth.shape != (cam.height, cam.width):
            raise ValueError(f"{name}: raw maps are {maps.depth.shape}, the camera is {cam.height}x{cam.width}")
        # 2. D_rc, S_rc, I_rc from M; 3. the paper's fusion; 4. normals of the rectified depth
        cast, _ = render_camera(compact, cam, poses[name], nthreads=nthreads)  # rasterized: M's triangles only
        rect = rectify(maps, cast, cfg.epsilon)
        out[name] = (rect, depth_normals(rect.maps.depth, cam.intrinsics, cfg.normals))
    return out


def _stats(name: str, rect: Rectification, raw: CameraMaps, clean: CameraMaps | None) -> CameraStats:
    m = rect.maps
    relabelled = (m.semantic != raw.semantic)
    if m.instance is not None and raw.instance is not None:
        relabelled |= m.instance != raw.instance
    base = dict(camera=name, pixels=int(m.depth.size), transparency=int(rect.transparency.sum()),
                omission=int(rect.omission.sum()), relabelled=int(relabelled.sum()),
                depth_changed=int(rect.depth_changed.sum()))
    if clean is None:
        return CameraStats(**base)
    inst = -1 if m.instance is None else int((m.instance != clean.instance).sum())
    return CameraStats(**base, raw_semantic_wrong=int((raw.semantic != clean.semantic).sum()),
                       semantic_mismatch=int((m.semantic != clean.semantic).sum()), instance_mismatch=inst,
                       depth_mismatch=int((np.abs(m.depth - clean.depth) > 1e-3).sum()))


def simulate_frame(scene: Sequence[SceneMesh], rig: RigConfig, cfg: SensorsConfig,
                   nthreads: int = 0, world_to_scene: np.ndarray | None = None) -> SensorFrame:
    """The raycast path for one frame: clean and raw maps of the selected cameras, rectified
    maps and normals, RGB (when ``cfg.rgb``: the sun of ``cfg`` in the world, turned into the
    scene frame by ``world_to_scene``, 3x3 or 4x4; identity when None), LiDAR points (when
    ``cfg.lidar``), per-camera statistics."""
    poses = camera_poses(rig)
    flags = unlabelled_meshes(scene, cfg.artifacts)
    mesh = flatten(scene)
    # per-triangle artifact flags: unlabelled assets; translucency only when the model has it
    counts = np.array([len(m.faces) for m in scene], dtype=np.int64)
    full = RayScene(mesh, unlabelled=np.repeat(flags, counts), nthreads=nthreads)
    cams = cfg.selected_cameras(rig)
    clean, raw = {}, {}
    for cam in cams:
        clean[cam.name], raw[cam.name] = render_camera(full, cam, poses[cam.name], raw=True,
                                                         see_through=cfg.artifacts.transparent, nthreads=nthreads)
    rectified = rectify_cameras(scene, rig, cfg, raw, nthreads=nthreads)
    rgb = {}
    if cfg.rgb:
        R = np.eye(3) if world_to_scene is None else np.asarray(world_to_scene, dtype=np.float64)[:3, :3]
        sun, up = sun_direction(cfg.sun_azimuth_deg, cfg.sun_elevation_deg, R), R @ np.array([0.0, 0.0, 1.0])
        # per triangle, once for the frame's cameras: normals and base colours
        normals = face_normals(mesh.vertices, mesh.faces)
        base = base_colours(mesh.color, mesh.semantic).astype(np.float32)
        for cam in cams:
            origin, dirs = rig_camera_rays(cam, poses[cam.name])  # cached per rig camera
            rgb[cam.name] = render_rgb(full, origin, dirs, clean[cam.name], raw[cam.name], sun, up, cfg.ambient,
                                       normals, base, nthreads)
    out = {}
    for cam in cams:
        rect, normal = rectified[cam.name]
        out[cam.name] = CameraFrame(cam, rect, normal, raw[cam.name],
                                    _stats(cam.name, rect, raw[cam.name], clean[cam.name]), rgb.get(cam.name))
    lidar = lidar_scan(full, rig.lidar, nthreads=nthreads) if cfg.lidar else None
    return SensorFrame(out, lidar)


def recorded_stats(name: str, rect: Rectification, raw: CameraMaps) -> CameraStats:
    """Statistics of a rectification of recorded maps (no clean maps to compare with)."""
    return _stats(name, rect, raw, None)
