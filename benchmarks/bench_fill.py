"""Solid fill of real, non-watertight meshes: what it costs and what it recovers.

1. **Models** (``../shared/testdata/meshes``: Kenney buildings, props and a Cesium truck, open
   where their parts meet; the Scenic BMW hull, watertight) voxelized alone at 0.05 m, each scaled
   to its real-world size: surface only against ``auto`` (winding numbers for the open ones,
   column parity for the closed one), and the winding-number fill against the same tree queried
   at every voxel centre of the bounding box (the direct way; IoU between the two).
2. **A street of real meshes** on the default 0.05 m grid (1536 x 1024 x 260): 24 buildings
   and 30 trucks of those models, a road plane; the frame's composition with ``fill="surface"``
   against ``fill="auto"`` -- what the fill adds to a frame full of open meshes.

One process, numba on one thread, JIT warmed first; the best of ``repeats`` runs.

Usage: ``python -m benchmarks.bench_fill [repeats] [out.json]``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numba
import numpy as np

from benchmarks.common import save_json

ROOT = Path(__file__).resolve().parents[1]
MESHES = ROOT.parent / "shared" / "testdata" / "meshes"
# (file, class, longest side in metres after scaling: the object's real size)
MODELS = (
    ("kenney-suburban/building-type-a.glb", "Building", 12.0),
    ("kenney-retro-urban/detail-light-traffic.glb", "TrafficLight", 4.5),
    ("kenney-retro-urban/detail-bench.glb", "Static", 1.8),
    ("kenney-roads/construction-cone.glb", "Static", 0.7),
    ("cesium/CesiumMilkTruck.glb", "Truck", 6.0),
    ("scenic/bmwx5_hull.obj", "Car", 4.9),
)


def _load(rel: str, longest: float) -> tuple[np.ndarray, np.ndarray]:
    """The model as one welded mesh, Z up, scaled so its longest side is ``longest`` metres,
    standing on z = 0 and centred in x, y."""
    import trimesh

    m = trimesh.load(str(MESHES / rel), force="mesh", process=False)
    V = np.asarray(m.vertices, dtype=np.float64)
    F = np.asarray(m.faces, dtype=np.int64)
    V, inverse = np.unique(V, axis=0, return_inverse=True)
    F = inverse.reshape(-1)[F]
    if rel.endswith(".glb"):
        V = V[:, [0, 2, 1]] * np.array([1.0, -1.0, 1.0])  # glTF is Y up: to Z up (a proper rotation)
    lo, hi = V.min(axis=0), V.max(axis=0)
    V = (V - np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])) * (longest / float((hi - lo).max()))
    return V, F


def _best(fn, repeats: int) -> tuple[float, object]:
    best, out = np.inf, None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def models(repeats: int) -> list[dict]:
    from carlaocc.schemas import taxonomy
    from carlaocc.schemas.grid import GridSpec
    from carlaocc.schemas.meshes import SceneMesh
    from carlaocc.stages.geometry import is_watertight
    from carlaocc.stages.voxelize.breakdown import fill_breakdown
    from carlaocc.stages.voxelize.compose import voxelize_scene
    from carlaocc.stages.voxelize.kernels import to_voxel_units
    from carlaocc.stages.voxelize.winding import INSIDE, winding_numbers, winding_tree

    rows = []
    print(f"{'model':<42} {'tris':>6} {'closed':>6} {'surface':>9} {'filled':>9} {'holes':>9} "
          f"{'t surf':>7} {'t auto':>7} {'every centre':>12} {'IoU':>6}")
    for rel, cls_name, longest in MODELS:
        V, F = _load(rel, longest)
        cls = taxonomy.by_name(cls_name)
        mesh = SceneMesh(V, F, cls.id, 1 if cls.kind == "thing" else 0, cls.kind != "thing", is_watertight(F),
                         name=rel)
        voxel_size = 0.05
        lo = np.floor(V.min(axis=0) / voxel_size) * voxel_size - voxel_size
        hi = np.ceil(V.max(axis=0) / voxel_size) * voxel_size + voxel_size
        grid = GridSpec(region_min=tuple(lo), region_max=tuple(hi), voxel_size=voxel_size)
        t_surf, _ = _best(lambda: voxelize_scene([mesh], grid, fill="surface"), repeats)
        t_auto, (sem, _) = _best(lambda: voxelize_scene([mesh], grid, fill="auto"), repeats)
        b = fill_breakdown([mesh], grid, "auto", solid=sem)
        # the direct way: the same tree at every voxel centre of the grid
        P = to_voxel_units(V, grid.origin, voxel_size)
        X, Y, Z = grid.shape
        centres = np.stack(np.meshgrid(np.arange(X), np.arange(Y), np.arange(Z), indexing="ij"), -1).reshape(-1, 3) + 0.5

        def direct():
            return winding_numbers(winding_tree(P, F), centres) > INSIDE

        t_direct, inside = _best(direct, 1)
        solid_direct = inside.reshape(grid.shape) | (voxelize_scene([mesh], grid, fill="surface")[0] > 0)
        ours = sem > 0
        iou = float((ours & solid_direct).sum() / max((ours | solid_direct).sum(), 1))
        row = {"model": rel, "class": cls_name, "triangles": int(len(F)), "watertight": bool(mesh.closed),
               "grid": list(grid.shape), "surface_voxels": b.surface, "filled_voxels": b.filled,
               "hole_voxels": b.from_holes, "surface_s": t_surf, "auto_s": t_auto, "every_centre_s": t_direct,
               "iou_vs_every_centre": iou}
        rows.append(row)
        print(f"{rel:<42} {len(F):>6} {'yes' if mesh.closed else 'no':>6} {b.surface:>9,} {b.filled:>9,} "
              f"{b.from_holes:>9,} {t_surf:>6.3f}s {t_auto:>6.3f}s {t_direct:>11.3f}s {iou:>6.4f}")
    return rows


def street(repeats: int) -> dict:
    from carlaocc.schemas import taxonomy
    from carlaocc.schemas.configs import DatasetConfig
    from carlaocc.schemas.meshes import SceneMesh
    from carlaocc.stages.geometry import is_watertight
    from carlaocc.stages.voxelize.compose import voxelize_tiles

    grid = DatasetConfig().voxelize.grid(0.05)
    lo, hi = np.asarray(grid.origin), np.asarray(grid.effective_max)
    rng = np.random.default_rng(7)
    building = _load(MODELS[0][0], 14.0)
    truck = _load(MODELS[4][0], 6.0)
    meshes = []
    # a road plane over the whole region
    V = np.array([[lo[0], lo[1], -1.7], [hi[0], lo[1], -1.7], [hi[0], hi[1], -1.7], [lo[0], hi[1], -1.7]])
    meshes.append(SceneMesh(V, np.array([[0, 1, 2], [0, 2, 3]]), taxonomy.by_name("Road").id, 0, True, False))
    inst = 1
    # buildings in two rows along the street, trucks on it
    for side in (-1, 1):
        for n in range(12):
            x = lo[0] + 4.0 + n * 6.5
            T = np.array([x, side * (18.0 + rng.uniform(0, 3)), -1.7])
            meshes.append(SceneMesh(building[0] + T, building[1], taxonomy.by_name("Building").id, inst, False,
                                    is_watertight(building[1])))
            inst += 1
    for n in range(30):
        T = np.array([rng.uniform(lo[0] + 3, hi[0] - 3), rng.uniform(-9, 9), -1.7])
        meshes.append(SceneMesh(truck[0] + T, truck[1], taxonomy.by_name("Truck").id, inst, False,
                                is_watertight(truck[1])))
        inst += 1

    def compose(fill):
        occupied = 0
        for tile in voxelize_tiles(meshes, grid, 128, fill):
            occupied += int(np.count_nonzero(tile.semantic))
        return occupied

    t_surf, n_surf = _best(lambda: compose("surface"), repeats)
    t_auto, n_auto = _best(lambda: compose("auto"), repeats)
    out = {"grid": list(grid.shape), "meshes": len(meshes), "open_meshes": sum(not m.closed for m in meshes),
           "surface_s": t_surf, "auto_s": t_auto, "added": t_auto / t_surf - 1.0,
           "surface_voxels": n_surf, "auto_voxels": n_auto}
    print(f"street of real meshes at 0.05 m ({out['meshes']} meshes, {out['open_meshes']} open): "
          f"surface {t_surf:.2f} s ({n_surf:,} voxels), auto {t_auto:.2f} s ({n_auto:,} voxels): "
          f"fill adds {100 * out['added']:.0f} %")
    return out


def main(argv: list[str] | None = None) -> dict:
    argv = [] if argv is None else argv
    repeats = int(argv[0]) if argv else 3
    numba.set_num_threads(1)
    from carlaocc.stages.voxelize import kernels, winding

    kernels.warmup()
    winding.warmup()
    results = {"repeats": repeats, "models": models(repeats), "street": street(repeats)}
    save_json(argv, 1, results)
    return results


if __name__ == "__main__":
    main(sys.argv[1:])
