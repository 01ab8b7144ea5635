"""Voxelization speed and agreement: our numba kernels against open3d, in one run.

Open3d's voxel (i, j, k) is ours (box centred at min_bound + (i + 0.5) * voxel_size) but it only
tries the voxels from floor(triangle min) up, so a triangle whose bounding box starts exactly on
a voxel face does not mark the voxel below that face; our boxes are closed and do. Scenes with
coordinates on the voxel lattice (poles here sit on a 0.1 m lattice) therefore give IoU < 1 with
every difference on our side; the same scene shifted off the lattice agrees to IoU 1.

A synthetic street scene in the LiDAR frame (ground at z = -1.73 m, ~40 buildings, cars, poles,
trees; several hundred thousand triangles, made with ``trimesh.creation``) is voxelized over the
default region (x [-25.6, 51.2], y [-25.6, 25.6], z [-3, 10] m):

* surface at 0.2 m and 0.05 m: ``carlaocc.stages.voxelize.surface_voxels`` against
  ``open3d.geometry.VoxelGrid.create_from_triangle_mesh_within_bounds`` plus the index extraction
  through ``get_voxels()``; both get the same mesh, pre-culled to the region. Reported: seconds,
  speed ratio and the IoU of the two voxel sets (open3d's out-of-bounds voxels dropped).
* solid fill of one building at 0.1 m: ``carlaocc.stages.voxelize.fill_interior`` against
  ``open3d.t.geometry.RaycastingScene.compute_occupancy`` on the voxel centres.
* the whole frame composed tile by tile, and its visibility masks for the default rig (every
  camera pixel, every LiDAR beam): fans (``carlaocc.stages.voxelize.visibility``, algorithm 2) against the
  same rays traced one by one by the 3D DDA (algorithm 1), with the voxels on which they differ.
* the whole frame composed (``voxelize_scene``: fusion, elevation order, fills) for reference.

The numba JIT is warmed up (compiled or loaded from its cache) before anything is timed.

Usage: ``python -m benchmarks.bench_voxelize [out.json]``.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np
import trimesh

from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.meshes import SceneMesh
from carlaocc.stages.voxelize import fill_interior, surface_voxels, voxelize_scene
from carlaocc.stages.voxelize.kernels import warmup

GROUND_Z = -1.73  # ground height in the LiDAR frame (LiDAR 1.73 m above the ground), metres
REGION_MIN = (-25.6, -25.6, -3.0)
REGION_MAX = (51.2, 25.6, 10.0)

# semantic ids (docs/architecture.md "Taxonomy")
ROAD, BUILDING, POLE, VEGETATION, CAR = 1, 3, 6, 9, 14


def _ground(rng: np.random.Generator, step: float = 0.2) -> tuple[np.ndarray, np.ndarray]:
    """Gently undulating ground grid slightly larger than the region (open surface)."""
    xs = np.arange(-30.0, 56.0 + 1e-9, step)
    ys = np.arange(-30.0, 30.0 + 1e-9, step)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    Z = GROUND_Z + 0.04 * np.sin(0.37 * X) * np.cos(0.23 * Y) + rng.normal(0, 0.003, X.shape)
    V = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    nx, ny = X.shape
    idx = np.arange(nx * ny).reshape(nx, ny)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return V, F


def _place(m: trimesh.Trimesh, x: float, y: float, z: float, yaw: float) -> trimesh.Trimesh:
    T = trimesh.transformations.rotation_matrix(yaw, (0, 0, 1))
    T[:3, 3] = (x, y, z)
    m = m.copy()
    m.apply_transform(T)
    return m


def street_scene(seed: int = 0) -> list[SceneMesh]:
    """The benchmark scene: ground (road stuff), 40 buildings, 40 cars, 30 poles, 20 trees."""
    rng = np.random.default_rng(seed)
    meshes: list[SceneMesh] = []
    V, F = _ground(rng)
    meshes.append(SceneMesh(V, F, semantic_id=ROAD, instance_id=0, is_stuff=True, closed=False, name="ground"))
    inst = 1
    # buildings: 24 boxes (faces subdivided to 0.5 m) and 16 domes (icospheres), along both sides
    for b in range(40):
        side = 1 if b % 2 else -1
        x = rng.uniform(-24.0, 50.0)
        y = side * rng.uniform(9.0, 22.0)
        if b < 24:
            ext = (rng.uniform(5, 12), rng.uniform(5, 9), rng.uniform(6, 16))
            m = trimesh.creation.box(extents=ext)
            v, f = trimesh.remesh.subdivide_to_size(m.vertices, m.faces, max_edge=0.5)
            m = trimesh.Trimesh(v, f, process=False)
            m = _place(m, x, y, GROUND_Z + ext[2] / 2, rng.uniform(-0.3, 0.3))
        else:
            r = rng.uniform(3.0, 6.0)
            m = trimesh.creation.icosphere(subdivisions=5, radius=r)
            m = _place(m, x, y, GROUND_Z + rng.uniform(-0.5, 0.5) * r, 0.0)
        meshes.append(SceneMesh(m.vertices, m.faces, semantic_id=BUILDING, instance_id=inst, is_stuff=False, closed=True, name=f"building{b}"))
        inst += 1
    # cars: body box + cabin (icosphere squashed), on the road, random yaw about the lane axis
    for c in range(40):
        body = trimesh.creation.box(extents=(4.5, 1.8, 0.9))
        v, f = trimesh.remesh.subdivide_to_size(body.vertices, body.faces, max_edge=0.25)
        body = trimesh.Trimesh(v, f, process=False)
        body.apply_translation((0, 0, 0.3 + 0.45))
        cab = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
        cab.apply_scale((1.2, 0.85, 0.5))
        cab.apply_translation((-0.3, 0, 1.2))
        x = rng.uniform(-24.0, 50.0)
        y = rng.choice([-4.5, -1.5, 1.5, 4.5]) + rng.uniform(-0.3, 0.3)
        yaw = rng.uniform(-0.15, 0.15) + (np.pi if y < 0 else 0.0)
        for part in (body, cab):
            m = _place(part, x, y, GROUND_Z, yaw)
            meshes.append(SceneMesh(m.vertices, m.faces, semantic_id=CAR, instance_id=inst, is_stuff=False, closed=True, name=f"car{c}"))
        inst += 1
    # poles (stuff): thin cylinders along the sidewalks
    for p in range(30):
        m = trimesh.creation.cylinder(radius=0.1, height=7.0, sections=24)
        m = _place(m, -24.0 + p * 2.5, (7.5 if p % 2 else -7.5), GROUND_Z + 3.5, 0.0)
        meshes.append(SceneMesh(m.vertices, m.faces, semantic_id=POLE, instance_id=0, is_stuff=True, closed=True, name=f"pole{p}"))
    # trees (stuff): trunk + crown
    for t in range(20):
        x, y = rng.uniform(-24.0, 50.0), (1 if t % 2 else -1) * rng.uniform(7.0, 8.5)
        trunk = _place(trimesh.creation.cylinder(radius=0.2, height=3.0, sections=16), x, y, GROUND_Z + 1.5, 0.0)
        crown = _place(trimesh.creation.icosphere(subdivisions=3, radius=rng.uniform(1.5, 2.5)), x, y, GROUND_Z + 4.0, 0.0)
        for m in (trunk, crown):
            meshes.append(SceneMesh(m.vertices, m.faces, semantic_id=VEGETATION, instance_id=0, is_stuff=True, closed=True, name=f"tree{t}"))
    return meshes


def merged_culled(meshes: list[SceneMesh], lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All meshes as one soup, keeping the triangles whose bounding box touches the region."""
    verts, faces, off = [], [], 0
    for m in meshes:
        verts.append(m.vertices)
        faces.append(m.faces + off)
        off += len(m.vertices)
    V, F = np.concatenate(verts), np.concatenate(faces)
    c = V[F]
    keep = np.all((c.min(axis=1) <= hi) & (c.max(axis=1) >= lo), axis=1)
    F = F[keep]
    used, F = np.unique(F, return_inverse=True)
    return V[used], F.reshape(-1, 3)


def _timed(fn, *args, repeat: int = 1):
    best, out = np.inf, None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn(*args)
        best = min(best, time.perf_counter() - t)
    return best, out


def _open3d_surface(V, F, grid: GridSpec):
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F.astype(np.int32)))
    lo = np.asarray(grid.origin, dtype=np.float64)
    hi = np.asarray(grid.effective_max, dtype=np.float64)
    t0 = time.perf_counter()
    vg = o3d.geometry.VoxelGrid.create_from_triangle_mesh_within_bounds(mesh, grid.voxel_size, lo, hi)
    t1 = time.perf_counter()
    ijk = np.array([v.grid_index for v in vg.get_voxels()], dtype=np.int64).reshape(-1, 3)
    t2 = time.perf_counter()
    shape = np.asarray(grid.shape)
    inb = np.all((ijk >= 0) & (ijk < shape), axis=1)
    lin = np.ravel_multi_index(tuple(ijk[inb].T), grid.shape)
    return t1 - t0, t2 - t1, np.unique(lin), int((~inb).sum())


def _iou(a: np.ndarray, b: np.ndarray) -> tuple[float, int, int]:
    inter = len(np.intersect1d(a, b, assume_unique=True))
    union = len(a) + len(b) - inter
    return (inter / union if union else 1.0), len(np.setdiff1d(a, b, assume_unique=True)), len(np.setdiff1d(b, a, assume_unique=True))


def _fill_vs_open3d(building: SceneMesh, voxel_size: float) -> dict:
    import open3d as o3d

    lo = building.vertices.min(axis=0) - voxel_size
    hi = building.vertices.max(axis=0) + voxel_size
    grid = GridSpec(region_min=tuple(lo), region_max=tuple(hi), voxel_size=voxel_size)
    t_ours, ours = _timed(fill_interior, building.vertices, building.faces, grid.origin, voxel_size, grid.shape, repeat=3)
    # open3d: occupancy of every voxel centre of the same grid
    nx, ny, nz = grid.shape
    I, J, K = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    centres = (np.stack([I, J, K], -1).reshape(-1, 3) + 0.5) * voxel_size + np.asarray(grid.origin)
    t0 = time.perf_counter()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(building.vertices.astype(np.float32)), o3d.core.Tensor(building.faces.astype(np.uint32))
    )
    occ = scene.compute_occupancy(o3d.core.Tensor(centres.astype(np.float32))).numpy()
    t_o3d = time.perf_counter() - t0
    theirs = np.flatnonzero(occ > 0.5)
    iou, only_ours, only_theirs = _iou(ours, theirs)
    return {
        "triangles": int(len(building.faces)),
        "grid_shape": list(grid.shape),
        "voxels_inside": int(len(ours)),
        "ours_s": t_ours,
        "open3d_s": t_o3d,
        "speedup": t_o3d / t_ours,
        "iou": iou,
        "only_ours": only_ours,
        "only_open3d": only_theirs,
    }


def _trimesh_surface(V: np.ndarray, F: np.ndarray, voxel_size: float) -> dict:
    """trimesh's ``voxelized`` (subdivide) against ours on the same mesh at ``voxel_size``: time, and how
    many fewer voxels trimesh returns than the exact surface (its own lattice, so by count)."""
    mesh = trimesh.Trimesh(V, F, process=False)
    t0 = time.perf_counter()
    vg = mesh.voxelized(pitch=voxel_size)
    pts = vg.points  # voxel centres, metres
    t_tm = time.perf_counter() - t0
    lo = np.floor(V.min(axis=0) / voxel_size) * voxel_size - voxel_size
    n = np.ceil((V.max(axis=0) - lo) / voxel_size).astype(int) + 2
    t0 = time.perf_counter()
    ours = surface_voxels(V, F, lo, voxel_size, tuple(n))
    t_ours = time.perf_counter() - t0
    # trimesh's voxels sit on its own lattice, so compare counts: a surface at the same pitch
    # has about as many voxels on any lattice, and exact overlap is the superset convention
    missing = 1.0 - len(pts) / max(len(ours), 1)
    return {"voxel_size": voxel_size, "trimesh_s": t_tm, "ours_s": t_ours, "speedup": t_tm / t_ours,
            "trimesh_voxels": int(len(pts)), "ours_voxels": int(len(ours)), "trimesh_missing": float(missing)}


def main(argv: list[str] | None = None) -> dict:
    """Run the benchmark and print the tables; ``argv[0]``, if given, is a JSON output path.

    (``python -m benchmarks`` calls ``main()`` with no arguments: nothing is written.)
    """
    argv = [] if argv is None else argv
    import numba

    t = time.perf_counter()
    warmup()
    print(f"numba JIT warm-up (compile or cache load, not timed below): {time.perf_counter() - t:.2f} s; "
          f"numba threads: {numba.get_num_threads()} ({numba.threading_layer()})")
    meshes = street_scene()
    lo, hi = np.asarray(REGION_MIN), np.asarray(REGION_MAX)
    V, F = merged_culled(meshes, lo, hi)
    print(f"scene: {len(meshes)} meshes, {sum(len(m.faces) for m in meshes):,} triangles; "
          f"{len(F):,} triangles / {len(V):,} vertices touch the region")
    results: dict = {"triangles_in_region": int(len(F)), "surface": [], "fill": None, "compose": []}

    print()
    print("surface voxels (same pre-culled mesh; open3d = create_from_triangle_mesh_within_bounds + get_voxels;")
    print("  'x build' / 'x total' = open3d's build / build + index extraction time over ours on 2 threads)")
    hdr = f"{'voxel':>5} {'voxels':>11} {'ours 2thr':>9} {'ours 1thr':>9} {'o3d build':>9} {'o3d get':>8} {'o3d total':>9} {'x build':>7} {'x total':>7} {'IoU':>9} {'only ours':>9} {'only o3d':>8} {'o3d oob':>7}"
    print(hdr)
    for voxel_size in (0.1, 0.05):
        grid = GridSpec(region_min=REGION_MIN, region_max=REGION_MAX, voxel_size=voxel_size)
        nthreads = numba.get_num_threads()
        t2, ours = _timed(surface_voxels, V, F, grid.origin, voxel_size, grid.shape, repeat=2)
        numba.set_num_threads(1)
        t1, _ = _timed(surface_voxels, V, F, grid.origin, voxel_size, grid.shape, repeat=1)
        numba.set_num_threads(nthreads)
        tb, tg, theirs, oob = _open3d_surface(V, F, grid)
        iou, only_ours, only_theirs = _iou(ours, theirs)
        row = {
            "voxel_size": voxel_size, "shape": list(grid.shape), "voxels": int(len(ours)),
            "ours_s": t2, "ours_1thread_s": t1, "open3d_build_s": tb, "open3d_get_voxels_s": tg,
            "open3d_total_s": tb + tg, "speedup_vs_build": tb / t2, "speedup_vs_total": (tb + tg) / t2,
            "iou": iou, "only_ours": only_ours, "only_open3d": only_theirs, "open3d_out_of_bounds": oob,
        }
        results["surface"].append(row)
        print(f"{voxel_size:>5} {len(ours):>11,} {t2:>8.3f}s {t1:>8.3f}s {tb:>8.2f}s {tg:>7.2f}s {tb + tg:>8.2f}s "
              f"{tb / t2:>6.1f}x {(tb + tg) / t2:>6.1f}x {iou:>9.6f} {only_ours:>9,} {only_theirs:>8,} {oob:>7,}")
        del ours, theirs

    # the same comparison with the scene shifted by a sub-voxel offset: no vertex or face lies
    # exactly on a voxel boundary any more, so the closed-box (ours) / floor-range (open3d)
    # boundary conventions can no longer differ
    shift = np.array([0.0123, 0.0071, 0.0037])
    grid = GridSpec(region_min=REGION_MIN, region_max=REGION_MAX, voxel_size=0.2)
    ours = surface_voxels(V + shift, F, grid.origin, 0.2, grid.shape)
    _, _, theirs, _ = _open3d_surface(V + shift, F, grid)
    iou, only_ours, only_theirs = _iou(ours, theirs)
    results["surface_shifted_0.2"] = {"shift_m": shift.tolist(), "iou": iou, "only_ours": only_ours, "only_open3d": only_theirs}
    print(f"  0.2 m, scene shifted by {tuple(float(x) for x in shift)} m (no exact boundary ties): IoU {iou:.6f} "
          f"(only ours {only_ours:,}, only open3d {only_theirs:,})")

    print()
    print("trimesh's voxelizer (mesh.voxelized(pitch), 'subdivide' method) at 0.5 m on the same culled mesh")
    tm = _trimesh_surface(V, F, 0.5)
    results["trimesh"] = tm
    print(f"  trimesh {tm['trimesh_s']:.2f} s ({tm['trimesh_voxels']:,} voxels), ours {tm['ours_s'] * 1e3:.1f} ms "
          f"({tm['ours_voxels']:,} voxels): {tm['speedup']:.0f}x; trimesh returns {tm['trimesh_missing']:.1%} fewer voxels")

    print()
    print("solid fill of one building at 0.1 m (ours: column parity; open3d: RaycastingScene.compute_occupancy on voxel centres, incl. BVH build)")
    building = max((m for m in meshes if m.semantic_id == BUILDING and m.name.startswith("building") and len(m.faces) < 20000),
                   key=lambda m: np.ptp(m.vertices, axis=0).prod())
    fill = _fill_vs_open3d(building, 0.1)
    results["fill"] = fill
    print(f"  {fill['triangles']:,} triangles, grid {tuple(fill['grid_shape'])}, {fill['voxels_inside']:,} voxels inside: "
          f"ours {fill['ours_s'] * 1e3:.1f} ms, open3d {fill['open3d_s'] * 1e3:.0f} ms ({fill['speedup']:.0f}x); "
          f"IoU {fill['iou']:.6f} (only ours {fill['only_ours']}, only open3d {fill['only_open3d']})")

    print()
    print("whole frame composed tile by tile (voxelize_tiles, 128-voxel x-slabs, buffers reused: the pipeline's")
    print("  path) and the camera/LiDAR visibility masks of the default rig (every pixel of the six cameras, the")
    print("  LiDAR's beams) traced as fans, against the same rays traced one by one by the 3D DDA; 1 and 2 threads")
    from carlaocc.schemas.rig import RigConfig
    from carlaocc.stages.voxelize import voxelize_tiles
    from carlaocc.stages.voxelize import visibility as vis

    vis.warmup()
    rig = RigConfig()
    poses = vis.sensor_to_lidar(rig)
    results["tiles"] = []
    for voxel_size in (0.2, 0.05):
        grid = GridSpec(region_min=REGION_MIN, region_max=REGION_MAX, voxel_size=voxel_size)
        sem = np.zeros(grid.shape, np.uint8)
        row = {"voxel_size": voxel_size}
        for threads in (1, numba.get_num_threads()):
            numba.set_num_threads(threads)
            for _ in range(2):  # the first pass maps the reused buffers
                t0 = time.perf_counter()
                for tile in voxelize_tiles(meshes, grid, 128):
                    sem[tile.x0:tile.x0 + tile.semantic.shape[0]] = tile.semantic
                t_tiles = time.perf_counter() - t0
            packed = vis.pack_occupancy(sem, grid)
            t_fans, t_rays = [], []
            for _ in range(2):
                t0 = time.perf_counter()
                fans = [vis.lidar_visibility_bits(packed, rig).copy(), vis.camera_visibility_bits(packed, rig).copy()]
                t_fans.append(time.perf_counter() - t0)
            # the same rays one by one (3D DDA): the LiDAR's beams and every camera pixel
            maxr = float(np.linalg.norm(np.asarray(grid.shape) * voxel_size))
            t0 = time.perf_counter()
            lid = packed.new_mask("bench_lidar")
            packed.trace(lid, np.zeros(3), vis.lidar_directions(rig.lidar), rig.lidar.range_m)
            cam = packed.new_mask("bench_camera")
            for c in rig.cameras:
                packed.trace(cam, *vis.camera_rays(c, poses[c.name]), maxr)
            t_rays.append(time.perf_counter() - t0)
            n_rays = sum(c.width * c.height for c in rig.cameras) + len(vis.lidar_directions(rig.lidar))
            agree = []
            for a, b in zip(fans, (lid, cam)):
                ma = packed.or_into(a, np.zeros(grid.shape, np.uint8))
                mb = packed.or_into(b, np.zeros(grid.shape, np.uint8))
                agree.append((int(mb.sum()), int((ma != mb).sum())))
                del ma, mb
            row.update({f"tiles_{threads}thread_s": t_tiles, f"masks_fans_{threads}thread_s": min(t_fans),
                        f"masks_dda_{threads}thread_s": min(t_rays), "rays": n_rays,
                        "lidar_observed": agree[0][0], "lidar_differ": agree[0][1],
                        "camera_observed": agree[1][0], "camera_differ": agree[1][1]})
            print(f"  {voxel_size:>5} m, {threads} thread(s): composed {t_tiles:.2f} s; masks ({n_rays / 1e6:.2f} M rays) as fans "
                  f"{min(t_fans):.2f} s, ray by ray {min(t_rays):.2f} s ({min(t_rays) / min(t_fans):.1f}x); voxels that "
                  f"differ: LiDAR {agree[0][1]:,} of {agree[0][0]:,}, camera {agree[1][1]:,} of {agree[1][0]:,}")
        numba.set_num_threads(nthreads)
        results["tiles"].append(row)
        del sem, packed

    print()
    print("whole frame composed (voxelize_scene: stuff fusion, cull, elevation order, surfaces + fills;")
    print("  first call on fresh memory, then a repeat: the difference is first-touch page faults of the outputs)")
    for voxel_size in (0.2, 0.05):
        grid = GridSpec(region_min=REGION_MIN, region_max=REGION_MAX, voxel_size=voxel_size)
        t_first, (sem, inst) = _timed(voxelize_scene, meshes, grid)
        del sem, inst
        t_again, (sem, inst) = _timed(voxelize_scene, meshes, grid)
        occ = int(np.count_nonzero(sem))
        results["compose"].append({"voxel_size": voxel_size, "first_s": t_first, "repeat_s": t_again, "occupied": occ,
                                   "occupied_fraction": occ / sem.size})
        print(f"  {voxel_size:>5} m: {t_first:.3f} s first, {t_again:.3f} s repeat; {occ:,} occupied voxels ({occ / sem.size:.2%})")
        del sem, inst

    if argv:
        with open(argv[0], "w") as fh:
            json.dump(results, fh, indent=2)
        print(f"\nwrote {argv[0]}")
    return results


if __name__ == "__main__":
    main(sys.argv[1:])
