"""Per-frame panoptic scene assembly (stages.scenes.assembly) on small hand-made towns."""

from __future__ import annotations

import random

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from carlaocc.schemas import taxonomy
from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.meshes import AssetGeometry, MeshPart
from carlaocc.schemas.records import ActorStateRecord, FrameRecord, PlacementRecord
from carlaocc.stages.geometry import invert_pose, pose_matrix, pose_to_list, transform_points
from carlaocc.stages.scenes import assembly
from carlaocc.stages.scenes.assembly import (
    PanopticMesh,
    PlacementIndex,
    assemble_frame,
    flatten,
    frame_region,
    region_of_grid,
    town_mesh,
)

ROAD, BUILDING, CAR, PED, POLE = (taxonomy.by_name(n).id for n in ("Road", "Building", "Car", "Pedestrian", "Pole"))
VEGETATION, FENCE = taxonomy.by_name("Vegetation").id, taxonomy.by_name("Fence").id
BOX_F = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                  [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]])  # fmt: skip


def box(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    V = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    return V, BOX_F.copy()


def grid_mesh(x0, x1, y0, y1, n) -> tuple[np.ndarray, np.ndarray]:
    """A flat z=0 square grid of n x n cells, two triangles each."""
    xs, ys = np.linspace(x0, x1, n + 1), np.linspace(y0, y1, n + 1)
    V = np.array([[x, y, 0.0] for y in ys for x in xs])
    F = []
    for j in range(n):
        for i in range(n):
            a, b, c, d = j * (n + 1) + i, j * (n + 1) + i + 1, (j + 1) * (n + 1) + i, (j + 1) * (n + 1) + i + 1
            F += [[a, b, d], [a, d, c]]
    return V, np.array(F)


def geom(asset_id, *parts) -> AssetGeometry:
    """parts: (name, (V, F), semantic, closed, transparent)."""
    mp = tuple(MeshPart(n, vf[0], vf[1], s, transparent=t) for n, vf, s, _, t in parts)
    return AssetGeometry(asset_id, mp, tuple(c for *_, c, _ in parts))


CAR_G = geom("car", ("body", box([-2, -1, 0], [2, 1, 1.5]), CAR, True, False),
             ("glass", box([-1, -0.9, 1.5], [1, 0.9, 1.6]), CAR, True, True))  # fmt: skip
HOUSE_G = geom("house", ("walls", box([-5, -5, 0], [5, 5, 8]), BUILDING, True, False))
POLE_G = geom("pole", ("pole", box([-0.1, -0.1, 0], [0.1, 0.1, 5]), POLE, True, False))
PED_G = geom("ped", ("body", box([-0.3, -0.3, 0], [0.3, 0.3, 1.7]), PED, True, False))
ROAD_G = geom("T/road", ("road", grid_mesh(-200, 200, -200, 200, 80), ROAD, False, False))
GEOMETRY = {g.asset_id: g for g in (CAR_G, HOUSE_G, POLE_G, PED_G, ROAD_G)}
V1_THINGS = frozenset(taxonomy.thing_ids("carlaocc-v1"))  # Building a thing, poles stuff


def place(pid, g: AssetGeometry, x=0.0, y=0.0, z=0.0, yaw=0.0, instance=None, name=None) -> PlacementRecord:
    T = pose_matrix(x, y, z, yaw)
    V = transform_points(T, np.concatenate([p.vertices for p in g.parts]))
    thing = any(p.semantic_id in taxonomy.thing_ids() for p in g.parts)
    return PlacementRecord(
        town="T", placement_id=pid, name=name or f"{g.asset_id}_{pid}", asset_id=g.asset_id, mesh_path="",
        semantic_id=g.parts[0].semantic_id, instance_id=(instance if instance is not None else (pid if thing else 0)),
        pose=pose_to_list(T), is_thing=thing, aabb_min=V.min(axis=0).tolist(), aabb_max=V.max(axis=0).tolist(),
    )  # fmt: skip


def frame(x=0.0, y=0.0, yaw=0.0, index=0, seq="s") -> FrameRecord:
    ego = pose_matrix(x, y, 0.0, yaw)
    lidar = ego @ pose_matrix(0.0, 0.0, 1.73, 0.0)
    return FrameRecord(sequence_id=seq, frame_index=index, timestamp=index * 0.1,
                       ego_pose=pose_to_list(ego), lidar_pose=pose_to_list(lidar))  # fmt: skip


def actor(inst, g: AssetGeometry, x, y, yaw=0.0, index=0, seq="s", phase=None, sem=CAR) -> ActorStateRecord:
    return ActorStateRecord(
        sequence_id=seq, frame_index=index, instance_id=inst, asset_id=g.asset_id, semantic_id=sem,
        pose=pose_to_list(pose_matrix(x, y, 0.0, yaw)), box_center=[x, y, 0.75], box_size=[4.0, 2.0, 1.5],
        yaw=yaw, velocity=[0.0, 0.0, 0.0], angular_velocity=[0.0, 0.0, 0.0], phase_index=phase,
    )  # fmt: skip


REGION = (np.array([-25.6, -25.6, -3.0]), np.array([51.2, 25.6, 10.0]))


def tri_touches(V, F, lo, hi) -> np.ndarray:
    t = V[F]
    return np.all((t.min(axis=1) <= hi) & (t.max(axis=1) >= lo), axis=1)


# -- selection ------------------------------------------------------------------------------------


coord = st.integers(-20, 20).map(float)


@st.composite
def boxes(draw):
    a = np.array([draw(coord) for _ in range(3)])
    b = np.array([draw(coord) for _ in range(3)])
    return np.minimum(a, b), np.maximum(a, b)


@settings(max_examples=60, deadline=None)
@given(aabbs=st.lists(boxes(), min_size=0, max_size=40), query=boxes(), seed=st.integers(0, 2**16))
def test_select_agrees_with_brute_force(aabbs, query, seed):
    # integer coordinates make touching faces common; ids shuffled so sorting matters
    ids = list(range(len(aabbs)))
    random.Random(seed).shuffle(ids)
    placements = [
        PlacementRecord(town="T", placement_id=pid, name=f"p{pid}", asset_id="a", mesh_path="", semantic_id=ROAD,
                        instance_id=0, pose=pose_to_list(np.eye(4)), is_thing=False,
                        aabb_min=lo.tolist(), aabb_max=hi.tolist())
        for pid, (lo, hi) in zip(ids, aabbs)
    ]
    index = PlacementIndex(placements)
    qlo, qhi = query
    expected = sorted(
        p.placement_id for p in placements
        if all(p.aabb_min[k] <= qhi[k] and p.aabb_max[k] >= qlo[k] for k in range(3))
    )  # fmt: skip
    got = index.select(qlo, qhi)
    assert [index.placements[i].placement_id for i in got] == expected
    assert np.all(np.diff(got) > 0)


def test_select_touching_is_kept_missing_is_dropped():
    index = PlacementIndex([place(0, POLE_G, x=10.0)])  # AABB x in [9.9, 10.1]
    assert list(index.select([10.1, -1, -1], [20, 1, 1])) == [0]  # touches the +x face
    assert list(index.select([10.1 + 1e-9, -1, -1], [20, 1, 1])) == []
    assert list(index.select([0, -1, 5.0], [9.9, 1, 6])) == [0]  # touches an edge (x and z)
    assert list(index.select([0, -1, 5.0 + 1e-9], [9.9, 1, 6])) == []
    with pytest.raises(ValueError, match="aabb_min"):
        PlacementIndex([place(0, POLE_G).model_copy(update={"aabb_min": [1.0, 0.0, 0.0], "aabb_max": [0.0, 1.0, 1.0]})])


def test_touching_placement_kept_in_assembly():
    # identity-yaw frame: the region in world is REGION + (0, 0, 1.73); a pole whose AABB just touches
    # the +x face is kept, one a millimetre further is dropped
    hi_x = REGION[1][0]
    index = PlacementIndex([place(1, POLE_G, x=hi_x + 0.1), place(2, POLE_G, x=hi_x + 0.101)])
    out = assemble_frame(frame(), [], index, GEOMETRY, REGION)
    assert [m.name for m in out] == ["pole_1/pole"]


def test_frame_region_is_world_box_of_rotated_region():
    lo, hi = np.array([0.0, -1.0, -2.0]), np.array([10.0, 1.0, 3.0])
    wlo, whi = frame_region(frame(x=100.0, y=50.0, yaw=np.pi / 2), lo, hi)
    # yaw 90: lidar x -> world +y, lidar y -> world -x; lidar at z 1.73
    np.testing.assert_allclose(wlo, [99.0, 50.0, -0.27], atol=1e-12)
    np.testing.assert_allclose(whi, [101.0, 60.0, 4.73], atol=1e-12)
    wlo, whi = frame_region(frame(yaw=np.pi / 4), np.array([-1.0, -1, 0]), np.array([1.0, 1, 0]))
    np.testing.assert_allclose(whi[:2], [np.sqrt(2), np.sqrt(2)], atol=1e-12)


def test_region_of_grid():
    grid = GridSpec(voxel_size=0.5)  # 153.6 voxels on x: grown to 154
    lo, hi = region_of_grid(grid, margin=0.5)
    np.testing.assert_allclose(lo, np.array(grid.origin) - 0.5)
    np.testing.assert_allclose(hi, np.array(grid.effective_max) + 0.5)
    assert hi[0] == pytest.approx(-25.6 + 154 * 0.5 + 0.5)  # 51.4 grown by the margin


# -- assembly -------------------------------------------------------------------------------------


def test_vertices_moved_into_lidar_frame():
    f = frame(x=10.0, y=5.0, yaw=np.pi / 2)
    index = PlacementIndex([place(3, HOUSE_G, x=20.0, y=5.0, instance=3)])
    (m,) = assemble_frame(f, [], index, GEOMETRY, (np.array([-100.0] * 3), np.array([100.0] * 3)))
    # asset vertex (5, 5, 8) -> world (25, 10, 8); minus lidar (10, 5, 1.73) = (15, 5, 6.27);
    # rotated by -90 deg about z: (x, y) -> (y, -x) = (5, -15)
    k = int(np.flatnonzero(np.all(HOUSE_G.parts[0].vertices == [5, 5, 8], axis=1))[0])
    np.testing.assert_allclose(m.vertices[k], [5.0, -15.0, 6.27], atol=1e-12)
    # the release's table: a building is stuff (instance 0), kept closed (it is filled)
    assert (m.semantic_id, m.instance_id, m.is_stuff, m.closed) == (BUILDING, 0, True, True)
    # carlaocc-v1: a building is a thing with its placement's instance
    (m,) = assemble_frame(f, [], index, GEOMETRY, (np.array([-100.0] * 3), np.array([100.0] * 3)), things=V1_THINGS)
    assert (m.semantic_id, m.instance_id, m.is_stuff, m.closed) == (BUILDING, 3, False, True)


@pytest.mark.parametrize("big_stuff", [True, False], ids=["precull-big-stuff", "direct"])
def test_stuff_culled_per_triangle_and_things_whole(big_stuff, monkeypatch):
    # the road (12 800 triangles) goes through the asset-frame pre-cull or, with the threshold
    # raised, through the direct per-triangle test: both give exactly the touching triangles
    if not big_stuff:
        monkeypatch.setattr(assembly, "_BIG_STUFF", 10**9)
    f = frame(x=3.0, y=-2.0, yaw=0.3)
    index = PlacementIndex([
        place(0, ROAD_G, name="road"),
        place(1, HOUSE_G, x=52.0, y=3.0, yaw=0.3),  # straddles the +x border: kept whole
        place(2, HOUSE_G, x=120.0, y=3.0),  # far away: dropped
    ])  # fmt: skip
    out = assemble_frame(f, [], index, GEOMETRY, REGION)
    assert [m.name for m in out] == ["road/road", "house_1/walls"]
    road, house = out
    assert road.is_stuff and road.instance_id == 0 and not road.closed
    # exactly the road triangles whose LiDAR-frame bounding box touches the region
    T = invert_pose(np.array(f.lidar_pose).reshape(4, 4))
    V = transform_points(T, ROAD_G.parts[0].vertices)
    expected = tri_touches(V, ROAD_G.parts[0].faces, *REGION)
    assert 0 < expected.sum() < len(expected)
    assert len(road.faces) == expected.sum()
    np.testing.assert_allclose(np.sort(road.vertices[road.faces].reshape(len(road.faces), -1), axis=0),
                               np.sort(V[ROAD_G.parts[0].faces[expected]].reshape(int(expected.sum()), -1), axis=0))
    assert len(np.unique(road.faces)) == len(road.vertices)  # unused vertices dropped
    # the house sticks out of the region but keeps all 12 faces
    assert len(house.faces) == 12 and house.vertices[:, 0].max() > REGION[1][0]


def test_transparent_flag_carried():
    out = assemble_frame(frame(), [actor(7, CAR_G, 10.0, 0.0)], PlacementIndex([]), GEOMETRY, REGION)
    assert [(m.name, m.transparent, m.closed, m.instance_id) for m in out] == [
        ("actor_7/body", False, True, 7), ("actor_7/glass", True, True, 7)]


def test_ego_excluded():
    f = frame(x=5.0, y=1.0, yaw=0.2)
    ego = actor(1, CAR_G, 5.0, 1.0, yaw=0.2)
    other = actor(2, CAR_G, 15.0, 1.0, yaw=0.2)
    out = assemble_frame(f, [ego, other], PlacementIndex([]), GEOMETRY, REGION, ego_asset_id="car")
    assert {m.instance_id for m in out} == {2}
    # an actor at the ego pose with another asset is not the ego when the ego asset is known ...
    ped_there = actor(3, PED_G, 5.0, 1.0, yaw=0.2, sem=PED)
    out = assemble_frame(f, [ped_there], PlacementIndex([]), GEOMETRY, REGION, ego_asset_id="car")
    assert {m.instance_id for m in out} == {3}
    # ... and anything at the ego pose is when it is not
    assert assemble_frame(f, [ego], PlacementIndex([]), GEOMETRY, REGION) == []


def test_pedestrian_geometry_by_phase():
    calls = []

    def phases(asset_id: str, phase: int) -> AssetGeometry:
        calls.append((asset_id, phase))
        if phase > 10:
            raise KeyError(phase)
        # a body whose height encodes the phase
        return geom(asset_id, ("body", box([-0.3, -0.3, 0], [0.3, 0.3, 1.0 + 0.01 * phase]), PED, True, False))

    walkers = [actor(4, PED_G, 8.0, 2.0, phase=3, sem=PED), actor(5, PED_G, 9.0, 2.0, phase=None, sem=PED)]
    out = assemble_frame(frame(), walkers, PlacementIndex([]), GEOMETRY, REGION, pedestrian_geometry=phases)
    assert calls == [("ped", 3)]
    top = {m.instance_id: m.vertices[:, 2].max() + 1.73 for m in out}  # lidar z -> ground z
    assert top[4] == pytest.approx(1.03) and top[5] == pytest.approx(1.7)  # phase 3 / rest
    # without a phase source the rest geometry is used
    out = assemble_frame(frame(), walkers, PlacementIndex([]), GEOMETRY, REGION)
    assert [m.vertices[:, 2].max() + 1.73 for m in out] == pytest.approx([1.7, 1.7])
    with pytest.raises(ValueError, match="actor 6 .*'ped'.*phase 11"):
        assemble_frame(frame(), [actor(6, PED_G, 8.0, 2.0, phase=11, sem=PED)], PlacementIndex([]), GEOMETRY,
                       REGION, pedestrian_geometry=phases)  # fmt: skip


def test_missing_geometry_names_the_culprit():
    index = PlacementIndex([place(9, HOUSE_G, x=10.0, name="building_009")])
    with pytest.raises(ValueError, match="placement 9 \\('building_009'\\).*'house'"):
        assemble_frame(frame(), [], index, {}, REGION)
    with pytest.raises(ValueError, match="actor 4 uses asset 'car'"):
        assemble_frame(frame(), [actor(4, CAR_G, 10.0, 0.0)], PlacementIndex([]), {}, REGION)
    # geometry is needed only for what the frame selects
    far = PlacementIndex([place(9, HOUSE_G, x=500.0)])
    assert assemble_frame(frame(), [], far, {}, REGION) == []


def test_order_is_deterministic_and_only_this_frames_actors():
    placements = [place(pid, POLE_G, x=2.0 * pid, y=3.0) for pid in range(12)] + [place(50, ROAD_G, name="road")]
    actors = [actor(i, CAR_G, 5.0 * i, -4.0) for i in (8, 3, 5)]
    actors += [actor(1, CAR_G, 5.0, -4.0, index=1), actor(2, CAR_G, 5.0, -4.0, seq="other")]
    shuffled = placements[:]
    random.Random(3).shuffle(shuffled)
    a = assemble_frame(frame(yaw=0.1), actors, PlacementIndex(placements), GEOMETRY, REGION)
    b = assemble_frame(frame(yaw=0.1), actors[::-1], PlacementIndex(shuffled), GEOMETRY, REGION)
    assert [m.name for m in a] == [f"pole_{i}/pole" for i in range(12)] + ["road/road"] + [
        f"actor_{i}/{p}" for i in (3, 5, 8) for p in ("body", "glass")]
    assert [m.name for m in a] == [m.name for m in b]
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x.vertices, y.vertices)
        np.testing.assert_array_equal(x.faces, y.faces)


@settings(max_examples=25, deadline=None)
@given(x=st.floats(-150, 150), y=st.floats(-150, 150), yaw=st.floats(-np.pi, np.pi), precull=st.booleans())
def test_scene_is_sound_and_complete_for_any_pose(x, y, yaw, precull):
    """Every emitted surface-stuff triangle touches the region, every thing or filled part kept reaches it, and every
    placed triangle lying inside the region is emitted."""
    rng = np.random.default_rng(0)
    placements = [place(0, ROAD_G, name="road")]
    for pid in range(1, 40):
        g = (HOUSE_G, POLE_G, CAR_G)[pid % 3]
        placements.append(place(pid, g, *rng.uniform(-180, 180, 2), yaw=float(rng.uniform(-np.pi, np.pi))))
    f = frame(x, y, yaw)
    old, assembly._BIG_STUFF = assembly._BIG_STUFF, (4096 if precull else 10**9)
    try:
        out = assemble_frame(f, [], PlacementIndex(placements), GEOMETRY, REGION)
    finally:
        assembly._BIG_STUFF = old
    lo, hi = REGION
    emitted = set()
    for m in out:
        if m.is_stuff and not assembly.fills(m.semantic_id, m.part):
            assert tri_touches(m.vertices, m.faces, lo, hi).all()
        else:
            assert np.all(m.vertices.min(axis=0) <= hi) and np.all(m.vertices.max(axis=0) >= lo)
        emitted |= {tuple(np.round(t.mean(axis=0), 6)) for t in m.vertices[m.faces]}
    T = invert_pose(np.array(f.lidar_pose).reshape(4, 4))
    for p in placements:
        for part in GEOMETRY[p.asset_id].parts:
            V = transform_points(T @ np.array(p.pose).reshape(4, 4), part.vertices)
            tri = V[part.faces]
            inside = np.all((tri.min(axis=1) >= lo) & (tri.max(axis=1) <= hi), axis=1)
            for t in tri[inside]:
                assert tuple(np.round(t.mean(axis=0), 6)) in emitted


def test_procedural_assets_realistic_frame():
    """A frame over procedural ADMesh assets: every part class and transparency survives assembly."""
    from carlaocc.schemas.configs import IngestConfig
    from carlaocc.stages.ingest import ingest_procedural

    lib = ingest_procedural(IngestConfig(variants_per_subclass=1))
    geometry = dict(lib.geometry) | {"T/road": ROAD_G}
    assets = [a for a in lib.assets if a.category not in ("Pedestrian", "Rider")]
    placements = [place(0, ROAD_G, name="road")]
    for k, a in enumerate(assets):  # even: well inside the region, odd: far beyond it
        x, y = (-10.0 + 5.0 * (k // 2 % 10), -10.0 + 5.0 * (k // 20)) if k % 2 == 0 else (300.0 + 10.0 * k, 0.0)
        placements.append(place(k + 1, geometry[a.asset_id], x=x, y=y, yaw=0.1 * k))
    out = assemble_frame(frame(), [], PlacementIndex(placements), geometry, REGION)
    inside = assets[::2]
    # every part of every asset inside, except tall buildings' tops above the region (z 10 m + 1.73 m)
    parts = [p for a in inside for p in geometry[a.asset_id].parts if p.vertices[:, 2].min() <= REGION[1][2] + 1.73]
    assert len(parts) < sum(len(geometry[a.asset_id].parts) for a in inside)
    assert len(out) == 1 + len(parts)  # and the road
    assert sum(m.transparent for m in out) == sum(p.transparent for p in parts) > 0
    for m in out:
        assert m.is_stuff == (m.semantic_id in taxonomy.stuff_ids())
        assert m.instance_id == (0 if m.is_stuff else int(m.name.split("/")[0].rsplit("_", 1)[1]))


# -- flatten, town mesh, export -------------------------------------------------------------------


def test_flatten_counts_and_ids():
    out = assemble_frame(frame(), [actor(7, CAR_G, 10.0, 0.0)], PlacementIndex([place(0, ROAD_G, name="road")]),
                         GEOMETRY, REGION)  # fmt: skip
    pm = flatten(out)
    assert isinstance(pm, PanopticMesh)
    assert len(pm.faces) == sum(len(m.faces) for m in out) and len(pm.vertices) == sum(len(m.vertices) for m in out)
    assert pm.semantic.dtype == np.uint8 and pm.instance.dtype == np.uint32 and pm.transparent.dtype == bool
    start = 0
    for m in out:
        sl = slice(start, start + len(m.faces))
        assert np.all(pm.semantic[sl] == m.semantic_id) and np.all(pm.instance[sl] == m.instance_id)
        assert np.all(pm.transparent[sl] == m.transparent)
        np.testing.assert_array_equal(pm.vertices[pm.faces[sl]], m.vertices[m.faces])
        start += len(m.faces)
    assert pm.transparent.sum() == 12  # the car's glass box
    empty = flatten([])
    assert empty.vertices.shape == (0, 3) and empty.faces.shape == (0, 3) and empty.semantic.shape == (0,)
    with pytest.raises(ValueError, match="faces"):
        PanopticMesh(pm.vertices, pm.faces, pm.semantic[:-1], pm.instance, pm.transparent)


def test_town_mesh_world_frame_ids():
    placements = [place(2, HOUSE_G, x=300.0, y=-40.0, instance=17), place(0, ROAD_G, name="road"),
                  place(1, CAR_G, x=-500.0, instance=4)]  # fmt: skip
    tm = town_mesh(placements, GEOMETRY, things=V1_THINGS)
    n_road, n_car, n_house = 2 * 80 * 80, 24, 12
    assert len(tm.faces) == n_road + n_car + n_house  # everything, stuff whole, however far
    np.testing.assert_array_equal(tm.semantic, [ROAD] * n_road + [CAR] * n_car + [BUILDING] * n_house)
    np.testing.assert_array_equal(tm.instance, [0] * n_road + [4] * n_car + [17] * n_house)
    # under the release's table (the default) the building is stuff
    np.testing.assert_array_equal(town_mesh(placements, GEOMETRY).instance, [0] * n_road + [4] * n_car + [0] * n_house)
    np.testing.assert_array_equal(tm.transparent, [False] * (n_road + 12) + [True] * 12 + [False] * n_house)
    house = tm.vertices[tm.faces[-n_house:]].reshape(-1, 3)
    np.testing.assert_allclose(house.min(axis=0), [295.0, -45.0, 0.0])
    np.testing.assert_allclose(house.max(axis=0), [305.0, -35.0, 8.0])
    with pytest.raises(ValueError, match="placement 2"):
        town_mesh(placements, {"T/road": ROAD_G, "car": CAR_G})


def test_frame_export_round_trip():
    from carlaocc.catalog.panoptic import load_panoptic_glb, panoptic_glb_bytes

    out = assemble_frame(frame(yaw=0.4), [actor(7, CAR_G, 10.0, 0.0)],
                         PlacementIndex([place(0, ROAD_G, name="road"), place(1, HOUSE_G, x=20.0, y=10.0)]),
                         GEOMETRY, REGION)  # fmt: skip
    pm = flatten(out)
    V, F, s, i, t = load_panoptic_glb(panoptic_glb_bytes(*pm.arrays()))
    # flatten's meshes have distinct (semantic, instance, transparent): the file keeps their order
    np.testing.assert_array_equal(s, pm.semantic)
    np.testing.assert_array_equal(i, pm.instance)
    np.testing.assert_array_equal(t, pm.transparent)
    np.testing.assert_allclose(V[F], pm.vertices[pm.faces], atol=1e-4)


def _rotation(q) -> np.ndarray:
    w, x, y, z = np.asarray(q, float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])  # fmt: skip


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), q=st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda v: np.linalg.norm(v) > 0.1),
       frame_q=st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda v: np.linalg.norm(v) > 0.1))  # fmt: skip
def test_big_stuff_precull_equals_direct_cull(seed, q, frame_q):
    """The asset-frame pre-cull of big stuff meshes never loses a triangle: for triangle soups of
    every size under arbitrary rigid placement and LiDAR poses, it matches the direct test."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-60, 60, (600, 3))
    V = (centres[:, None, :] + rng.uniform(-1, 1, (600, 3, 3)) * rng.uniform(0.1, 25, (600, 1, 1))).reshape(-1, 3)
    g = geom("T/soup", ("soup", (V, np.arange(len(V)).reshape(-1, 3)), ROAD, False, False))
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = _rotation(q), rng.uniform(-20, 20, 3)
    W = transform_points(T, V)
    p = PlacementRecord(town="T", placement_id=0, name="soup", asset_id="T/soup", mesh_path="", semantic_id=ROAD,
                        instance_id=0, pose=pose_to_list(T), is_thing=False,
                        aabb_min=W.min(axis=0).tolist(), aabb_max=W.max(axis=0).tolist())  # fmt: skip
    L = np.eye(4)
    L[:3, :3], L[:3, 3] = _rotation(frame_q), rng.uniform(-10, 10, 3)
    f = FrameRecord(sequence_id="s", frame_index=0, timestamp=0.0, ego_pose=pose_to_list(np.eye(4)), lidar_pose=pose_to_list(L))
    region = (np.array([-20.0, -15.0, -5.0]), np.array([25.0, 15.0, 8.0]))
    old = assembly._BIG_STUFF
    try:
        assembly._BIG_STUFF = 1
        a = assemble_frame(f, [], PlacementIndex([p]), {"T/soup": g}, region)
        assembly._BIG_STUFF = 10**9
        b = assemble_frame(f, [], PlacementIndex([p]), {"T/soup": g}, region)
    finally:
        assembly._BIG_STUFF = old
    assert len(a) == len(b) <= 1
    if a:
        np.testing.assert_array_equal(a[0].vertices[a[0].faces], b[0].vertices[b[0].faces])


def test_prepared_cache_follows_new_geometry():
    index = PlacementIndex([place(0, POLE_G, x=5.0)])
    first = assemble_frame(frame(), [], index, GEOMETRY, REGION)
    taller = geom("pole", ("pole", box([-0.1, -0.1, 0], [0.1, 0.1, 9]), POLE, True, False))
    second = assemble_frame(frame(), [], index, GEOMETRY | {"pole": taller}, REGION)
    assert first[0].vertices[:, 2].max() == pytest.approx(5 - 1.73)
    assert second[0].vertices[:, 2].max() == pytest.approx(9 - 1.73)


def test_filled_stuff_kept_whole_surface_stuff_culled():
    # the fill rule (auto) fills poles and trunks: a pole part straddling the region's border is
    # kept whole and closed (its fill needs every triangle); a crown and a fence are surfaces, cut
    TREE_G = geom("tree", ("trunk", box([-0.2, -0.2, 0], [0.2, 0.2, 4]), VEGETATION, True, False),
                  ("crown", box([-2, -2, 3], [2, 2, 7]), VEGETATION, True, False))  # fmt: skip
    FENCE_G = geom("fence", ("panel", box([-3, -0.05, 0], [3, 0.05, 1.2]), FENCE, True, False))
    geometry = {**GEOMETRY, "tree": TREE_G, "fence": FENCE_G}
    f = frame()
    x_border = float(REGION[1][0])
    index = PlacementIndex([
        place(0, POLE_G, x=x_border, y=0.0),  # 0.1 m either side of the +x border
        place(1, TREE_G, x=x_border, y=5.0),
        place(2, FENCE_G, x=x_border, y=-5.0),
    ])  # fmt: skip
    # (carlaocc-v1's table, where a pole is stuff; the release makes it a thing, whole anyway)
    by_name = {m.name.split("/")[-1]: m for m in assemble_frame(f, [], index, geometry, REGION, things=V1_THINGS)}
    pole, trunk, crown, fence = by_name["pole"], by_name["trunk"], by_name["crown"], by_name["panel"]
    for m in (pole, trunk):  # whole: all 12 faces, watertight, past the border
        assert m.is_stuff and m.instance_id == 0 and m.closed and len(m.faces) == 12
        assert m.vertices[:, 0].max() > x_border
    assert trunk.part == "trunk" and crown.part == "crown"
    for m in (crown, fence):  # cut to the triangles touching the region: no longer closed
        assert not m.closed and len(m.faces) < 12
