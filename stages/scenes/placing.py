"""Building blocks every town builder shares: tiled stuff slabs, the placement accumulator
(placement ids, instance ids, world AABBs) and the asset pools assets are drawn from.

World frame: metres, Z up. Asset frame: +X forward, origin at the bottom centre of the asset's
bounding box, so an asset of extent (l, w, h) spans ``[-l/2, l/2] x [-w/2, w/2] x [0, h]``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from carlaocc.schemas import taxonomy
from carlaocc.schemas.meshes import AssetGeometry, MeshPart
from carlaocc.schemas.records import AssetRecord, PlacementRecord
from carlaocc.stages.geometry import concatenate, is_watertight, pose_matrix, pose_to_list

__all__ = [
    "SURFACE", "STUFF_TILE", "POLE_RADIUS", "grid_slab", "slab", "slabs", "stuff_geometry", "rot2", "yaw_of", "Placer",
    "AssetPools", "box_corners_aabb",
]  # fmt: skip

SURFACE = 0.01  # m: thickness of the thin closed slabs that stand for ground surfaces
STUFF_TILE = 8.0  # m: largest tile edge of a stuff slab's top and bottom faces
POLE_RADIUS = 0.09  # m: pole radius assumed when placing pole-like assets by their pole axis
DEFAULT_THINGS: frozenset[int] = frozenset(taxonomy.thing_ids())
"""The thing classes of the default label table."""


def grid_slab(G: np.ndarray, z0: float, z1: float):
    """Closed slab ``[z0, z1]`` (m) over the quad grid ``G`` (nx + 1, ny + 1, 2) of xy points,
    in any orientation: top and bottom are the grid's quads, the sides follow its boundary
    (watertight, outward normals). Returns (vertices (N, 3), faces (M, 3))."""
    # orient the grid counter-clockwise seen from above
    e0, e1 = G[1, 0] - G[0, 0], G[0, 1] - G[0, 0]
    if e0[0] * e1[1] - e0[1] * e1[0] < 0:
        G = G[:, ::-1]
    nx1, ny1 = G.shape[:2]
    n = nx1 * ny1  # grid vertex (i, j) -> index i * ny1 + j
    flat = G.reshape(n, 2)
    top = np.column_stack([flat, np.full(n, z1)])
    bottom = np.column_stack([flat, np.full(n, z0)])
    idx = np.arange(n).reshape(nx1, ny1)
    # cell corners counter-clockwise seen from above: a (i, j), b (i+1, j), c (i+1, j+1), d (i, j+1)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = [np.column_stack([a, b, c]), np.column_stack([a, c, d])]  # top, normal +z
    faces += [np.column_stack([a, c, b]) + n, np.column_stack([a, d, c]) + n]  # bottom, normal -z
    # boundary ring, counter-clockwise seen from above; each edge p -> q gets an outward quad
    ring = np.concatenate([idx[:-1, 0], idx[-1, :-1], idx[:0:-1, -1], idx[0, :0:-1]])
    p, q = ring, np.roll(ring, -1)
    faces += [np.column_stack([p + n, q + n, q]), np.column_stack([p + n, q, p])]
    return np.vstack([top, bottom]), np.concatenate(faces).astype(np.int64)


def slab(x0: float, x1: float, y0: float, y1: float, z0: float, z1: float, tile: float = STUFF_TILE):
    """Closed axis-aligned slab ``[x0, x1] x [y0, y1] x [z0, z1]`` (m) whose top and bottom are
    grids of tiles of at most ``tile`` m (see :func:`grid_slab`)."""
    nx, ny = max(1, math.ceil((x1 - x0) / tile - 1e-9)), max(1, math.ceil((y1 - y0) / tile - 1e-9))
    gx, gy = np.meshgrid(np.linspace(x0, x1, nx + 1), np.linspace(y0, y1, ny + 1), indexing="ij")
    return grid_slab(np.stack([gx, gy], axis=-1), z0, z1)


def slabs(rects, z0: float, z1: float):
    """Tiled slabs ``[z0, z1]`` over ``rects`` (xmin, xmax, ymin, ymax) as one (vertices, faces)."""
    return concatenate([slab(r[0], r[1], r[2], r[3], z0, z1) for r in rects])


def stuff_geometry(key: str, mesh, semantic: str, material: str) -> AssetGeometry:
    """One stuff mesh (a single part named after the key's last component) from (vertices, faces)."""
    V, F = mesh
    sem = taxonomy.by_name(semantic).id
    part = MeshPart(name=key.split("/")[-1], vertices=V, faces=F, semantic_id=sem, material=material)
    return AssetGeometry(asset_id=key, parts=(part,), part_closed=(is_watertight(F),))


def rot2(yaw: float, v) -> np.ndarray:
    """Rotate the xy vector ``v`` by ``yaw`` rad about +Z."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])


def yaw_of(v) -> float:
    """Heading (rad) of the xy vector ``v``."""
    return math.atan2(float(v[1]), float(v[0]))


def box_corners_aabb(lo, hi, T: np.ndarray) -> tuple[list[float], list[float]]:
    """World AABB (min, max) of the local box ``lo .. hi`` moved by the 4x4 pose ``T``."""
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    w = corners @ T[:3, :3].T + T[:3, 3]
    return [float(v) for v in w.min(axis=0)], [float(v) for v in w.max(axis=0)]


class Placer:
    """Accumulates placement records in order: sequential placement ids, per-kind names
    (``<kind>_<nnn>``), instance ids 1.. for thing classes (``things``: the thing ids of the
    dataset's label table), 0 for stuff, and the world AABB of every placed mesh."""

    def __init__(self, town: str, things: frozenset[int] = DEFAULT_THINGS) -> None:
        self.town, self.things = town, frozenset(things)
        self.records: list[PlacementRecord] = []
        self.counts: dict[str, int] = {}
        self.next_instance = 1

    def add(self, kind: str, asset_id: str, semantic_id: int, pose: np.ndarray, local_bounds,
            named: str | None = None) -> PlacementRecord:  # fmt: skip
        """Record one placement of a mesh whose object-frame bounds are ``local_bounds`` =
        (min xyz, max xyz); ``named`` overrides the ``<kind>_<nnn>`` name (stuff)."""
        k = self.counts.get(kind, 0)
        self.counts[kind] = k + 1
        instance = 0
        if semantic_id in self.things:
            instance, self.next_instance = self.next_instance, self.next_instance + 1
        lo, hi = box_corners_aabb(local_bounds[0], local_bounds[1], np.asarray(pose, dtype=np.float64))
        rec = PlacementRecord(
            town=self.town, placement_id=len(self.records), name=named or f"{kind}_{k:03d}",
            asset_id=asset_id, mesh_path="", semantic_id=semantic_id, instance_id=instance,
            pose=pose_to_list(pose), is_thing=semantic_id in self.things, aabb_min=lo, aabb_max=hi,
        )  # fmt: skip
        self.records.append(rec)
        return rec

    def add_stuff(self, geom: AssetGeometry) -> PlacementRecord:
        """Place a world-frame stuff mesh at the identity pose, named after its key."""
        V = np.concatenate([p.vertices for p in geom.parts])
        name = geom.asset_id.split("/")[-1]
        return self.add(name, geom.asset_id, geom.parts[0].semantic_id, np.eye(4), (V.min(axis=0), V.max(axis=0)),
                        named=name)  # fmt: skip

    def add_asset(self, kind: str, asset: AssetRecord, xy, z: float, yaw: float, anchor=(0.0, 0.0)) -> PlacementRecord:
        """Place ``asset`` so its asset-frame point ``anchor`` (xy, m) lands on world ``xy`` at
        height ``z``, turned by ``yaw`` rad."""
        origin = np.asarray(xy, dtype=np.float64)[:2] - rot2(yaw, anchor)
        l, w, h = (float(e) for e in asset.extent)
        bounds = ((-l / 2, -w / 2, 0.0), (l / 2, w / 2, h))
        return self.add(kind, asset.asset_id, asset.category_id, pose_matrix(origin[0], origin[1], z, yaw), bounds)


class AssetPools:
    """Assets by category (and sub-class), sorted by (sub-class, asset id) so a town does not
    depend on the order the assets arrive in."""

    def __init__(self, assets: Sequence[AssetRecord]) -> None:
        self.by_cat: dict[str, list[AssetRecord]] = {}
        for a in sorted(assets, key=lambda a: (a.category_id, a.subclass, a.asset_id)):
            self.by_cat.setdefault(a.category, []).append(a)

    def get(self, category: str, subclasses: Sequence[str] | None = None) -> list[AssetRecord]:
        """Assets of ``category`` (restricted to ``subclasses`` when given)."""
        pool = self.by_cat.get(category, [])
        return [a for a in pool if subclasses is None or a.subclass in subclasses]

    def pick(
        self, rng: np.random.Generator, category: str, subclasses: Sequence[str] | None = None
    ) -> AssetRecord | None:
        """A uniformly drawn asset of ``category`` (and ``subclasses``), falling back to any asset
        of the category when no sub-class matches; None when the category is empty."""
        pool = self.get(category, subclasses) or self.get(category)
        return pool[int(rng.integers(len(pool)))] if pool else None
