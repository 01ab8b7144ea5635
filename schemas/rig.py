"""The ego sensor rig as config: cameras and LiDAR, with intrinsics and extrinsics derived.

Positions are given as in the published CarlaOcc configuration, in CARLA's frame (x forward,
y right, z up, metres; yaw in degrees, positive turning right), relative to the ego vehicle's
origin on the ground. The conversion to our right-handed frame (x forward, y left, z up; yaw
positive turning left) happens once, in :meth:`SensorPlacement.sensor_to_ego`.

Camera intrinsics come from the image size and the horizontal field of view (square pixels,
principal point at the image centre): ``fx = fy = width / (2 tan(hfov / 2))``. Camera extrinsics
map the OpenCV optical frame (z forward, x right, y down) into the ego frame.

In the dataset's frame (:meth:`SensorPlacement.ego_position`, :attr:`SensorPlacement.ego_yaw_deg`)
a sensor is named by the direction it faces (:func:`facing`: front, front-left, left...) and two
cameras with the same height and heading side by side form a stereo pair (:func:`stereo_pairs`:
``camera_00``/``camera_01`` at the front, ``camera_04``/``camera_05`` at the rear of the reference
rig); :func:`rig_lines` prints a rig that way (``carlaocc config``, docs/architecture.md
"Reference rig").

Pure Python (math only): these are contracts, shared by scenes, sensors and exports.
"""

from __future__ import annotations

import math

from pydantic import BaseModel, ConfigDict, Field, model_validator

Matrix = list[list[float]]

# the eight directions a sensor can face, counter-clockwise from ego +x in 45-degree sectors
_DIRECTIONS = ("front", "front-left", "left", "rear-left", "rear", "rear-right", "right", "front-right")


def facing(yaw_deg: float) -> str:
    """The direction, in words, of a heading ``yaw_deg`` in the ego frame (degrees, 0 = +x forward,
    positive turning left towards +y): the nearest of front, front-left, left, rear-left, rear,
    rear-right, right, front-right (sectors of 45 degrees centred on them)."""
    # nearest multiple of 45 degrees, wrapped to 0..7
    return _DIRECTIONS[int(math.floor((yaw_deg % 360.0) / 45.0 + 0.5)) % 8]


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

    def ego_position(self) -> tuple[float, float, float]:
        """(x forward, y left, z up) of the sensor in the ego frame, metres (CARLA's y negated)."""
        return (self.x, -self.y if self.y else 0.0, self.z)

    @property
    def ego_yaw_deg(self) -> float:
        """Heading in the ego frame, degrees in (-180, 180], positive turning left (CARLA's yaw
        negated)."""
        yaw = -self.yaw_deg % 360.0
        return yaw - 360.0 if yaw > 180.0 else yaw + 0.0

    @property
    def direction(self) -> str:
        """The direction the sensor faces, in words (:func:`facing`)."""
        return facing(self.ego_yaw_deg)


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


def _pairs(items) -> list[tuple[str, str, float]]:
    """Stereo pairs among ``(name, (x, y, z) ego metres, ego yaw degrees, image key)`` items (see
    :func:`stereo_pairs`)."""
    pairs, used = [], set()
    for i, (an, (ax, ay, az), ayaw, akey) in enumerate(items):
        for bn, (bx, by, bz), byaw, bkey in items[i + 1 :]:
            if an in used or bn in used:
                continue
            dyaw = (ayaw - byaw + 180.0) % 360.0 - 180.0
            if abs(dyaw) > 1e-4 or abs(az - bz) > 1e-3 or akey != bkey:
                continue
            psi = math.radians(ayaw)
            # offset b - a along the heading (must vanish) and along the camera's left axis
            along = (bx - ax) * math.cos(psi) + (by - ay) * math.sin(psi)
            left = -(bx - ax) * math.sin(psi) + (by - ay) * math.cos(psi)
            if abs(along) > 1e-3 or abs(left) < 1e-3:
                continue
            pairs.append((bn, an, abs(left)) if left > 0 else (an, bn, abs(left)))
            used |= {an, bn}
    return pairs


def stereo_pairs(cameras) -> list[tuple[str, str, float]]:
    """``(left, right, baseline_m)`` of every stereo pair among ``cameras``: two cameras with the
    same heading, height and image size whose offset is perpendicular to their heading (within
    1 mm). ``left`` is the one on the left as seen looking along the pair's heading (for a pair
    facing the rear, the one on the ego's right side). Each camera is in at most one pair, taken in
    the cameras' order."""
    return _pairs([(c.name, c.ego_position(), c.ego_yaw_deg, (c.width, c.height, c.hfov_deg)) for c in cameras])


def _roles(names, directions, pairs) -> dict[str, str]:
    roles = dict(zip(names, directions))
    for left, right, _ in pairs:
        roles[left] += f", stereo left (with {right})"
        roles[right] += f", stereo right (with {left})"
    return roles


def camera_roles(cameras) -> dict[str, str]:
    """``name -> description`` of each camera: its direction in words and, for a camera of a stereo
    pair, its place in it, e.g. ``"front, stereo left (with camera_01)"``."""
    return _roles([c.name for c in cameras], [c.direction for c in cameras], stereo_pairs(cameras))


def pose_roles(poses: dict[str, Matrix]) -> dict[str, str]:
    """:func:`camera_roles` from cameras' poses instead of a rig: ``name -> 4x4`` pose of the
    camera's OpenCV optical frame (z forward) in the ego or LiDAR frame (x forward, y left, z
    up), e.g. a recorded frame's ``sensor_poses`` brought into its LiDAR frame. A camera's
    heading is its optical axis projected on the ground plane; a pair needs the same heading
    and height and an offset across it."""
    items = []
    for name, T in poses.items():
        yaw = math.degrees(math.atan2(T[1][2], T[0][2]))  # the optical z axis, seen from above
        items.append((name, (T[0][3], T[1][3], T[2][3]), yaw, None))
    return _roles([n for n, *_ in items], [facing(y) for _, _, y, _ in items], _pairs(items))


def rig_lines(rig: "RigConfig") -> list[str]:
    """The rig in the dataset's ego frame (x forward, y left, z up, metres; yaw positive turning
    left), one line a sensor with its direction in words, then its stereo pairs."""
    roles = camera_roles(rig.cameras)
    out = []
    for s in (*rig.cameras, rig.lidar):
        x, y, z = s.ego_position()
        what = roles.get(s.name, "spinning, on the ego's vertical axis" if not (x or y) else "spinning")
        extra = f"  {s.width}x{s.height} px, hfov {s.hfov_deg:g} deg" if isinstance(s, CameraSpec) else ""
        out.append(f"{s.name:<10} x {x:+.2f}  y {y:+.2f}  z {z:.2f}  yaw {s.ego_yaw_deg:+6.1f} deg  {what}{extra}")
    for left, right, base in stereo_pairs(rig.cameras):
        out.append(f"stereo pair {left} (left) / {right} (right): baseline {base:.2f} m")
    return out


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
