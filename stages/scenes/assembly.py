"""Per-frame panoptic scene assembly, and the town's unified static mesh.

Implements the selection of the paper's "Mesh-Based Scene Reconstruction" for one frame:

1. **Select static placements.** A :class:`PlacementIndex` (built once per town) holds every
   placement's world-frame AABB (``PlacementRecord.aabb_min`` / ``aabb_max``) as two (P, 3)
   arrays, sorted by placement id. :meth:`PlacementIndex.select` returns, vectorized, the
   placements whose AABB meets a world box (closed boxes: touching counts). The world box of a
   frame is :func:`frame_region`: the world AABB of the LiDAR-frame region box.
2. **Add actors.** This frame's rigid actors use their asset's geometry (``geometry[asset_id]``);
   pedestrians (``phase_index`` not None) use ``pedestrian_geometry(asset_id, phase_index)``
   when given -- the mesh of the gait phase the Skeletal Motion Analyzer matched -- else their
   rest geometry. An actor whose ``scale`` is not 1 (a recorded walker scaled to its recorded
   height) uses that geometry scaled about the asset origin (:func:`scaled_geometry`); its pose
   stays rigid. The **ego vehicle is never part of the scene**: an actor standing exactly at
   the frame's ego pose (1 cm, 1e-3 rad; and, when ``ego_asset_id`` is given, using that asset)
   is dropped.
3. **Move into the LiDAR frame** with ``inverse(lidar_pose) @ object_pose`` and emit one
   :class:`~carlaocc.schemas.meshes.SceneMesh` per asset part, with the rules of the former
   ``compose_frame_scene``:

   * stuff parts (taxonomy stuff classes) that the fill rule leaves surfaces under ``auto``
     (:func:`carlaocc.stages.voxelize.fill.fills`: roads, terrain, fences, crowns...) are culled
     per triangle: only triangles whose LiDAR-frame bounding box touches the region are kept,
     with the vertices they use; a part left empty is dropped; ``closed=False``, instance 0;
   * thing parts and the stuff parts ``auto`` fills (walls, poles, props, trunks) are kept whole
     (a fill needs every triangle) or dropped when the bounding box of their LiDAR-frame
     vertices misses the region; ``closed`` is the part's watertightness, ``instance_id`` the
     placement's / actor's (0 for stuff);
   * ``transparent`` is the part's flag (glass: cameras see past it, occupancy does not).

   Order is deterministic: placements by placement id, then actors by instance id, parts in
   asset order.

Region: a closed box ``(lo, hi)`` in the LiDAR frame (metres). The voxelizer's callers pass the
grid grown by a margin (:func:`region_of_grid`); sensor rendering may pass a larger range.

Relation to the old per-placement test: a placement is a candidate when its *world* AABB meets
the world AABB of the region (a superset of the rotated region), then every part is tested
exactly in the LiDAR frame as before. The output can differ from ``compose_frame_scene`` only by
meshes that do not reach the region at all (their LiDAR-frame bounding box touched it, their
world AABB did not), which contribute no voxel.

:func:`town_mesh` is the paper's city-level reconstruction: every placement placed in the world
frame, stuff whole, as one :class:`PanopticMesh` with per-face semantic and instance ids.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from carlaocc.schemas import taxonomy
from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.meshes import AssetGeometry, SceneMesh
from carlaocc.schemas.records import ActorStateRecord, FrameRecord, PlacementRecord
from carlaocc.stages.geometry import invert_pose, pose_from_list, transform_points
from carlaocc.stages.voxelize.fill import fills

__all__ = [
    "scaled_geometry",
    "PanopticMesh",
    "PlacementIndex",
    "assemble_frame",
    "flatten",
    "frame_region",
    "region_of_grid",
    "town_mesh",
]

DEFAULT_THINGS: frozenset[int] = frozenset(taxonomy.thing_ids())
"""The thing classes of the default label table (``taxonomy.DEFAULT_LABEL_TABLE``)."""
_UNIT_CUBE = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=np.float64)

PedestrianGeometry = Callable[[str, int], AssetGeometry]


# --------------------------------------------------------------------------------------------
# static placement selection
# --------------------------------------------------------------------------------------------


class PlacementIndex:
    """The static placements of one town with their world AABBs, for fast per-frame selection.

    ``placements`` are kept sorted by placement id (stable for equal ids), so selected indices in
    ascending order are placements in ascending id. ``lo`` / ``hi`` are the (P, 3) float64 world
    AABB corners of the placed meshes, in the same order.

    :func:`assemble_frame` also keeps here, per asset id (and per pedestrian phase), the asset
    prepared for placing (parts stacked; per-triangle pre-cull boxes of big stuff meshes). An
    entry is redone when another geometry object comes for its key, so reusing one index across
    frames is fast and passing fresh geometry is still correct. Share an index between threads
    freely: a race only prepares an asset twice.
    """

    def __init__(self, placements: Sequence[PlacementRecord]) -> None:
        self.placements: tuple[PlacementRecord, ...] = tuple(sorted(placements, key=lambda p: p.placement_id))
        n = len(self.placements)
        self.lo = np.array([p.aabb_min for p in self.placements], dtype=np.float64).reshape(n, 3)
        self.hi = np.array([p.aabb_max for p in self.placements], dtype=np.float64).reshape(n, 3)
        bad = np.flatnonzero(np.any(self.lo > self.hi, axis=1))
        if bad.size:
            p = self.placements[int(bad[0])]
            raise ValueError(f"placement {p.placement_id} ({p.name!r}): aabb_min {p.aabb_min} exceeds aabb_max {p.aabb_max}")
        # column views, contiguous: six 1-D comparisons beat one (P, 3) reduction
        self._cols = [np.ascontiguousarray(a[:, k]) for a in (self.lo, self.hi) for k in range(3)]
        # per-asset preparation for assemble_frame (stacked vertices, big stuff pre-cull boxes),
        # keyed by asset id / (asset id, phase); an entry is redone when another geometry object
        # is passed for its key, so the cache stays bounded by the town's assets
        self._prepared: dict[object, _Prepared] = {}

    def __len__(self) -> int:
        return len(self.placements)

    def select(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Indices (into :attr:`placements`, ascending, so by placement id) of the placements
        whose world AABB meets the closed world box ``lo .. hi`` (touching counts)."""
        lo = np.asarray(lo, dtype=np.float64).reshape(3)
        hi = np.asarray(hi, dtype=np.float64).reshape(3)
        plo_x, plo_y, plo_z, phi_x, phi_y, phi_z = self._cols
        keep = plo_x <= hi[0]
        keep &= phi_x >= lo[0]
        keep &= plo_y <= hi[1]
        keep &= phi_y >= lo[1]
        keep &= plo_z <= hi[2]
        keep &= phi_z >= lo[2]
        return np.flatnonzero(keep)


def _box_corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The 8 corners of the box ``lo .. hi``."""
    return lo + _UNIT_CUBE * (hi - lo)


def frame_region(frame: FrameRecord, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World AABB (min, max) of the LiDAR-frame box ``lo .. hi`` of ``frame`` (its 8 corners
    moved by the frame's lidar-to-world pose)."""
    lo = np.asarray(lo, dtype=np.float64).reshape(3)
    hi = np.asarray(hi, dtype=np.float64).reshape(3)
    c = transform_points(pose_from_list(frame.lidar_pose), _box_corners(lo, hi))
    return c.min(axis=0), c.max(axis=0)


def region_of_grid(grid: GridSpec, margin: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """The grid's region ``[origin, effective_max]`` (LiDAR frame) grown by ``margin`` metres on
    every side: the region the voxelizer's scene must cover."""
    m = float(margin)
    return (np.asarray(grid.origin, dtype=np.float64) - m, np.asarray(grid.effective_max, dtype=np.float64) + m)


# --------------------------------------------------------------------------------------------
# placing parts
# --------------------------------------------------------------------------------------------


def _cull(V: np.ndarray, F: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Keep the triangles whose bounding box touches ``lo .. hi``; when some are dropped, keep
    only the vertices the rest use (in ascending original order). Third: the kept triangles'
    indices into ``F`` (None: all kept)."""
    keep = np.ones(len(F), dtype=bool)
    for axis in range(3):
        c = V[:, axis][F]  # (M, 3)
        keep &= (c.min(axis=1) <= hi[axis]) & (c.max(axis=1) >= lo[axis])
    if keep.all():
        return V, F, None
    kept = np.flatnonzero(keep)
    F = F[kept]
    if len(F) == 0:
        return V[:0], F, kept
    used, inverse = np.unique(F, return_inverse=True)
    return V[used], inverse.reshape(-1, 3).astype(np.int64), kept


class _Prepared:
    """One asset's geometry made ready for placing many times.

    Small parts (every thing part, stuff parts under :data:`_BIG_STUFF` triangles) are stacked
    into one vertex array, so a placement costs one matrix product and one min/max per part.
    Big stuff parts (town ground meshes) keep, per triangle, a box in the asset frame that is
    provably a superset test: a triangle whose bounding box *in any rigid frame* touches the
    region has its asset-frame box within ``sqrt(3) * diag`` of the region's asset-frame AABB
    (``diag`` = its asset-frame box diagonal, which bounds its diameter; any point of a
    bounding box is within its diagonal of the triangle's vertices). Only the triangles passing
    that cheap test are moved and tested exactly, so a town-wide ground mesh is not transformed
    whole every frame.
    """

    __slots__ = ("big", "geom", "small", "starts", "stuff", "things", "vertices", "whole")

    def __init__(self, geom: AssetGeometry, things: frozenset[int]) -> None:
        self.geom, self.things = geom, things
        # a part is stuff (instance 0, fused per class) unless the label table makes its class a thing
        self.stuff = [int(p.semantic_id) not in things for p in geom.parts]
        # stuff parts the fill rule fills are kept whole like things (the fill needs every triangle)
        self.whole = [not st or fills(p.semantic_id, p.name) for st, p in zip(self.stuff, geom.parts)]
        self.small: list[int] = []
        self.big: dict[int, tuple[np.ndarray, ...]] = {}
        for k, p in enumerate(geom.parts):
            if len(p.faces) == 0:
                continue
            if not self.whole[k] and len(p.faces) >= _BIG_STUFF:
                tri = p.vertices[p.faces]  # (M, 3, 3)
                tmin, tmax = tri.min(axis=1), tri.max(axis=1)
                grow = (np.sqrt(3.0) * np.linalg.norm(tmax - tmin, axis=1))[:, None]
                lo, hi = tmin - grow, tmax + grow
                self.big[k] = tuple(np.ascontiguousarray(a[:, j]) for a in (lo, hi) for j in range(3))
            else:
                self.small.append(k)
        counts = [len(geom.parts[k].vertices) for k in self.small]
        self.starts = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        self.vertices = (np.concatenate([geom.parts[k].vertices for k in self.small]) if self.small
                         else np.zeros((0, 3)))  # fmt: skip


_BIG_STUFF = 4096  # stuff parts with at least this many triangles are pre-culled in the asset frame


def _prepared(cache: dict[object, _Prepared], key: object, geom: AssetGeometry,
              things: frozenset[int] = DEFAULT_THINGS) -> _Prepared:
    """The preparation of ``geom`` under the thing classes ``things``, cached in ``cache`` under
    ``key`` (an asset id, or an ``(asset id, phase)`` pair) while the same geometry object and
    thing classes are passed for it."""
    hit = cache.get(key)
    if hit is None or hit.geom is not geom or hit.things != things:
        hit = cache[key] = _Prepared(geom, things)
    return hit


def _placement_geometry(p: PlacementRecord, geometry: Mapping[str, AssetGeometry]) -> AssetGeometry:
    """The geometry of placement ``p``'s asset; ``ValueError`` naming the placement when missing."""
    try:
        return geometry[p.asset_id]
    except KeyError:
        raise ValueError(
            f"placement {p.placement_id} ({p.name!r}) uses asset {p.asset_id!r}, which has no geometry"
        ) from None


def _emit(
    prep: _Prepared,
    T: np.ndarray,
    instance_id: int,
    name: str,
    region: tuple[np.ndarray, np.ndarray] | None,
) -> list[SceneMesh]:
    """Scene meshes of one placed object: each part moved by ``T`` (object -> target frame), in
    asset order. ``region`` None keeps everything (the whole-town mesh)."""
    geom = prep.geom
    V_all = transform_points(T, prep.vertices)
    if region is not None and prep.small:
        lo, hi = region
        # per-part bounds, one reduction each for the whole object
        pmin = np.minimum.reduceat(V_all, prep.starts[:-1], axis=0)
        pmax = np.maximum.reduceat(V_all, prep.starts[:-1], axis=0)
        reaches = np.all((pmin <= hi) & (pmax >= lo), axis=1)
    slot = {k: j for j, k in enumerate(prep.small)}
    out = []
    for k, (part, closed) in enumerate(zip(geom.parts, geom.part_closed, strict=True)):
        is_stuff = prep.stuff[k]
        faces_of = None  # which of the part's triangles are kept (None: all, in order)
        if k in slot:
            j = slot[k]
            V, F = V_all[prep.starts[j] : prep.starts[j + 1]], part.faces
            if region is not None:
                if not reaches[j]:
                    continue  # nothing of the part reaches the region
                if not prep.whole[k]:
                    # a surface: drop the triangles lying wholly outside the region
                    V, F, faces_of = _cull(V, F, *region)
                # a thing or filled stuff part reaching the region is kept whole
        elif k in prep.big:
            if region is None:
                V, F = transform_points(T, part.vertices), part.faces
            else:
                # cheap superset test in the asset frame, then the exact test on the survivors
                inv = invert_pose(T)
                c = transform_points(inv, _box_corners(*region))
                wlo, whi = c.min(axis=0), c.max(axis=0)
                cols = prep.big[k]  # lo x, y, z then hi x, y, z: six 1-D comparisons
                keep = cols[0] <= whi[0]
                for j in range(3):
                    if j:
                        keep &= cols[j] <= whi[j]
                    keep &= cols[3 + j] >= wlo[j]
                cand = np.flatnonzero(keep)
                F = part.faces[cand]
                used, inverse = np.unique(F, return_inverse=True)
                V, F, kept = _cull(transform_points(T, part.vertices[used]), inverse.reshape(-1, 3).astype(np.int64), *region)
                faces_of = cand if kept is None else cand[kept]
        else:
            continue  # a part without triangles
        if len(F) == 0:
            continue
        out.append(SceneMesh(
            vertices=V, faces=F, semantic_id=int(part.semantic_id),
            instance_id=0 if is_stuff else int(instance_id), is_stuff=is_stuff,
            closed=bool(closed) and prep.whole[k], name=f"{name}/{part.name}",
            transparent=bool(part.transparent), asset_id=geom.asset_id, part=part.name,
            color=tuple(int(c) for c in part.color[:3]),
            corner_uv=None if part.image is None else (part.corner_uv if faces_of is None else part.corner_uv[faces_of]),
            image=part.image,
        ))  # fmt: skip
    return out


def _is_ego(actor: ActorStateRecord, ego_pose: np.ndarray, ego_asset_id: str | None) -> bool:
    """An actor standing at the ego pose (1 cm, 1e-3 rad) with the ego's asset, when known."""
    if ego_asset_id is not None and actor.asset_id != ego_asset_id:
        return False
    P = pose_from_list(actor.pose)
    same_place = np.linalg.norm(P[:3, 3] - ego_pose[:3, 3]) < 0.01
    return bool(same_place and np.allclose(P[:3, :3], ego_pose[:3, :3], atol=1e-3))


_SCALED: dict[tuple[int, float], tuple[AssetGeometry, AssetGeometry]] = {}  # (id(geom), scale) -> (geom, scaled)


def scaled_geometry(geom: AssetGeometry, scale: float) -> AssetGeometry:
    """``geom`` scaled uniformly by ``scale`` about the asset origin (the bottom centre of its
    bounds, so it keeps standing on it); asset frame, metres. Cached while the same geometry
    object is passed (a walker's frames reuse their cycle frame's copy)."""
    hit = _SCALED.get((id(geom), scale))
    if hit is not None and hit[0] is geom:
        return hit[1]
    if len(_SCALED) > 256:
        _SCALED.clear()
    parts = tuple(dataclasses.replace(p, vertices=p.vertices * scale) for p in geom.parts)
    out = AssetGeometry(asset_id=geom.asset_id, parts=parts, part_closed=geom.part_closed)
    _SCALED[(id(geom), scale)] = (geom, out)
    return out


def _actor_geometry(
    actor: ActorStateRecord,
    geometry: Mapping[str, AssetGeometry],
    pedestrian_geometry: PedestrianGeometry | None,
) -> tuple[object, AssetGeometry]:
    """``(cache key, geometry)`` an actor shows in this frame: its matched gait phase for
    pedestrians (when a phase source is given), else its asset's rest geometry."""
    who = f"actor {actor.instance_id}"
    if actor.scale != 1.0:
        if not (np.isfinite(actor.scale) and actor.scale > 0):
            raise ValueError(f"{who} has scale {actor.scale}: a scale is a positive number")
        key, geom = _actor_geometry(actor.model_copy(update={"scale": 1.0}), geometry, pedestrian_geometry)
        return (key, actor.scale), scaled_geometry(geom, actor.scale)
    if actor.phase_index is not None and pedestrian_geometry is not None:
        try:
            return (actor.asset_id, int(actor.phase_index)), pedestrian_geometry(actor.asset_id, int(actor.phase_index))
        except KeyError:
            raise ValueError(
                f"{who} uses asset {actor.asset_id!r} at gait phase {actor.phase_index}, which has no geometry"
            ) from None
    try:
        return actor.asset_id, geometry[actor.asset_id]
    except KeyError:
        raise ValueError(f"{who} uses asset {actor.asset_id!r}, which has no geometry") from None


def assemble_frame(
    frame: FrameRecord,
    actors: Sequence[ActorStateRecord],
    index: PlacementIndex,
    geometry: Mapping[str, AssetGeometry],
    region: tuple[np.ndarray, np.ndarray],
    pedestrian_geometry: PedestrianGeometry | None = None,
    ego_asset_id: str | None = None,
    things: frozenset[int] = DEFAULT_THINGS,
) -> list[SceneMesh]:
    """The panoptic scene of ``frame`` in its LiDAR frame (metres, x forward, y left, z up).

    ``region`` is the closed LiDAR-frame box ``(lo, hi)`` the scene must cover (see
    :func:`region_of_grid`). ``actors`` may hold any frames/sequences: only those of this frame
    are used. ``geometry`` maps asset ids (ADMesh ids and the town's ``"<town>/<name>"`` stuff
    keys) to geometry in the object frame; it needs only the assets of the selected placements
    and of this frame's actors. ``pedestrian_geometry(asset_id, phase_index)`` gives a walker's
    mesh at a canonical gait phase. ``things``: the class ids that carry instance ids (the
    dataset's label table); parts of other classes are stuff (instance 0). Raises ``ValueError``
    naming the placement or actor whose asset has no geometry.
    """
    lo = np.asarray(region[0], dtype=np.float64).reshape(3)
    hi = np.asarray(region[1], dtype=np.float64).reshape(3)
    if np.any(lo > hi):
        raise ValueError(f"region min {lo.tolist()} exceeds max {hi.tolist()}")
    box = (lo, hi)
    world_to_lidar = invert_pose(pose_from_list(frame.lidar_pose))
    ego_pose = pose_from_list(frame.ego_pose)

    out: list[SceneMesh] = []
    # 1. static placements meeting the frame's world region, by placement id
    for i in index.select(*frame_region(frame, lo, hi)):
        p = index.placements[int(i)]
        prep = _prepared(index._prepared, p.asset_id, _placement_geometry(p, geometry), things)
        out.extend(_emit(prep, world_to_lidar @ pose_from_list(p.pose), p.instance_id, p.name, box))
    # 2. this frame's actors (never the ego), by instance id
    mine = [a for a in actors if a.sequence_id == frame.sequence_id and a.frame_index == frame.frame_index]
    for a in sorted(mine, key=lambda a: a.instance_id):
        if _is_ego(a, ego_pose, ego_asset_id):
            continue
        key, geom = _actor_geometry(a, geometry, pedestrian_geometry)
        out.extend(_emit(_prepared(index._prepared, key, geom, things), world_to_lidar @ pose_from_list(a.pose), a.instance_id, f"actor_{a.instance_id}", box))
    return out


# --------------------------------------------------------------------------------------------
# one mesh with per-triangle ids
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PanopticMesh:
    """One triangle mesh with per-triangle panoptic labels (frame: whatever its maker says --
    LiDAR frame from :func:`flatten` of an assembled scene, world frame from :func:`town_mesh`)."""

    vertices: np.ndarray  # (N, 3) float64, metres
    faces: np.ndarray  # (M, 3) int64
    semantic: np.ndarray  # (M,) uint8
    instance: np.ndarray  # (M,) uint32, 0 for stuff
    transparent: np.ndarray  # (M,) bool
    color: np.ndarray | None = None  # (M, 3) uint8 base colour per triangle (None: grey)
    # textures (None: no triangle has one): per triangle its image's index in ``images`` (-1:
    # none) and its corners' texture coordinates (M, 3, 2) float32 (zeros where untextured)
    texture: np.ndarray | None = None
    uv: np.ndarray | None = None
    images: tuple[np.ndarray, ...] = ()

    def __post_init__(self) -> None:
        V = np.ascontiguousarray(self.vertices, dtype=np.float64).reshape(-1, 3)
        F = np.ascontiguousarray(self.faces, dtype=np.int64).reshape(-1, 3)
        m = len(F)
        color = np.full((m, 3), 200, np.uint8) if self.color is None else self.color
        arrays = {
            "semantic": np.ascontiguousarray(self.semantic, dtype=np.uint8).reshape(-1),
            "instance": np.ascontiguousarray(self.instance, dtype=np.uint32).reshape(-1),
            "transparent": np.ascontiguousarray(self.transparent, dtype=bool).reshape(-1),
            "color": np.ascontiguousarray(color, dtype=np.uint8).reshape(-1, 3),
        }
        for name, a in arrays.items():
            if len(a) != m:
                raise ValueError(f"{name} has {len(a)} entries for {m} faces")
        if m and (F.min() < 0 or F.max() >= len(V)):
            raise ValueError(f"face index outside [0, {len(V)})")
        if (self.texture is None) != (self.uv is None):
            raise ValueError("textures need both the per-triangle image index and the coordinates")
        if self.texture is not None:
            tex = np.ascontiguousarray(self.texture, dtype=np.int32).reshape(-1)
            uv = np.ascontiguousarray(self.uv, dtype=np.float32)
            if len(tex) != m or uv.shape != (m, 3, 2):
                raise ValueError(f"texture index {tex.shape} / coordinates {uv.shape} for {m} faces")
            if m and (tex.min() < -1 or tex.max() >= len(self.images)):
                raise ValueError(f"texture index outside [-1, {len(self.images)})")
            object.__setattr__(self, "texture", tex)
            object.__setattr__(self, "uv", uv)
        object.__setattr__(self, "vertices", V)
        object.__setattr__(self, "faces", F)
        for name, a in arrays.items():
            object.__setattr__(self, name, a)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(vertices, faces, semantic, instance, transparent)``, the arguments of
        ``carlaocc.catalog.panoptic.panoptic_glb_bytes``."""
        return self.vertices, self.faces, self.semantic, self.instance, self.transparent


def flatten(scene: Sequence[SceneMesh]) -> PanopticMesh:
    """Concatenate scene meshes into one mesh, in scene order, with each mesh's semantic id,
    instance id, transparent flag and base colour repeated on its triangles."""
    verts, faces, sem, inst, transp, color = [], [], [], [], [], []
    textured = any(m.image is not None for m in scene)
    tex, uvs, images, image_slot = [], [], [], {}  # one slot per image object (placements share it)
    offset = 0
    for pos, m in enumerate(scene):
        if not 0 <= int(m.semantic_id) <= 255:
            raise ValueError(f"mesh {pos} ({m.name!r}): semantic id {m.semantic_id} outside [0, 255]")
        if not 0 <= int(m.instance_id) < 2**32:
            raise ValueError(f"mesh {pos} ({m.name!r}): instance id {m.instance_id} outside uint32")
        n = len(m.faces)
        verts.append(m.vertices.reshape(-1, 3))
        faces.append(m.faces.reshape(-1, 3) + offset)
        sem.append(np.full(n, m.semantic_id, dtype=np.uint8))
        inst.append(np.full(n, m.instance_id, dtype=np.uint32))
        transp.append(np.full(n, bool(m.transparent)))
        color.append(np.tile(np.asarray(m.color[:3], np.uint8), (n, 1)))
        if textured:
            if m.image is None:
                tex.append(np.full(n, -1, np.int32))
                uvs.append(np.zeros((n, 3, 2), np.float32))
            else:
                slot = image_slot.setdefault(id(m.image), len(images))
                if slot == len(images):
                    images.append(m.image)
                tex.append(np.full(n, slot, np.int32))
                uvs.append(np.asarray(m.corner_uv, np.float32).reshape(n, 3, 2))
        offset += len(m.vertices)
    if not faces:
        return PanopticMesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.uint8),
                            np.zeros(0, np.uint32), np.zeros(0, bool))  # fmt: skip
    textures = {"texture": np.concatenate(tex), "uv": np.concatenate(uvs), "images": tuple(images)} if textured else {}
    return PanopticMesh(np.concatenate(verts), np.concatenate(faces), np.concatenate(sem),
                        np.concatenate(inst), np.concatenate(transp), np.concatenate(color), **textures)  # fmt: skip


def town_mesh(placements: Sequence[PlacementRecord], geometry: Mapping[str, AssetGeometry],
              things: frozenset[int] = DEFAULT_THINGS) -> PanopticMesh:
    """The town's unified static mesh in the world frame: every placement (by placement id) moved
    by its pose, every part whole, stuff with instance 0 and things (``things``: the label
    table's thing classes) with the placement's instance id. Raises ``ValueError`` naming a
    placement whose asset has no geometry."""
    scene: list[SceneMesh] = []
    prepared: dict[object, _Prepared] = {}
    for p in sorted(placements, key=lambda p: p.placement_id):
        prep = _prepared(prepared, p.asset_id, _placement_geometry(p, geometry), things)
        scene.extend(_emit(prep, pose_from_list(p.pose), p.instance_id, p.name, None))
    return flatten(scene)
