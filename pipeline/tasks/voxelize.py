"""The voxelize stage: one task per (sequence, voxel size, frame) voxelizes the frame's panoptic
scene exactly (triangle-box overlap, closed things filled) into occupancy.zarr — semantic,
instance and flow tile by tile, then the camera and LiDAR visibility masks traced through the
frame's packed occupancy and written chunk by chunk from their bits, with their union kept as
bits (``observed_bits``, what the quality stage reads). The Zarr arrays of every
(sequence, voxel size) are created before the tasks run (``prepare``).
"""

from __future__ import annotations

import numpy as np

from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.store import Store
from carlaocc.pipeline.engine.spec import Context, Partition, StageSpec
from carlaocc.pipeline.tasks.frame import FrameInputs, frame_inputs
from carlaocc.pipeline.tasks.partitions import INGEST_PARTITION, sequences
from carlaocc.schemas.configs import DatasetConfig, VoxelizeConfig
from carlaocc.schemas.rig import RigConfig
from carlaocc.stages.geometry import pose_from_list
from carlaocc.stages.scenes.assembly import region_of_grid
from carlaocc.stages.voxelize import voxelize_tiles
from carlaocc.stages.voxelize.flow import actor_voxels, voxel_flow
from carlaocc.stages.voxelize.observed import observed_columns, packed_block
from carlaocc.stages.voxelize.visibility import camera_visibility_bits, lidar_visibility_bits, pack_occupancy


def voxelize_config(config: DatasetConfig) -> VoxelizeConfig:
    """The voxelize stage's config: ``voxelize`` with the rig of ``scenes`` (masks are cast from
    the sensors the sequences were recorded with; a rig change re-runs both stages)."""
    return config.voxelize.model_copy(update={"rig": config.scenes.rig, "taxonomy": config.taxonomy})


def _voxelize_partitions(ctx: Context) -> list[Partition]:
    out = []
    for seq in sequences(ctx):
        for voxel_size in ctx.voxel_sizes:
            key = ctx.config.voxelize.grid(voxel_size).key
            for t in range(seq.frame_count):
                out.append(Partition(
                    f"{seq.sequence_id}/{key}/{t:04d}",
                    {"sequence_id": seq.sequence_id, "voxel_size": voxel_size, "frame_index": t},
                    needs=(("ingest", INGEST_PARTITION), ("scenes", seq.town)),
                ))
    return out


def _voxelize_prepare(ctx: Context, to_run: list[Partition], partitions: list[Partition]) -> set[str]:
    """Create the Zarr arrays of every (sequence, voxel size) about to be written; when an array
    had to be replaced, every frame of it is invalidated."""
    frames = {s.sequence_id: s.frame_count for s in sequences(ctx)}
    occ = OccupancyStore(ctx.store)
    groups = {(p.params["sequence_id"], p.params["voxel_size"]) for p in to_run}
    invalid: set[str] = set()
    for seq, voxel_size in sorted(groups):
        vcfg = voxelize_config(ctx.config)
        # the rig's LiDAR mount travels with the arrays: exports to ego-frame grids need it
        lidar_to_ego = [list(r) for r in ctx.config.scenes.rig.lidar.sensor_to_ego()]
        if occ.create(seq, vcfg.grid(voxel_size), frames[seq], vcfg.chunk_edge, extra_attrs={"lidar_to_ego": lidar_to_ego, "label_table": ctx.config.taxonomy},
                      names=occupancy_arrays(vcfg)):
            invalid |= {p.key for p in partitions
                        if (p.params["sequence_id"], p.params["voxel_size"]) == (seq, voxel_size)}
    return invalid


def occupancy_arrays(cfg: VoxelizeConfig) -> tuple[str, ...]:
    """The occupancy arrays the voxelize stage writes under ``cfg``."""
    return ("semantic", "instance") + (("mask_camera", "mask_lidar", "observed_bits") if cfg.masks else ()) + (
        ("flow",) if cfg.flow else ())


def _frame_flow(inputs: FrameInputs):
    """``(tile, tile_origin, voxel_size) -> (flat indices, float16 (N, 3) flow) | None``: the flow
    of the voxels of the frame's actors in a tile (None when it holds none: its flow is zero)."""

    actors = [a for a in inputs.actors if a.instance_id > 0]
    ids = np.asarray([a.instance_id for a in actors], dtype=np.uint32)
    # rotation centre: the actor's pose origin (its velocity is that point's, see traffic)
    centres = np.asarray([pose_from_list(a.pose)[:3, 3] for a in actors], dtype=np.float64).reshape(-1, 3)
    vel = np.asarray([a.velocity for a in actors], dtype=np.float64).reshape(-1, 3)
    ang = np.asarray([a.angular_velocity for a in actors], dtype=np.float64).reshape(-1, 3)
    lidar_to_world = pose_from_list(inputs.frame.lidar_pose)

    def flow(tile, tile_origin, voxel_size):
        # an actor's voxels are looked for only inside the boxes of its meshes in the tile
        flat, actor = actor_voxels(tile.instance, tile.things, ids)
        if len(flat) == 0:
            return None
        return flat, voxel_flow(flat, tile.instance.shape, tile_origin, voxel_size, actor, centres, vel, ang,
                                lidar_to_world)

    return flow


def voxelize_task(store: Store, cfg: VoxelizeConfig, part: Partition) -> dict[str, str]:
    """Voxelize one frame of one sequence at one voxel size into occupancy.zarr: semantic,
    instance and flow tile by tile (x-slabs of whole chunks), then the camera and LiDAR masks,
    traced through the frame's occupancy packed tile by tile and written chunk by chunk from
    their bits (no array of the whole frame is ever held)."""

    seq_id, frame_index = part.params["sequence_id"], part.params["frame_index"]
    grid = cfg.grid(part.params["voxel_size"])
    inputs = frame_inputs(store, seq_id, frame_index, region_of_grid(grid), cfg.taxonomy)
    occ = OccupancyStore(store)
    names = occupancy_arrays(cfg)
    tile_x = cfg.chunk_edge * cfg.tile_chunks
    cx, cy = occ.chunk_edges(seq_id, grid, "instance")
    flow = _frame_flow(inputs) if cfg.flow else None
    packed = pack_occupancy(None, grid, reuse=True) if cfg.masks else None
    voxel_size = float(grid.voxel_size)
    # 1. per tile: semantic, instance (only the chunks its things' boxes reach are read), flow,
    #    and the tile's occupancy packed for the masks
    # elevation order along the world's up (the LiDAR tilts with the ego on slopes and banks)
    for tile in voxelize_tiles(inputs.scene, grid, tile_x, cfg.fill, inputs.up):
        nx = tile.semantic.shape[0]
        occ.write_tile(seq_id, grid, frame_index, "semantic", tile.semantic, tile.x0)
        # instances are nonzero only inside things' boxes: chunks assembled from the boxes' parts
        occ.write_boxes(seq_id, grid, frame_index, "instance", tile.instance, tile.x0, tile.things)
        if packed is not None:
            packed.pack_slab(tile.x0, tile.semantic)
        if flow is None:
            continue
        v = flow(tile, (grid.origin[0] + tile.x0 * voxel_size, grid.origin[1], grid.origin[2]), voxel_size)
        if v is None:
            occ.clear_tile(seq_id, grid, frame_index, "flow", tile.x0, nx)
            continue
        # the flow's voxels scattered chunk by chunk (a dense tile is 200 MB at 0.05 m)
        occ.write_points(seq_id, grid, frame_index, "flow", tile.x0, nx, *v)
    # 2. visibility: rays of the rig's LiDAR and cameras through the frame's occupancy, each
    #    mask's chunks unpacked from its bits one at a time (an empty one is known from its words)
    if packed is not None:
        rig = cfg.rig or RigConfig()
        X, Y = packed.shape[:2]
        lidar = lidar_visibility_bits(packed, rig)
        camera = camera_visibility_bits(packed, rig, cfg.camera_ray_stride)
        for name, bits in (("mask_lidar", lidar), ("mask_camera", camera)):
            occ.write_chunks(seq_id, grid, frame_index, name, 0, X, lambda ci, cj, bits=bits: packed.block(
                bits, ci * cx, cj * cy, min(cx, X - ci * cx), min(cy, Y - cj * cy)))
        # 3. their union as bits packed along z (a strided copy of the column words, no unpacking):
        #    what the quality stage reads instead of decoding both masks byte per voxel
        observed = observed_columns(lidar, camera)
        occ.write_chunks(seq_id, grid, frame_index, "observed_bits", 0, X, lambda ci, cj: packed_block(
            observed, packed.shape, ci * cx, cj * cy, min(cx, X - ci * cx), min(cy, Y - cj * cy)))
    return occ.fingerprints(seq_id, grid, frame_index, names)


SPEC = StageSpec(
    name="voxelize",
    description="panoptic voxelization of every frame's scene mesh (exact triangle-box overlap)",
    upstream=("ingest", "scenes"),
    reads=("admesh/", "scenes/"),
    writes=("occupancy.zarr/<seq>/<voxel_size>/{semantic,instance,mask_camera,mask_lidar,flow,observed_bits}",),
    partitions=_voxelize_partitions,
    task=voxelize_task,
    prepare=_voxelize_prepare,
    config_of=voxelize_config,
)
