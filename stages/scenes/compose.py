"""The panoptic scene mesh of one frame, in the LiDAR frame (the grid's frame).

Implements the selection of the paper's "Mesh-Based Scene Reconstruction": every placed mesh and
every actor of the frame whose transformed bounding box touches the occupancy region (grown by
:data:`REGION_MARGIN`) is moved into the LiDAR frame with ``inverse(lidar_pose) @ object_pose``
and emitted as one :class:`~stages.geometry.SceneMesh` per part, labelled with the part's class
and the placement's / actor's instance id (0 for stuff classes).

* Stuff parts (taxonomy stuff classes) are surfaces (``closed=False``, instance 0); their
  triangles lying entirely outside the grown region are culled, and unused vertices dropped.
* Thing parts are kept whole (a closed part needs every triangle for its interior fill) or
  dropped when their own bounding box misses the grown region; ``closed`` is the part's
  watertightness.
* The **ego vehicle is not part of the scene**: :func:`simulate_sequences` never emits it as an
  actor, and an actor that sits exactly at the frame's ego pose (and, when ``ego_asset_id`` is
  given, uses that asset) is dropped as the ego, should a caller add it.
* Order is deterministic: placements by placement id, then actors by instance id, parts in asset
  order.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from schemas import taxonomy
from schemas.grid import GridSpec
from schemas.records import ActorStateRecord, FrameRecord, PlacementRecord
from stages.geometry import AssetGeometry, SceneMesh, invert_pose, pose_from_list, transform_points

__all__ = ["compose_frame_scene", "REGION_MARGIN"]

REGION_MARGIN = 0.5  # m: the region is grown by this much before selecting and culling
_STUFF = frozenset(taxonomy.stuff_ids())


def _bounds(geom: AssetGeometry) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounds (min, max) of all parts of an asset, in its own frame (m)."""
    V = np.concatenate([p.vertices for p in geom.parts]) if geom.parts else np.zeros((1, 3))
    return V.min(axis=0), V.max(axis=0)


def _box_touches(bounds: tuple[np.ndarray, np.ndarray], T: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> bool:
    """Whether the box ``bounds`` moved by ``T`` has an axis-aligned hull touching ``lo .. hi``."""
    bmin, bmax = bounds
    corners = np.array([[x, y, z] for x in (bmin[0], bmax[0]) for y in (bmin[1], bmax[1]) for z in (bmin[2], bmax[2])])
    c = transform_points(T, corners)
    return bool(np.all(c.min(axis=0) <= hi) and np.all(c.max(axis=0) >= lo))


def _cull(V: np.ndarray, F: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Keep the triangles whose bounding box touches ``lo .. hi`` and only the vertices they use."""
    tri = V[F]
    keep = np.all((tri.min(axis=1) <= hi) & (tri.max(axis=1) >= lo), axis=1)
    F = F[keep]
    used, inverse = np.unique(F, return_inverse=True)
    return V[used], inverse.reshape(-1, 3).astype(np.int64)


def _emit(
    geom: AssetGeometry, T: np.ndarray, instance_id: int, name: str, lo: np.ndarray, hi: np.ndarray
) -> list[SceneMesh]:
    """Scene meshes of one placed object: each part moved by ``T`` (object -> LiDAR)."""
    out = []
    for part, closed in zip(geom.parts, geom.part_closed):
        V, F = transform_points(T, part.vertices), part.faces
        is_stuff = part.semantic_id in _STUFF
        if is_stuff:
            # stuff is a surface: drop the triangles lying wholly outside the region
            V, F = _cull(V, F, lo, hi)
            if len(F) == 0:
                continue
        elif np.any(V.min(axis=0) > hi) or np.any(V.max(axis=0) < lo):
            continue  # a closed thing part is kept whole or, when it misses the region, dropped
        out.append(SceneMesh(
            vertices=V, faces=F, semantic_id=int(part.semantic_id),
            instance_id=0 if is_stuff else int(instance_id), is_stuff=is_stuff,
            closed=bool(closed) and not is_stuff, name=f"{name}/{part.name}",
        ))  # fmt: skip
    return out


def _is_ego(actor: ActorStateRecord, ego_pose: np.ndarray, ego_asset_id: str | None) -> bool:
    """An actor standing at the ego pose (1 cm, 1e-3 rad) with the ego's asset, when known."""
    if ego_asset_id is not None and actor.asset_id != ego_asset_id:
        return False
    P = pose_from_list(actor.pose)
    same_place = np.linalg.norm(P[:3, 3] - ego_pose[:3, 3]) < 0.01
    return bool(same_place and np.allclose(P[:3, :3], ego_pose[:3, :3], atol=1e-3))


def compose_frame_scene(
    frame: FrameRecord,
    actors: Sequence[ActorStateRecord],
    placements: Sequence[PlacementRecord],
    geometry: Mapping[str, AssetGeometry],
    grid: GridSpec,
    ego_asset_id: str | None = None,
) -> list[SceneMesh]:
    """The panoptic scene of ``frame`` in its LiDAR frame (metres, x forward, y left, z up).

    ``actors`` may hold any frames/sequences: only those of this frame are used. ``geometry``
    maps asset ids (ADMesh ids and the town's ``"<town>/<name>"`` stuff keys) to geometry in the
    object frame (stuff: world frame with an identity pose). Raises ``ValueError`` when a
    placement or actor refers to an asset missing from ``geometry``.
    """
    world_to_lidar = invert_pose(pose_from_list(frame.lidar_pose))
    ego_pose = pose_from_list(frame.ego_pose)
    lo = np.asarray(grid.origin, dtype=np.float64) - REGION_MARGIN
    hi = np.asarray(grid.effective_max, dtype=np.float64) + REGION_MARGIN
    bounds: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def lookup(asset_id: str, who: str) -> AssetGeometry:
        try:
            geom = geometry[asset_id]
        except KeyError:
            raise ValueError(f"{who} uses asset {asset_id!r}, which has no geometry") from None
        if asset_id not in bounds:
            bounds[asset_id] = _bounds(geom)
        return geom

    out: list[SceneMesh] = []
    # 1. static placements, by placement id
    for p in sorted(placements, key=lambda p: p.placement_id):
        geom = lookup(p.asset_id, f"placement {p.name!r}")
        T = world_to_lidar @ pose_from_list(p.pose)
        if _box_touches(bounds[p.asset_id], T, lo, hi):
            out.extend(_emit(geom, T, p.instance_id, p.name, lo, hi))
    # 2. this frame's actors (never the ego), by instance id
    mine = [a for a in actors if a.sequence_id == frame.sequence_id and a.frame_index == frame.frame_index]
    for a in sorted(mine, key=lambda a: a.instance_id):
        if _is_ego(a, ego_pose, ego_asset_id):
            continue
        geom = lookup(a.asset_id, f"actor {a.instance_id}")
        T = world_to_lidar @ pose_from_list(a.pose)
        if _box_touches(bounds[a.asset_id], T, lo, hi):
            out.extend(_emit(geom, T, a.instance_id, f"actor_{a.instance_id}", lo, hi))
    return out
