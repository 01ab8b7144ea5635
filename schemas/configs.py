"""Frozen stage configurations and the dataset config file that holds them.

A stage's config hash is part of its cache key: change a field and that stage (and what depends on
it) re-runs. Unknown keys are refused everywhere (``extra="forbid"``) so a typo in a config file is
an error naming the key, not a silently ignored setting. Angles are degrees only here, in
user-facing config; the code converts them to radians.
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from carlaocc.schemas import taxonomy
from carlaocc.schemas.grid import DEFAULT_REGION_MAX, DEFAULT_REGION_MIN, GridSpec, voxel_size_key
from carlaocc.schemas.rig import RigConfig
from carlaocc.schemas.taxonomy import DEFAULT_LABEL_TABLE, LabelTableName

_SET_BY_PIPELINE = "the label table (which classes carry instance ids); the pipeline sets it from the dataset's taxonomy"


class StageConfig(BaseModel):
    """Base of every stage config: frozen, no unknown keys."""

    model_config = ConfigDict(frozen=True, extra="forbid")


class IngestConfig(StageConfig):
    """ADMesh ingestion from the built-in procedural source."""

    seed: int = 7
    variants_per_subclass: int = Field(3, ge=1, le=50, description="procedural variants per sub-class")


class SourceIngestConfig(StageConfig):
    """Ingestion of one external mesh source (``carlaocc ingest KIND PATH``)."""

    kind: Literal["folder", "shapenet", "buildingnet", "meshfleet", "carla", "carla-recording"]
    root: str = Field(description="the source's root directory (absolute)")
    category_map: str | None = Field(None, description="folder sources: CSV glob,category,subclass[,length_m]")


TrafficLevelName = Literal["none", "low", "medium", "high"]
TownStyle = Literal["downtown", "suburb", "arterial", "opendrive", "carla-recording"]


class TownSpec(StageConfig):
    """One town of the dataset: a procedural style built from the seed, or an OpenDRIVE file with
    buildings and vegetation placed procedurally beside its network, and the traffic sequences
    driven through it; or a CARLA recording (``carla-recording``: the town's exported meshes and
    the recorded sequences, nothing simulated; ``traffic_levels`` and the layout fields are ignored).

    The layout fields (``blocks`` ... ``sidewalk_width``) override the style's defaults for the
    procedural styles and are ignored for OpenDRIVE towns.
    """

    style: TownStyle = "downtown"
    opendrive: str | None = Field(
        None, description="opendrive style: path of the .xodr file, or builtin:<name> for a file shipped with carlaocc")
    recording: str | None = Field(
        None, description="carla-recording style: the recording's root (CarlaOcc release layout: calib/, SceneMeshes/, "
        "<Town>_Opt_Seq<NN>/)")
    map: str | None = Field(
        None, description="carla-recording style: which town of the recording (e.g. Town01_Opt; default: its only one)")
    traffic_levels: tuple[TrafficLevelName, ...] = Field(("medium",), min_length=1)
    sequences_per_level: int | dict[TrafficLevelName, int] = Field(
        1, description="sequences per traffic level: one number for every level, or a number per level "
        "(e.g. {none: 1, low: 3, medium: 3, high: 6}, the CarlaOcc collection's plan)")

    def sequences_of(self, level: str) -> int:
        """How many sequences of ``level`` the town drives."""
        n = self.sequences_per_level
        return int(n) if isinstance(n, int) else int(n.get(level, 0))
    blocks: int | None = Field(None, ge=1, le=12, description="city blocks per side of the road grid")
    block_size: float | None = Field(None, gt=10.0, le=500.0, description="block edge, m, kerb to kerb")
    road_width: float | None = Field(None, gt=3.0, le=40.0, description="carriageway width, m")
    sidewalk_width: float | None = Field(None, gt=0.5, le=10.0, description="sidewalk width, m")

    @model_validator(mode="after")
    def _opendrive_file(self) -> TownSpec:
        if (self.style == "opendrive") != (self.opendrive is not None):
            raise ValueError("a town has an opendrive file exactly when its style is 'opendrive'")
        if (self.style == "carla-recording") != (self.recording is not None):
            raise ValueError("a town has a recording exactly when its style is 'carla-recording'")
        if self.map is not None and self.style != "carla-recording":
            raise ValueError("map names a town of a recording: only for the 'carla-recording' style")
        if len(set(self.traffic_levels)) != len(self.traffic_levels):
            raise ValueError(f"traffic_levels repeats a level: {list(self.traffic_levels)}")
        counts = ([self.sequences_per_level] if isinstance(self.sequences_per_level, int)
                  else list(self.sequences_per_level.values()))  # fmt: skip
        if any(not 1 <= c <= 64 for c in counts):
            raise ValueError(f"sequences_per_level must be 1..64 per level, got {self.sequences_per_level}")
        if isinstance(self.sequences_per_level, dict):
            extra = sorted(set(self.sequences_per_level) - set(self.traffic_levels))
            missing = sorted(set(self.traffic_levels) - set(self.sequences_per_level))
            if extra or missing:
                raise ValueError(f"sequences_per_level names levels {sorted(self.sequences_per_level)}, "
                                 f"traffic_levels are {list(self.traffic_levels)}: they must be the same")
        return self


def _default_towns() -> tuple[TownSpec, ...]:
    return (
        TownSpec(style="downtown", traffic_levels=("low", "high")),
        TownSpec(style="opendrive", opendrive="builtin:crossroads.xodr", traffic_levels=("medium",)),
    )


class ScenesConfig(StageConfig):
    """Towns, the traffic sequences driven through them and the ego rig."""

    seed: int = 11
    towns: tuple[TownSpec, ...] = Field(default_factory=_default_towns, min_length=1, max_length=16)
    curb_height: float = Field(0.15, ge=0.0, le=0.5, description="kerb height above the road, m")
    frame_count: int = Field(20, ge=2, le=10_000)
    rate_hz: float = Field(20.0, gt=0.0, le=100.0)
    ego_speed: float = Field(8.0, ge=0.0, le=40.0, description="ego target speed, m/s")
    actor_range: float = Field(80.0, gt=0.0, le=1000.0, description="actors within this many m of the ego are recorded")
    rig: RigConfig = Field(default_factory=RigConfig)
    taxonomy: LabelTableName | None = Field(None, description=_SET_BY_PIPELINE)
    asset_sources: tuple[str, ...] = Field(
        ("procedural",), min_length=1,
        description="ADMesh sources whose assets towns and traffic draw from (e.g. procedural, folder)")


# Named occupancy regions (``voxelize.region``), boxes in the ego frame (x forward, y left, z
# up, m): ``occ3d`` is the Occ3D-nuScenes grid, so an export onto it covers every voxel.
NAMED_REGIONS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "occ3d": ((-40.0, -40.0, -1.0), (40.0, 40.0, 5.4)),
}


def named_region(name: str, lidar_to_ego) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """``(region_min, region_max)`` in the LiDAR frame of the box :data:`NAMED_REGIONS` ``[name]``
    (ego frame): the axis-aligned bounds of its corners seen from the LiDAR mounted at
    ``lidar_to_ego`` (4x4), rounded to micrometres (the default rig: z 1.73 m, so Occ3D's box is
    x, y [-40, 40], z [-2.73, 3.67], whole voxels at 0.05 .. 0.4 m)."""
    lo, hi = NAMED_REGIONS[name]
    m = [list(map(float, row)) for row in lidar_to_ego]
    r = [row[:3] for row in m[:3]]
    t = [m[i][3] for i in range(3)]
    # ego -> LiDAR: R^T (p - t)
    corners = [(x, y, z) for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
    local = [[sum(r[k][i] * (c[k] - t[k]) for k in range(3)) for i in range(3)] for c in corners]
    mins = tuple(round(min(p[i] for p in local), 6) + 0.0 for i in range(3))
    maxs = tuple(round(max(p[i] for p in local), 6) + 0.0 for i in range(3))
    return mins, maxs  # type: ignore[return-value]


class VoxelizeConfig(StageConfig):
    """Panoptic voxelization of every frame's scene mesh."""

    region_min: tuple[float, float, float] = DEFAULT_REGION_MIN
    region_max: tuple[float, float, float] = DEFAULT_REGION_MAX
    fill: Literal["auto", "surface", "solid"] = Field(
        "auto", description="auto: fill the volumetric classes (vehicles, people, buildings, walls, poles, "
        "traffic lights and signs, props, rocks, tree trunks), leave roads, terrain, fences, guard rails and "
        "foliage surfaces; solid: fill every mesh; surface: fill nothing. Watertight meshes are filled by column "
        "parity, open ones by generalized winding numbers")
    chunk_edge: int = Field(128, ge=16, le=1024, description="x/y chunk edge of the Zarr arrays, voxels")
    tile_chunks: int = Field(1, ge=1, le=64, description="x chunks per voxelization tile (memory per worker)")
    masks: bool = Field(True, description="compute mask_camera and mask_lidar (ray traversal from the rig's sensors)")
    camera_ray_stride: int = Field(
        1, ge=1, le=64, description="camera mask rays through every n-th pixel row and column (1 = every pixel of "
        "the cameras, whose neighbouring rays are one 0.05 m voxel apart at about 27 m; n divides that distance by "
        "n). null, the former automatic choice, means 1")
    flow: bool = Field(True, description="compute the occupancy flow of dynamic instances")
    rig: RigConfig | None = Field(
        None, description="the ego rig for the masks; the pipeline sets it from scenes.rig")
    taxonomy: LabelTableName | None = Field(None, description=_SET_BY_PIPELINE)

    @field_validator("camera_ray_stride", mode="before")
    @classmethod
    def _stride_null_is_every_pixel(cls, v):
        # configs written by `carlaocc config` before every pixel became the default say null
        return 1 if v is None else v

    def grid(self, voxel_size: float) -> GridSpec:
        """The grid spec of this region at one voxel size (validates the voxel size)."""
        return GridSpec(region_min=self.region_min, region_max=self.region_max, voxel_size=voxel_size)


class SimulatorArtifacts(StageConfig):
    """What a UE5 CARLA camera gets wrong (paper, appendix "Sensor Artifacts Rectification"):
    the model that turns clean ray-cast maps into the ``*_raw`` maps a simulator delivers, and
    the renderer's known omissions that rectification repairs.

    * translucent parts (ADMesh ``transparent``) are absent from the depth buffer and the
      semantic pass: a pixel sees the first opaque surface behind them;
    * unlabelled assets (the non-Nanite ones the semantic pass does not substitute) keep their
      depth but get the empty label (0) and instance 0.
    """

    transparent: bool = Field(True, description="translucent parts are missing from raw depth and semantics")
    unlabelled_classes: tuple[str, ...] = Field(
        ("Terrain",), description="taxonomy classes whose meshes the semantic pass leaves unlabelled (0)")
    unlabelled_fraction: float = Field(
        0.05, ge=0.0, le=1.0, description="share of thing assets (chosen by a stable hash of the asset id and "
        "seed) the semantic pass leaves unlabelled")
    seed: int = 0

    @model_validator(mode="after")
    def _known_classes(self) -> SimulatorArtifacts:
        for name in self.unlabelled_classes:
            try:
                taxonomy.by_name(name)
            except KeyError as exc:
                raise ValueError(f"artifacts.unlabelled_classes: {exc.args[0]}") from None
        return self


class SensorsConfig(StageConfig):
    """Ray-cast camera maps and LiDAR per frame, and the instance-guided rectification."""

    source: Literal["raycast", "recorded"] = Field(
        "raycast", description="raycast: render clean maps and simulate the raw ones; recorded: rectify the raw "
        "maps a recorder wrote into sensors.zarr (depth_raw, semantic_raw[, instance_raw])")
    cameras: tuple[str, ...] | None = Field(None, description="rig cameras to render (default: all)")
    lidar: bool = Field(True, description="cast the rig's LiDAR (raycast source only)")
    scene_range: float = Field(
        120.0, gt=0.0, le=2000.0, description="half-width (m) of the box around the LiDAR whose scene the sensors "
        "see; beyond it cameras see sky")
    artifacts: SimulatorArtifacts = SimulatorArtifacts()
    epsilon: float = Field(
        0.05, gt=0.0, le=10.0, description="transparency threshold (m): raw depth at least this far behind the "
        "rectified depth marks a pixel seen through a translucent surface")
    normals: Literal["d2nt_basic", "d2nt_v2", "d2nt_v3"] = Field(
        "d2nt_v2", description="D2NT version for the normal maps (v3 adds MRF refinement at 3x the cost)")
    rgb: bool = Field(True, description="raycast source: render each camera's RGB from the scene (parts' base colours, "
                                        "sun with cast shadows, ambient, sky gradient); recorded RGB takes precedence")
    sun_azimuth_deg: float = Field(135.0, ge=-360.0, le=360.0,
                                   description="the sun's azimuth, degrees counter-clockwise from the world's +x")
    sun_elevation_deg: float = Field(50.0, gt=0.0, le=90.0, description="the sun's elevation above the horizon, degrees")
    ambient: float = Field(0.35, ge=0.0, le=1.0, description="share of light that reaches shadowed and unlit surfaces")
    rig: RigConfig | None = Field(None, description="the ego rig; the pipeline sets it from scenes.rig")
    taxonomy: LabelTableName | None = Field(None, description=_SET_BY_PIPELINE)

    def selected_cameras(self, rig: RigConfig) -> tuple:
        """The rig's CameraSpecs to render, in rig order; unknown names are an error naming them."""
        names = [c.name for c in rig.cameras]
        if self.cameras is None:
            return tuple(rig.cameras)
        unknown = [n for n in self.cameras if n not in names]
        if unknown:
            raise ValueError(f"sensors.cameras: unknown cameras {unknown}; the rig has {names}")
        return tuple(c for c in rig.cameras if c.name in self.cameras)


class QualityConfig(StageConfig):
    """Dataset-quality scores (spatial continuity, temporal consistency) and the report."""

    neighbourhood: Literal[6] = 6
    frames_per_task: int = Field(20, ge=1, le=1000, description="consecutive frames one quality task scores "
                                 "(its time and memory do not grow with the sequence; each task also reads "
                                 "the next task's first frame for its last pair)")
    taxonomy: LabelTableName | None = Field(None, description=_SET_BY_PIPELINE + " (the report)")


class SplitsConfig(StageConfig):
    """Train / val / test by sequence (edited sequences follow their parent)."""

    seed: int = Field(0, description="seed of the permutation that deals sequences to the splits")
    val_fraction: float = Field(0.15, ge=0.0, lt=1.0, description="share of sequences in val (at least one when > 0)")
    test_fraction: float = Field(0.15, ge=0.0, lt=1.0, description="share of sequences in test (at least one when > 0)")

    @model_validator(mode="after")
    def _fractions(self) -> SplitsConfig:
        if self.val_fraction + self.test_fraction >= 1.0:
            raise ValueError(f"splits: val_fraction + test_fraction must stay below 1 (train keeps a sequence), got "
                             f"{self.val_fraction} + {self.test_fraction}")
        return self


class DatasetConfig(StageConfig):
    """Everything a dataset build is configured by; the optional ``--config`` YAML/JSON file."""

    taxonomy: LabelTableName = Field(
        DEFAULT_LABEL_TABLE, description="the label table: 'release' (the official CarlaOcc release's utils/labels.py: "
        "Pole, TrafficLight, TrafficSign and the road users carry instance ids, Building does not; its Occ3D and "
        "KITTI-360 ids) or 'carlaocc-v1' (Building a thing, poles, lights and signs stuff). Recorded with every "
        "array; changing it re-runs every stage after ingest")
    ingest: IngestConfig = IngestConfig()
    scenes: ScenesConfig = ScenesConfig()
    splits: SplitsConfig = SplitsConfig()
    voxelize: VoxelizeConfig = VoxelizeConfig()
    sensors: SensorsConfig = SensorsConfig()
    quality: QualityConfig = QualityConfig()

    @model_validator(mode="before")
    @classmethod
    def _retired_sections(cls, data):
        # the quality section's earlier name: refused with the name to use (not read silently)
        if isinstance(data, dict) and "metrics" in data:
            raise ValueError("config section 'metrics' was renamed 'quality': rename it in the config file")
        return data

    @model_validator(mode="before")
    @classmethod
    def _named_region(cls, data):
        # voxelize.region: a name resolving to region_min / region_max in the LiDAR frame of the
        # configured rig (the name is not kept: the bounds are what the build records)
        if not isinstance(data, dict) or not isinstance(data.get("voxelize"), dict) or "region" not in data["voxelize"]:
            return data
        vox = dict(data["voxelize"])
        name = vox.pop("region")
        if name not in NAMED_REGIONS:
            raise ValueError(f"voxelize.region must be one of {', '.join(NAMED_REGIONS)}, got {name!r}")
        if "region_min" in vox or "region_max" in vox:
            raise ValueError("voxelize.region names the bounds: give it or region_min / region_max, not both")
        scenes = data.get("scenes") or {}
        rig = scenes.rig if isinstance(scenes, ScenesConfig) else RigConfig.model_validate(scenes.get("rig") or {})
        vox["region_min"], vox["region_max"] = named_region(name, rig.lidar.sensor_to_ego())
        return {**data, "voxelize": vox}

    @model_validator(mode="after")
    def _one_taxonomy(self) -> DatasetConfig:
        # the stages' taxonomy fields are the pipeline's copies of the top-level one
        for name in ("scenes", "voxelize", "sensors", "quality"):
            own = getattr(self, name).taxonomy
            if own is not None and own != self.taxonomy:
                raise ValueError(f"{name}.taxonomy is {own!r} but the dataset's taxonomy is {self.taxonomy!r}: set the "
                                 f"top-level 'taxonomy' key (every stage uses it)")
        return self

    @model_validator(mode="after")
    def _region_is_valid(self) -> DatasetConfig:
        # the region must hold at least one voxel of the coarsest sensible size; per-voxel-size
        # checks happen when a voxel size is requested (GridSpec validation)
        for lo, hi in zip(self.voxelize.region_min, self.voxelize.region_max):
            if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
                raise ValueError(f"voxelize region must have max > min on every axis, got {lo} .. {hi}")
        return self


def parse_voxel_size_list(text: str) -> tuple[float, ...]:
    """Parse ``"0.2"`` or ``"0.2,0.05"`` into voxel sizes (m); each must be positive and finite.
    Sizes that share a store key (``0.4`` and ``0.4000001`` are both ``"0.4"``) are one
    voxel size: the first spelling is kept."""
    out: dict[str, float] = {}
    for item in str(text).split(","):
        item = item.strip()
        if not item:
            continue
        try:
            v = float(item)
        except ValueError:
            raise ValueError(f"voxel size {item!r} is not a number of metres") from None
        if not math.isfinite(v) or v <= 0:
            raise ValueError(f"voxel size {item!r} must be a positive finite number of metres")
        if voxel_size_key(v) == "0":
            raise ValueError(f"voxel size {item!r} is below the store's micrometre precision")
        out.setdefault(voxel_size_key(v), v)
    if not out:
        raise ValueError("no voxel size given (e.g. --voxel-size 0.2 or --voxel-size 0.2,0.05)")
    return tuple(out.values())


__all__ = [
    "DatasetConfig",
    "IngestConfig",
    "QualityConfig",
    "ScenesConfig",
    "SourceIngestConfig",
    "SplitsConfig",
    "StageConfig",
    "TownSpec",
    "VoxelizeConfig",
    "parse_voxel_size_list",
]
