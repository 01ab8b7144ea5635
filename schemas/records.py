"""Persisted records: one pydantic model per Parquet table of the store.

Field types are kept to what maps one-to-one onto Arrow (str, int, float, bool, list[float],
list[int], optional scalars, datetime) so that ``carlaocc.catalog.parquet`` converts every model generically
and every model round-trips. Poses are 4x4 float64 matrices flattened row-major into 16 floats
("sensor-to-world" or "object-to-world"); lengths in metres, times in seconds, angles in radians.
"""

from __future__ import annotations

import math
from datetime import datetime
from typing import Annotated, ClassVar, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict


class Record(BaseModel):
    """Base of every persisted row: frozen, no unknown fields. ``TABLE`` names its store table.

    ``STORED_NAMES`` maps a field's name in code to its column name in the stored Parquet files
    where the two differ: ``voxel_size`` is stored as ``resolution`` (its name when the first
    datasets were written), so existing roots load and new files are byte-identical to theirs.
    ``carlaocc.catalog.parquet`` applies it at the file boundary only (Arrow tables in memory and
    the SQL views use the code names)."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    TABLE: ClassVar[str] = ""
    STORED_NAMES: ClassVar[dict[str, str]] = {"voxel_size": "resolution"}


def _check_pose(v: list[float]) -> list[float]:
    if len(v) != 16:
        raise ValueError(f"a pose is 16 floats (4x4 row-major), got {len(v)}")
    if not all(math.isfinite(x) for x in v):
        raise ValueError("a pose must be finite")
    return v


def _check_vec3(v: list[float]) -> list[float]:
    if len(v) != 3:
        raise ValueError(f"expected 3 components, got {len(v)}")
    if not all(math.isfinite(x) for x in v):
        raise ValueError("vector must be finite")
    return v


Pose = Annotated[list[float], AfterValidator(_check_pose)]  # 4x4 row-major, finite
Vec3 = Annotated[list[float], AfterValidator(_check_vec3)]  # 3 finite components


class AssetRecord(Record):
    """One ADMesh asset: a standardized mesh in the asset frame (+X forward, Z up, metres, origin
    at the bottom centre of its bounding box)."""

    TABLE: ClassVar[str] = "assets"
    asset_id: str
    source: str
    source_path: str
    licence: str
    category_id: int
    category: str
    subclass: str
    extent: Vec3  # bounding-box size x, y, z (m)
    vertex_count: int
    face_count: int  # triangles, after degenerate and duplicate faces are removed
    part_count: int
    transparent_part_count: int
    surface_area: float  # m^2
    volume: float | None  # m^3, watertight assets only
    watertight: bool  # every part closed and consistently wound
    # how the voxelizer fills the asset under ``auto`` (carlaocc.stages.voxelize.breakdown.asset_fill,
    # measured in the asset frame at fill_voxel_size); "" in rows written before these fields existed
    fill_method: str = ""  # "surface" (no part filled), "parity" (filled parts watertight), "winding" (some open)
    fill_voxel_size: float = 0.0  # m, the reference voxel edge: 0.05, or longest side / 256 when coarser
    fill_voxels: int = 0  # occupied voxels of the asset at fill_voxel_size (surface + filled)
    hole_fill_voxels: int = 0  # filled voxels reached only through holes (a flood fill would miss them)
    hole_fill_fraction: float = 0.0  # hole_fill_voxels / fill_voxels
    scale_applied: float = 1.0  # source units -> metres
    scale_rule: str = ""  # why that scale (declared units, inferred from a size range...)
    geometry_hash: str  # content hash of the standardized geometry (duplicates share it)
    aliases: list[str] = []  # source paths of duplicates stored once under this asset
    notes: str = ""  # what standardization changed (faces removed, winding repaired, turned...)
    mesh_path: str  # store-relative path of the standardized GLB
    texture_path: str = ""  # store-relative path of the parts' textures ("" when none has one)


class PartRecord(Record):
    """A sub-mesh of an asset, with its own material and semantic class."""

    TABLE: ClassVar[str] = "parts"
    asset_id: str
    part_index: int
    name: str
    material: str
    transparent: bool
    semantic_id: int
    face_count: int
    watertight: bool
    texture: str = ""  # texture reference (URI or path relative to the source), kept by reference
    # base colour RGBA 0-255 (the material's diffuse colour; parts written before the column: grey)
    color: list[int] = [200, 200, 200, 255]  # pydantic copies the default per instance


class QuarantineRecord(Record):
    """An input rejected by a batch stage, with the reason and a hint to fix it."""

    TABLE: ClassVar[str] = "quarantine"
    stage: str
    source: str
    source_path: str
    reason: str
    hint: str


class PlacementRecord(Record):
    """A static object of a town placed in the world frame (town's frame, metres)."""

    TABLE: ClassVar[str] = "placements"
    town: str
    placement_id: int
    name: str  # e.g. "road", "building_012"
    asset_id: str  # ADMesh asset id; town stuff meshes (road, sidewalk, ...) use "<town>/<name>"
    mesh_path: str  # store-relative GLB holding the geometry
    semantic_id: int
    instance_id: int  # 0 for stuff
    pose: Pose  # object-to-world, 4x4 row-major
    is_thing: bool  # taxonomy thing class (has an instance id) or stuff
    aabb_min: Vec3  # world-frame axis-aligned bounding box of the placed mesh, m
    aabb_max: Vec3


class TownRecord(Record):
    """One town: how it was made and the size of its road network."""

    TABLE: ClassVar[str] = "towns"
    town: str
    style: Literal["downtown", "suburb", "arterial", "opendrive", "carla-recording"]
    source: str  # the OpenDRIVE file of opendrive towns, the recording of recorded ones, "" for procedural ones
    seed: int
    road_length: float  # m of road centreline, each road once
    lane_count: int  # lanes of the traffic network (junction connectors included)
    junction_count: int
    walkway_length: float  # m of walkways (sidewalks and crosswalks)
    crosswalk_count: int
    placement_count: int
    bounds: list[float]  # xmin, ymin, xmax, ymax of the town ground, m
    # the label table its placements' instance ids follow (towns written before the column: the
    # first table, carlaocc-v1)
    label_table: str = "carlaocc-v1"


class SequenceRecord(Record):
    """One driving sequence of a town."""

    TABLE: ClassVar[str] = "sequences"
    sequence_id: str
    town: str
    seed: int
    frame_count: int
    rate_hz: float
    traffic_level: Literal["none", "low", "medium", "high"]
    ego_asset_id: str
    parent_sequence_id: str | None = None  # edited sequences (``scenes swap``): the original
    edit: str = ""  # what the edit changed, e.g. "swap Car seed=3"
    # key of the placements table the frames use: "" = the town's ("town=<town>"); an edit that
    # swaps static objects (buildings, props) writes its own copy ("sequence=<sequence_id>")
    placements: str = ""

    def placements_key(self) -> str:
        """The key of the placements table holding this sequence's static objects."""
        return self.placements or f"town={self.town}"


class FrameRecord(Record):
    """One frame of a sequence: the ego and LiDAR poses at its timestamp."""

    TABLE: ClassVar[str] = "frames"
    sequence_id: str
    frame_index: int
    timestamp: float  # s since the sequence start
    ego_pose: Pose  # ego-to-world
    lidar_pose: Pose  # lidar-to-world


class ActorStateRecord(Record):
    """A dynamic actor's state in one frame: pose, 3D box and velocity in the world frame."""

    TABLE: ClassVar[str] = "actors"
    sequence_id: str
    frame_index: int
    instance_id: int
    asset_id: str
    semantic_id: int
    pose: Pose  # actor-to-world (asset frame to world)
    box_center: Vec3  # world frame, m
    box_size: Vec3  # length, width, height, m
    yaw: float  # rad, about world z
    # rad: pitch about the body's y axis (positive: nose down) and roll about its x axis
    # (positive: right side down); pose rotation = Rz(yaw) Ry(pitch) Rx(roll) (ROS REP 103)
    pitch: float = 0.0
    roll: float = 0.0
    velocity: Vec3  # world frame, m/s
    angular_velocity: Vec3  # world frame, rad/s
    gait_phase: float | None = None  # walkers only: simulated phase of the gait cycle, [0, 1)
    phase_index: int | None = None  # walkers only: canonical phase matched by the Skeletal Motion Analyzer
    # uniform scale of the asset about its origin, applied before ``pose`` (which stays rigid): 1 but
    # for recorded walkers, whose walk cycle is scaled to their recorded height
    scale: float = 1.0


class EgoStateRecord(Record):
    """The ego's motion in one frame of a recorded sequence, as the recording holds it (CARLA's
    own values in ``traffic_info``, not differences of poses): world frame (right-handed, x
    forward, y left, z up). Simulated sequences have none (their ego follows its poses)."""

    TABLE: ClassVar[str] = "ego_states"
    sequence_id: str
    frame_index: int
    velocity: Vec3  # m/s, world frame, at the ego origin
    acceleration: Vec3  # m/s2, world frame


class SkeletonRecord(Record):
    """One joint of a walker in one frame: the gait cycle's bones as posed for the frame (the
    canonical phase the Skeletal Motion Analyzer matched, or the rest pose), in the world frame
    and in the frame's LiDAR frame (metres)."""

    TABLE: ClassVar[str] = "skeletons"
    sequence_id: str
    frame_index: int
    instance_id: int
    asset_id: str
    joint_index: int  # position in the skeleton's joint list
    joint: str  # pelvis, l_hip, l_knee, l_ankle, r_hip, r_knee, r_ankle, l_shoulder, l_hand, ...
    world: Vec3
    lidar: Vec3


class SensorPoseRecord(Record):
    """A rig sensor's pose in one frame (cameras: OpenCV camera frame, x right, y down, z forward;
    LiDAR: x forward, y left, z up)."""

    TABLE: ClassVar[str] = "sensor_poses"
    sequence_id: str
    frame_index: int
    sensor: str
    pose: Pose  # sensor-to-world, 4x4 row-major


class LidarAgreementRecord(Record):
    """How a recorded frame's LiDAR scan agrees with our scene from the same pose: each recorded
    point's beam (its direction from the sensor) cast through the frame's scene mesh, our range
    against the recorded one. Static points are those neither scene nor recording labels a road
    user on (:func:`carlaocc.schemas.taxonomy.dynamic_ids`); a beam our scene does not hit within
    range counts as a disagreement."""

    TABLE: ClassVar[str] = "lidar_agreement"
    sequence_id: str
    frame_index: int
    points: int  # recorded points (both scans of the frame: lidar/ and semantic_lidar/)
    static_points: int
    missed: int  # static points whose beam hits nothing of our scene within the recorded range + tolerance
    median_m: float  # median |our range - recorded range| over static points, m (-1: no static point)
    p95_m: float  # its 95th percentile, m (inf when over 5 % of our beams miss; -1: no static point)
    within: float  # fraction of static points whose ranges agree within `tolerance_m`
    tolerance_m: float


class RectificationRecord(Record):
    """What the instance-guided rectification did to one camera image (pixel counts) and, for
    ray-cast frames, how far its output is from the clean ray-cast maps (-1: not measured, the
    raw maps were recorded)."""

    TABLE: ClassVar[str] = "rectification"
    sequence_id: str
    frame_index: int
    camera: str
    source: Literal["raycast", "recorded"]
    pixels: int
    transparency: int  # Omega_t: raw depth >= epsilon behind the rectified depth
    omission: int  # Omega_s: raw label empty
    relabelled: int  # semantic or instance label changed by rectification
    depth_changed: int
    raw_semantic_wrong: int  # raw semantic != clean
    semantic_mismatch: int  # rectified semantic != clean
    instance_mismatch: int
    depth_mismatch: int  # |rectified - clean| > 1 mm


class QualityRecord(Record):
    """A dataset-quality score over one frame (frame_index set) or one sequence (frame_index None).

    ``metric`` "spatial_continuity": ``value = 1 - isolated / occupied``; numerator = occupied -
    isolated (connected voxels), denominator = occupied. ``metric`` "temporal_consistency": one row
    per frame pair (t, t+1) with ``frame_index = t`` and one per sequence; ``value = numerator /
    denominator`` = intersection / union voxels summed over classes (within the valid mask M_t);
    occupied and isolated are 0. Sums of numerators over denominators aggregate any set of rows.
    """

    TABLE: ClassVar[str] = "quality"
    sequence_id: str
    voxel_size: float  # metres; stored as the column 'resolution' (Record.STORED_NAMES)
    frame_index: int | None
    metric: str
    value: float
    occupied: int = 0  # spatial_continuity only
    isolated: int = 0  # spatial_continuity only
    numerator: int | None = None  # None in rows written before these fields existed
    denominator: int | None = None
    # sequence rows: the lowest frame (pair) value and its frame index (None on frame rows)
    worst_value: float | None = None
    worst_frame: int | None = None


class ClassQualityRecord(Record):
    """Per-class occupied and isolated voxel counts behind the spatial continuity score."""

    TABLE: ClassVar[str] = "quality_classes"
    sequence_id: str
    voxel_size: float  # metres; stored as the column 'resolution' (Record.STORED_NAMES)
    frame_index: int
    semantic_id: int
    occupied: int
    isolated: int


class FrameStatisticsRecord(Record):
    """Voxels and instances of one class in one frame at one voxel size (the quality stage's
    per-frame statistics, summed per sequence by the aggregate stage into
    :class:`ClassStatisticsRecord`): ``instance_ids`` are the distinct nonzero instance ids among
    the class's voxels in the frame."""

    TABLE: ClassVar[str] = "statistics_frames"
    sequence_id: str
    voxel_size: float  # metres; stored as the column 'resolution' (Record.STORED_NAMES)
    frame_index: int
    semantic_id: int
    voxels: int
    instance_ids: list[int]


class ClassStatisticsRecord(Record):
    """Voxels and instances of one class in one sequence at one voxel size (the aggregate stage's
    statistics: voxels summed over the sequence's frames; instances are distinct (instance id,
    class) pairs among its voxels, of which ``moving_instances`` are dynamic actors)."""

    TABLE: ClassVar[str] = "statistics_classes"
    sequence_id: str
    voxel_size: float  # metres; stored as the column 'resolution' (Record.STORED_NAMES)
    semantic_id: int
    frames: int
    voxels: int
    instances: int
    moving_instances: int


class AssetStatisticsRecord(Record):
    """ADMesh assets of one category from one source (duplicates counted once)."""

    TABLE: ClassVar[str] = "statistics_assets"
    source: str
    category_id: int
    category: str
    assets: int


class RunRecord(Record):
    """Lineage of one (stage, partition) task of one run."""

    TABLE: ClassVar[str] = "runs"
    run_id: str
    stage: str
    partition: str
    code_version: str
    config_hash: str
    cache_key: str
    input_fingerprints: str  # JSON object: store path -> fingerprint
    output_fingerprints: str  # JSON object: store path -> fingerprint
    # "retired": the partition no longer exists and its outputs were removed (e.g. the quality
    # stage's runs of frames after frames_per_task changed); never planned, never verified
    status: Literal["completed", "failed", "retired"]
    started_at: datetime
    ended_at: datetime
    host: str
    error: str = ""
    # JSON objects: output key / input file -> stat signature (carlaocc.catalog.signatures) when
    # recorded; a recorded fingerprint is trusted while its signature is unchanged
    output_signatures: str = ""
    input_signatures: str = ""


PERSISTED: tuple[type[Record], ...] = (
    AssetRecord,
    PartRecord,
    QuarantineRecord,
    PlacementRecord,
    TownRecord,
    SequenceRecord,
    FrameRecord,
    SensorPoseRecord,
    ActorStateRecord,
    SkeletonRecord,
    EgoStateRecord,
    LidarAgreementRecord,
    QualityRecord,
    ClassQualityRecord,
    RectificationRecord,
    FrameStatisticsRecord,
    ClassStatisticsRecord,
    AssetStatisticsRecord,
    RunRecord,
)
