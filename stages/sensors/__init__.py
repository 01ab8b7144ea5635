"""Sensors stage compute: ray-cast camera maps and LiDAR, the simulator artifact model and the
instance-guided rectification (paper, section 3.2 and its appendix)."""

from carlaocc.stages.sensors.artifacts import unlabelled_meshes
from carlaocc.stages.sensors.frame import (CameraFrame, CameraStats, SensorFrame, camera_poses, rectify_cameras,
                                  recorded_stats, simulate_frame)
from carlaocc.stages.sensors.normals import depth_normals, to_float16
from carlaocc.stages.sensors.raycast import (SKY, UNLABELLED, CameraMaps, RayScene, camera_ray_bundle, covered_pixels, lidar_scan,
                                    render_camera)
from carlaocc.stages.sensors.rectify import Rectification, compact_mesh, rectify

__all__ = [
    "SKY", "UNLABELLED", "CameraFrame", "CameraMaps", "CameraStats", "RayScene", "Rectification", "SensorFrame",
    "camera_poses", "camera_ray_bundle", "compact_mesh", "covered_pixels", "depth_normals", "lidar_scan", "recorded_stats",
    "rectify", "rectify_cameras", "render_camera", "simulate_frame", "to_float16", "unlabelled_meshes",
]
