"""The ego sensor rig as config: cameras and LiDAR, with intrinsics and extrinsics derived.

Positions are given as in the published CarlaOcc configuration, in CARLA's frame (x forward,
y right, z up, metres; yaw in degrees, positive turning right), relative to the ego vehicle's
origin on the ground. The conversion to our right-handed frame (x forward, y left, z up; yaw
positive turning left) happens once, in :meth:`SensorPlacement.sensor_to_ego`.

Camera intrinsics come from the image size and the horizontal field of view (square pixels,
principal point at the image centre): ``fx = fy = width / (2 tan(hfov / 2))``. Camera extrinsics
map the OpenCV optical frame (z forward, x right, y down) into the ego frame.

Pure Python (math only): these are contracts, shared by scenes, sensors and exports.
"""

from __future__ import annotations

import math

from pydantic import BaseModel, ConfigDict, Field, model_validator

Matrix = list[list[float]]


def _matmul(a: Matrix, b: Matrix) -> Matrix:
    return [[sum(a[i][k] * b[k][j] for k in range(len(b))) for j in range(len(b[0]))] for i in range(len(a))]


class SensorPlacement(BaseModel):
    """Where a sensor sits on the ego vehicle, in CARLA's frame as published."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: str
    x: float = 0.0  # m, forward
    y: float = 0.0  # m, right (CARLA)
    z: float = 0.0  # m, up, above the ground
    yaw_deg: float = 0.0  # degrees, positive to the right (CARLA)

    def sensor_to_ego(self) -> Matrix:
        """4x4 pose of the sensor frame (x forward, y left, z up) in the ego frame: CARLA's y and
        yaw change sign here, once."""
        yaw = -math.radians(self.yaw_deg)
        c, s = math.cos(yaw), math.sin(yaw)
        return [[c, -s, 0.0, self.x], [s, c, 0.0, -self.y], [0.0, 0.0, 1.0, self.z], [0.0, 0.0, 0.0, 1.0]]


# OpenCV optical axes (x right, y down, z forward) expressed in the sensor frame (x fwd, y left, z up)
_OPTICAL_TO_SENSOR: Matrix = [[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]


class CameraSpec(SensorPlacement):
    """A pinhole camera: image size and horizontal field of view; intrinsics derived."""

    width: int = Field(1408, ge=1, le=16384)
    height: int = Field(376, ge=1, le=16384)
    hfov_deg: float = Field(103.744808, gt=0.0, lt=180.0)

    @property
    def focal_px(self) -> float:
        """Focal length in pixels, ``width / (2 tan(hfov / 2))``."""
        return self.width / (2.0 * math.tan(math.radians(self.hfov_deg) / 2.0))

    @property
    def intrinsics(self) -> Matrix:
        """3x3 K: square pixels, principal point at the image centre."""
        f = self.focal_px
        return [[f, 0.0, self.width / 2.0], [0.0, f, self.height / 2.0], [0.0, 0.0, 1.0]]

    @property
    def vfov_deg(self) -> float:
        """Vertical field of view implied by the size and the horizontal one."""
        return math.degrees(2.0 * math.atan(self.height / (2.0 * self.focal_px)))

    def camera_to_ego(self) -> Matrix:
        """4x4 pose of the OpenCV optical frame (z forward, x right, y down) in the ego frame."""
        return _matmul(self.sensor_to_ego(), _OPTICAL_TO_SENSOR)


class LidarSpec(SensorPlacement):
    """A spinning multi-beam LiDAR (CARLA's ray-cast sensor model)."""

    name: str = "lidar"
    z: float = 1.73
    channels: int = Field(32, ge=1, le=512)
    range_m: float = Field(80.0, gt=0.0)
    upper_fov_deg: float = Field(10.0, ge=-90.0, le=90.0)
    lower_fov_deg: float = Field(-30.0, ge=-90.0, le=90.0)
    rate_hz: float = Field(20.0, gt=0.0)
    points_per_second: int = Field(250_000, ge=1)

    @model_validator(mode="after")
    def _fov_ordered(self) -> LidarSpec:
        if self.lower_fov_deg >= self.upper_fov_deg:
            raise ValueError(f"lidar lower_fov_deg {self.lower_fov_deg} must be below upper_fov_deg {self.upper_fov_deg}")
        return self

    @property
    def beam_elevations_deg(self) -> list[float]:
        """Elevation of each channel, evenly spaced from the upper to the lower limit."""
        if self.channels == 1:
            return [self.upper_fov_deg]
        step = (self.upper_fov_deg - self.lower_fov_deg) / (self.channels - 1)
        return [self.upper_fov_deg - i * step for i in range(self.channels)]

    @property
    def points_per_frame(self) -> int:
        return int(round(self.points_per_second / self.rate_hz))


def _reference_cameras() -> tuple[CameraSpec, ...]:
    # docs/architecture.md "Reference rig": front pair, side pair, rear pair at 1.55 m
    table = [("camera_00", 0.8, -0.3, 0.0), ("camera_01", 0.8, 0.3, 0.0), ("camera_02", 0.0, -0.46, -90.0),
             ("camera_03", 0.0, 0.46, 90.0), ("camera_04", -0.8, -0.3, 180.0), ("camera_05", -0.8, 0.3, 180.0)]
    return tuple(CameraSpec(name=n, x=x, y=y, z=1.55, yaw_deg=yaw) for n, x, y, yaw in table)


class RigConfig(BaseModel):
    """The ego rig: cameras and one LiDAR (the reference CarlaOcc rig by default)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    cameras: tuple[CameraSpec, ...] = Field(default_factory=_reference_cameras)
    lidar: LidarSpec = LidarSpec()

    @model_validator(mode="after")
    def _unique_names(self) -> RigConfig:
        names = [c.name for c in self.cameras] + [self.lidar.name]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"sensor names must be unique, repeated: {', '.join(dup)}")
        return self
