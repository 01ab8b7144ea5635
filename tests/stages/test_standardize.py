"""Standardization of source assets: frame (Z up, +X forward, bottom-centre origin), units and
their inference, cleaning, winding repair, quarantine reasons and content-derived ids.

Real files from the shared test data are read here with trimesh (standardize never opens files);
this module plays the source adapter: it builds SourceAssets with what the reader would declare.
"""

from __future__ import annotations

import json
import struct
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from carlaocc.schemas import taxonomy
from carlaocc.schemas.meshes import SourceAsset, SourcePart
from carlaocc.stages.geometry import is_watertight, signed_volume
from carlaocc.stages.ingest.checks import Rejection
from carlaocc.stages.ingest.sizes import (SIZE_RANGES, SOLID_CLASSES, SUBCLASS_SIZE_RANGES, THIN_FACTOR, min_extent,
                                          size_range)
from carlaocc.stages.ingest.standardize import StandardizedAsset, rotation_to_asset_frame, standardize
from shared_data import needs, shared_path

DATA = shared_path("meshes")
needs_data = needs(DATA)


# --------------------------------------------------------------------------------------------
# helpers: the test's own little "adapter"
# --------------------------------------------------------------------------------------------


def _glb_image_uris(path: Path) -> list[str]:
    """External image URIs declared in a GLB's JSON chunk (textures are kept by reference)."""
    data = path.read_bytes()
    length, kind = struct.unpack_from("<I4s", data, 12)
    assert kind == b"JSON"
    doc = json.loads(data[20 : 20 + length])
    return [im["uri"] for im in doc.get("images", []) if "uri" in im]


def _read(path: Path, **declared) -> SourceAsset:
    """Every geometry instance of the file's scene graph as a SourcePart (node transforms applied,
    source units and frame untouched)."""
    scene = trimesh.load_scene(str(path))
    uris = _glb_image_uris(path) if path.suffix == ".glb" else []
    parts = []
    for node in scene.graph.nodes_geometry:
        T, gname = scene.graph[node]
        g = scene.geometry[gname]
        v = np.asarray(g.vertices, dtype=np.float64) @ T[:3, :3].T + T[:3, 3]
        mat = getattr(g.visual, "material", None)
        name = getattr(mat, "name", None) or "default"
        alpha = getattr(mat, "baseColorFactor", None)
        transparent = name == "glass" or getattr(mat, "alphaMode", None) == "BLEND" or (
            alpha is not None and alpha[3] < 255)
        parts.append(SourcePart(name=str(node), vertices=v, faces=np.asarray(g.faces, dtype=np.int64),
                             material=name, transparent=bool(transparent), texture=uris[0] if uris else ""))
    fields = dict(source="testdata", source_path=str(path), licence="CC0-1.0", category=None, subclass="")
    fields.update(declared)
    return SourceAsset(parts=tuple(parts), **fields)


def _ok(result) -> StandardizedAsset:
    assert isinstance(result, StandardizedAsset), result
    return result


def _all_vertices(s: StandardizedAsset) -> np.ndarray:
    return np.concatenate([p.vertices for p in s.geometry.parts])


def _assert_asset_frame(s: StandardizedAsset) -> None:
    """Bottom at z = 0, centred in x and y, extent consistent with the vertices."""
    v = _all_vertices(s)
    lo, hi = v.min(axis=0), v.max(axis=0)
    assert lo[2] == pytest.approx(0.0, abs=1e-6)
    assert (lo[0] + hi[0]) / 2 == pytest.approx(0.0, abs=1e-6)
    assert (lo[1] + hi[1]) / 2 == pytest.approx(0.0, abs=1e-6)
    np.testing.assert_allclose(s.asset.extent, hi - lo, atol=1e-6)


def _cube(size: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    b = trimesh.creation.box(extents=(size, size, size))
    return np.array(b.vertices), np.array(b.faces, dtype=np.int64)


def _raw(parts, **kw) -> SourceAsset:
    fields = dict(source="unit", source_path="mem://cube", licence="CC0-1.0", category="Dynamic",
                  subclass="box", units="m")
    fields.update(kw)
    parts = tuple(p if isinstance(p, SourcePart) else SourcePart(name=f"p{k}", vertices=p[0], faces=p[1])
                  for k, p in enumerate(parts))
    return SourceAsset(parts=parts, **fields)


@pytest.fixture(scope="module")
def bmw() -> SourceAsset:
    # Scenic's BMW X5 hull: Z up already (height 1.835 is the smallest extent, on z); the hood is
    # the low end at +x (z top ~0.1 there vs ~0.8 at the -x tailgate), mirrors near +x: forward +x
    return _read(DATA / "scenic/bmwx5_hull.obj", category="Car", subclass="suv", up="+z", forward="+x")


# --------------------------------------------------------------------------------------------
# the size table
# --------------------------------------------------------------------------------------------


def test_size_table_covers_every_class_and_is_consistent():
    assert set(SIZE_RANGES) == {c.name for c in taxonomy.CLASSES}
    for key, (dim, lo, typ, hi) in [*SIZE_RANGES.items(), *SUBCLASS_SIZE_RANGES.items()]:
        assert dim in ("length", "height") and 0 < lo <= typ <= hi, key
    for cat, sub in SUBCLASS_SIZE_RANGES:
        assert sub in taxonomy.by_name(cat).subclasses
    assert size_range("Car", "sedan")[1:] == (3.5, 4.5, 5.5)
    assert size_range("Building", "house") == ("height", 4.0, 7.0, 15.0)
    assert size_range("Car", "no_such_subclass") == SIZE_RANGES["Car"]
    assert size_range("trafficlight", "") == SIZE_RANGES["TrafficLight"]  # any by_name spelling
    with pytest.raises(KeyError):
        size_range("Spaceship", "")


def test_rotation_is_proper_and_maps_declared_axes():
    axes = ["+x", "-x", "+y", "-y", "+z", "-z"]
    unit = {a: (1.0 if a[0] == "+" else -1.0) * np.eye(3)["xyz".index(a[1])] for a in axes}
    for up in axes:
        for fwd in axes:
            R = rotation_to_asset_frame(up, fwd)
            if up[1] == fwd[1]:
                assert R is None
                continue
            assert np.linalg.det(R) == pytest.approx(1.0)
            np.testing.assert_allclose(R @ unit[up], [0, 0, 1])
            np.testing.assert_allclose(R @ unit[fwd], [1, 0, 0])


# --------------------------------------------------------------------------------------------
# real files
# --------------------------------------------------------------------------------------------


@needs_data
def test_kenney_house_yup_game_units_scaled_to_a_plausible_house():
    path = DATA / "kenney-suburban/building-type-a.glb"
    # glTF: Y up; Kenney models face +Z; game units (~1 per tile), so units unknown
    raw = _read(path, category="Building", subclass="house", up="+y", forward="+z")
    src = np.concatenate([p.vertices for p in raw.parts])
    src_ext = src.max(axis=0) - src.min(axis=0)  # (1.3, 0.834, 1.028): y is the height
    s = _ok(standardize(raw))
    _assert_asset_frame(s)
    # no unit factor makes a 0.83-unit house 4-15 m tall: fallback to the typical 7 m height
    assert s.asset.scale_rule.startswith("fallback")
    assert s.asset.extent[2] == pytest.approx(7.0)
    k = 7.0 / src_ext[1]
    assert s.asset.scale_applied == pytest.approx(k)
    # source z (front) -> +X, source x -> +Y, source y (up) -> +Z
    np.testing.assert_allclose(s.asset.extent, [src_ext[2] * k, src_ext[0] * k, src_ext[1] * k], rtol=1e-6)
    assert 4.0 <= s.asset.extent[2] <= 15.0 and max(s.asset.extent[:2]) < 20.0
    assert s.asset.category == "Building" and s.asset.category_id == taxonomy.by_name("Building").id
    assert s.parts[0].texture == "Textures/colormap.png"  # kept by reference
    # this reader passes no material colour or texture: the part is uncoloured (cameras shade it
    # in its class's base colour)
    assert s.geometry.parts[0].color[:3] == (200, 200, 200) and s.geometry.parts[0].image is None
    assert s.asset.mesh_path == "" and s.asset.aliases == []
    assert s.asset.face_count <= 1174 and s.asset.vertex_count <= 1870


@needs_data
def test_bmw_in_metres_keeps_its_frame(bmw):
    s = _ok(standardize(replace(bmw, units="m")))
    _assert_asset_frame(s)
    np.testing.assert_allclose(s.asset.extent, [4.853, 2.231, 1.835], atol=1e-3)
    assert np.argmin(s.asset.extent) == 2  # a car's height is its smallest extent, along z
    assert s.asset.scale_applied == 1.0 and s.asset.scale_rule == "declared units m"
    assert s.asset.watertight and s.geometry.part_closed == (True,)
    assert s.asset.volume == pytest.approx(13.124, rel=1e-3)
    assert s.asset.face_count == 1168 and s.asset.vertex_count == 586
    assert s.asset.surface_area > 0 and s.asset.licence == "CC0-1.0"
    assert s.asset.geometry_hash and len(s.asset.asset_id) == 16


@needs_data
def test_bmw_units_inferred_or_declared(bmw):
    metres = _ok(standardize(bmw))  # units unknown: 4.85 m fits Car/suv as is
    assert metres.asset.scale_applied == 1.0
    assert metres.asset.scale_rule.startswith("inferred: Car/suv length 4.853 -> 4.85 m (x1, m)")
    in_cm = replace(bmw, parts=tuple(replace(p, vertices=p.vertices * 100.0) for p in bmw.parts))
    declared = _ok(standardize(replace(in_cm, units="cm")))
    assert declared.asset.scale_applied == 0.01  # exactly the declared factor
    assert declared.asset.scale_rule == "declared units cm"
    np.testing.assert_allclose(declared.asset.extent, metres.asset.extent, atol=1e-6)
    inferred = _ok(standardize(in_cm))
    assert inferred.asset.scale_applied == 0.01
    assert inferred.asset.scale_rule == "inferred: Car/suv length 485.3 -> 4.85 m (x0.01, cm)"
    in_mm = replace(bmw, parts=tuple(replace(p, vertices=p.vertices * 1000.0) for p in bmw.parts))
    assert _ok(standardize(in_mm)).asset.scale_rule.endswith("(x0.001, mm)")
    # normalized to a unit box: scaled to the sub-class's typical length
    norm = replace(bmw, parts=tuple(replace(p, vertices=p.vertices / 4.853) for p in bmw.parts), normalized=True)
    s = _ok(standardize(norm))
    assert s.asset.extent[0] == pytest.approx(4.8)
    assert s.asset.scale_rule == "normalized: scaled to typical length 4.8 m of Car/suv"
    # a known target length wins over everything
    s = _ok(standardize(replace(norm, target_length=4.2)))
    assert s.asset.extent[0] == pytest.approx(4.2)
    assert s.asset.scale_rule == "target_length 4.2 m from category map"


@needs_data
def test_milk_truck_multipart_yup():
    path = DATA / "cesium/CesiumMilkTruck.glb"
    # glTF Y up; the cab (glass part) sits at +x, so the truck drives along +x
    raw = _read(path, category="Truck", subclass="box_truck", up="+y", forward="+x", units="m")
    s = _ok(standardize(raw))
    _assert_asset_frame(s)
    assert s.asset.part_count == 5 == len(s.parts) == len(s.geometry.parts)  # the wheels twice
    assert [p.part_index for p in s.parts] == list(range(5))
    np.testing.assert_allclose(s.asset.extent, [4.869, 2.792, 2.583], atol=2e-3)
    assert s.asset.extent[2] < s.asset.extent[0]
    assert s.asset.transparent_part_count == 1
    glass = next(p for p in s.geometry.parts if p.material == "glass")
    assert glass.transparent and glass.vertices[:, 0].mean() > 0.0  # the cab stays in front
    # right-handed: the source's +z side (the truck's right when +y up, +x forward) is -Y
    # right-handed: with +y up and +x forward, the source's +z side (the truck's right) is -Y
    from carlaocc.stages.ingest.standardize import rotation_to_asset_frame

    R = rotation_to_asset_frame("+y", "+x")
    np.testing.assert_allclose(R @ [0.0, 0.0, 1.0], [0.0, -1.0, 0.0], atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    assert s.asset.face_count <= 3624 and sum(p.face_count for p in s.parts) == s.asset.face_count
    assert s.asset.volume is None or s.asset.watertight


@needs_data
def test_unit_cube_stl_and_storey_building():
    cube = _read(DATA / "trimesh-models/unit_cube.STL", category="Dynamic", subclass="box", units="m")
    s = _ok(standardize(cube))
    _assert_asset_frame(s)
    np.testing.assert_allclose(s.asset.extent, [1, 1, 1], atol=1e-9)
    assert s.asset.watertight and s.asset.volume == pytest.approx(1.0)
    # non-indexed glTF with Y-up node transforms: 3 storeys, 9 m high
    raw = _read(DATA / "trimesh-models/no_indices_3storybuilding.glb", category="Building",
                subclass="residential", up="+y", forward="+z")
    s = _ok(standardize(raw))
    _assert_asset_frame(s)
    np.testing.assert_allclose(s.asset.extent, [63.361, 56.080, 9.0], atol=2e-3)
    assert s.asset.scale_applied == 1.0 and "(x1, m)" in s.asset.scale_rule
    assert s.asset.part_count == 3 and s.asset.face_count == 72
    assert not s.asset.watertight and s.asset.volume is None  # a triangle soup is not closed


# --------------------------------------------------------------------------------------------
# quarantine
# --------------------------------------------------------------------------------------------


def _rejected(raw: SourceAsset) -> Rejection:
    r = standardize(raw)
    assert isinstance(r, Rejection), r
    assert r.reason and r.hint
    return r


def test_rejections():
    v, f = _cube()
    bad = v.copy()
    bad[3, 1] = np.nan
    assert _rejected(_raw([(bad, f)])).reason == "non-finite vertices"
    bad[3, 1] = np.inf
    assert _rejected(_raw([(bad, f)])).reason == "non-finite vertices"
    assert _rejected(_raw([])).reason == "empty mesh"
    assert _rejected(_raw([(np.zeros((0, 3)), np.zeros((0, 3), np.int64))])).reason == "empty mesh"
    f_out = f.copy()
    f_out[0, 0] = 8
    assert _rejected(_raw([(v, f_out)])).reason == "face index out of range"
    f_out[0, 0] = -1
    assert _rejected(_raw([(v, f_out)])).reason == "face index out of range"
    assert _rejected(_raw([(v, np.zeros((2, 4), np.int64))])).reason == "not triangles"
    # a 10 km "car"
    big, bf = _cube(10_000.0)
    r = _rejected(_raw([(big, bf)], category="Car", subclass="sedan"))
    assert r.reason == "absurd size"
    assert "1e+04" in r.hint and "3.5-5.5" in r.hint
    # category
    assert _rejected(_raw([(v, f)], category=None)).reason == "no category"
    assert _rejected(_raw([(v, f)], category="None")).reason == "no category"
    r = _rejected(_raw([(v, f)], category="Spaceship"))
    assert r.reason == "unknown category 'Spaceship'"
    assert "Car" in r.hint and "Building" in r.hint
    # licence
    assert _rejected(_raw([(v, f)], licence="", licence_required=True)).reason == "missing licence"
    assert isinstance(standardize(_raw([(v, f)], licence="", licence_required=False)), StandardizedAsset)
    # frame
    assert _rejected(_raw([(v, f)], up="+y", forward="-y")).reason == "axes not perpendicular"
    # everything degenerate
    line = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], dtype=float)
    r = _rejected(_raw([(line, np.array([[0, 1, 2], [0, 0, 1], [2, 1, 0]]))]))
    assert r.reason == "all faces degenerate"
    # a part class outside the taxonomy
    r = _rejected(_raw([SourcePart("p", v, f, semantic_id=42)]))
    assert r.reason == "unknown part class"


def test_nan_is_rejected_not_raised_in_any_part():
    v, f = _cube()
    bad = v.copy()
    bad[0] = [np.nan, 0, 0]
    r = standardize(_raw([(v, f), (bad, f)]))
    assert isinstance(r, Rejection) and r.reason == "non-finite vertices"


# --------------------------------------------------------------------------------------------
# cleaning and winding
# --------------------------------------------------------------------------------------------


def test_duplicate_degenerate_faces_and_unreferenced_vertices_removed():
    v, f = _cube()
    mid = (v[f[0, 0]] + v[f[0, 1]]) / 2.0
    v2 = np.vstack([v, mid, [5.0, 5.0, 5.0]])  # 8 = collinear midpoint, 9 = unreferenced
    extra = np.array([
        f[0][::-1],              # duplicate, opposite winding
        f[1][[1, 2, 0]],         # duplicate, rotated
        [0, 0, 1],               # repeated index
        [f[0, 0], f[0, 1], 8],   # zero area (collinear)
    ])  # fmt: skip
    s = _ok(standardize(_raw([(v2, np.vstack([f, extra]))])))
    assert s.asset.face_count == 12 and s.parts[0].face_count == 12
    assert s.asset.vertex_count == 8
    assert s.asset.watertight and s.asset.volume == pytest.approx(1.0)
    assert any("removed 2 degenerate and 2 duplicate faces, 2 unreferenced vertices" in n for n in s.notes)
    np.testing.assert_allclose(s.asset.extent, [1, 1, 1])


def test_inconsistent_winding_fixed_on_a_closed_cube():
    v, f = _cube()
    bad = f.copy()
    bad[[0, 5, 9]] = bad[[0, 5, 9]][:, ::-1]
    assert not is_watertight(bad)
    s = _ok(standardize(_raw([(v, bad)])))
    assert s.geometry.part_closed == (True,) and s.parts[0].watertight and s.asset.watertight
    assert is_watertight(s.geometry.parts[0].faces)
    assert s.asset.volume == pytest.approx(1.0)  # outward after the repair
    assert any("winding fixed" in n for n in s.notes)
    # entirely inside out: consistently wound, negative volume -> flipped outward
    s = _ok(standardize(_raw([(v, f[:, ::-1].copy())])))
    assert s.asset.volume == pytest.approx(1.0) and any("inside-out" in n for n in s.notes)
    # both at once, two bodies in one part
    v2, f2 = np.vstack([v, v + [3.0, 0, 0]]), np.vstack([bad, f[:, ::-1] + 8])
    s = _ok(standardize(_raw([(v2, f2)])))
    assert s.asset.watertight and s.asset.volume == pytest.approx(2.0)


def test_hollow_shell_and_open_mesh_left_alone():
    v, f = _cube(2.0)
    vi, fi = _cube(1.0)
    hollow = (np.vstack([v, vi]), np.vstack([f, fi[:, ::-1] + 8]))  # inner shell faces inward
    s = _ok(standardize(_raw([hollow])))
    assert s.asset.watertight and s.asset.volume == pytest.approx(7.0)
    assert not any("inside-out" in n for n in s.notes)
    # an open box (one face missing, some faces flipped) stays open and is not "fixed"
    open_f = f[2:].copy()
    open_f[[0, 1]] = open_f[[0, 1]][:, ::-1]
    s = _ok(standardize(_raw([(v, open_f)])))
    assert not s.asset.watertight and s.asset.volume is None
    np.testing.assert_array_equal(s.geometry.parts[0].faces, open_f)


# --------------------------------------------------------------------------------------------
# labels, parts, identity
# --------------------------------------------------------------------------------------------


def test_part_classes_materials_and_unknown_subclass():
    v, f = _cube()
    glass = SourcePart("window", v + [0, 0, 1.0], f, material="glass", transparent=True, texture="t/glass.png")
    rider = SourcePart("driver", v + [0, 2.0, 0], f, semantic_id=taxonomy.by_name("Rider").id)
    s = _ok(standardize(_raw([(v, f), glass, rider], category="Car", subclass="rocket_car",
                             units="unknown", target_length=4.0)))
    car, rid = taxonomy.by_name("Car"), taxonomy.by_name("Rider")
    assert [p.semantic_id for p in s.parts] == [car.id, car.id, rid.id]
    # no material colours given: uncoloured (the cameras shade them in their class's colour)
    assert [p.color for p in s.geometry.parts] == [(200, 200, 200, 255), (200, 200, 200, 110), (200, 200, 200, 255)]
    assert s.parts[1].transparent and s.parts[1].material == "glass" and s.parts[1].texture == "t/glass.png"
    assert s.asset.transparent_part_count == 1
    assert s.asset.subclass == "rocket_car"  # kept ...
    assert any("rocket_car" in n and "not in the taxonomy" in n for n in s.notes)  # ... and recorded
    assert max(s.asset.extent[:2]) == pytest.approx(4.0)
    assert s.asset.volume == pytest.approx(3 * (4.0 / 3.0) ** 3)


def test_asset_id_is_content_derived():
    v, f = _cube()
    a = _ok(standardize(_raw([(v, f)], source_path="a.obj")))
    b = _ok(standardize(_raw([(v * 100 + 7.0, f)], source_path="b/c.fbx", units="cm", source="other")))
    assert a.asset.geometry_hash == b.asset.geometry_hash
    assert a.asset.asset_id == b.asset.asset_id  # one asset, stored once
    assert a.asset.source_path != b.asset.source_path
    c = _ok(standardize(_raw([(v, f)], category="Static", subclass="box")))
    assert c.asset.asset_id != a.asset.asset_id
    d = _ok(standardize(_raw([(v, f)], subclass="luggage")))
    assert d.asset.asset_id != a.asset.asset_id
    assert all(p.asset_id == a.asset.asset_id for p in a.parts) and a.geometry.asset_id == a.asset.asset_id


_AXES = ["+x", "-x", "+y", "-y", "+z", "-z"]
_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}


def _unit(a: str) -> np.ndarray:
    return (1.0 if a[0] == "+" else -1.0) * np.eye(3)["xyz".index(a[1])]


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    extents=st.tuples(*[st.floats(0.2, 20.0) for _ in range(3)]),
    up=st.sampled_from(_AXES),
    fwd_index=st.integers(0, 3),
    units=st.sampled_from(sorted(_UNITS)),
    shift=st.tuples(*[st.floats(-1e3, 1e3) for _ in range(3)]),
)
def test_rigid_transform_and_declared_units_give_the_same_extents(extents, up, fwd_index, units, shift):
    box = trimesh.creation.box(extents=extents)
    forward = [a for a in _AXES if a[1] != up[1]][fwd_index]
    # the source frame: asset +X is the source's forward, +Z its up (a proper rotation)
    u, fw = _unit(up), _unit(forward)
    M = np.column_stack([fw, np.cross(u, fw), u])
    src = (np.asarray(box.vertices) @ M.T) / _UNITS[units] + np.asarray(shift)
    raw = _raw([(src, np.asarray(box.faces, np.int64))], category="Other", subclass="", up=up,
               forward=forward, units=units)
    s = _ok(standardize(raw))
    np.testing.assert_allclose(s.asset.extent, extents, rtol=1e-6, atol=1e-6)
    _assert_asset_frame(s)
    assert s.asset.watertight and s.asset.volume == pytest.approx(np.prod(extents), rel=1e-6)
    assert s.asset.scale_applied == _UNITS[units]
    assert signed_volume(s.geometry.parts[0].vertices, s.geometry.parts[0].faces) > 0


def test_unknown_units_rescale_game_units_but_reject_a_10km_car():
    box = lambda L: trimesh.creation.box((L, 0.42 * L, 0.33 * L))
    part = lambda m: SourcePart("body", m.vertices, m.faces)
    # a 1.2-unit "car" from a game kit: no unit explains it, it is rescaled to the typical length
    game = standardize(_raw((part(box(1.2)),), category="Car", subclass="sedan", units="unknown"))
    assert not isinstance(game, Rejection) and game.asset.scale_rule.startswith("fallback")
    assert game.asset.extent[0] == pytest.approx(4.5, rel=1e-6)
    # a 10 km "car" in unknown units: mm would make it 10 m, no unit fits, and it is > 100x typical
    huge = standardize(_raw((part(box(10_000.0)),), category="Car", subclass="sedan", units="unknown"))
    assert isinstance(huge, Rejection) and huge.reason == "absurd size" and "1e+04" in huge.hint


def test_split_seam_vertices_are_welded_so_closed_meshes_stay_watertight():
    box = trimesh.creation.box((4.5, 1.8, 1.5))
    # exporters split vertices per face (normals/UVs): 36 vertices, every face on its own
    v = box.vertices[box.faces].reshape(-1, 3)
    f = np.arange(len(v)).reshape(-1, 3)
    s = _ok(standardize(_raw(((v, f),), category="Car", subclass="sedan", units="m")))
    assert s.asset.watertight and s.geometry.part_closed == (True,)
    assert s.asset.vertex_count == 8
    assert s.asset.volume == pytest.approx(4.5 * 1.8 * 1.5, rel=1e-9)


def test_sideways_vehicle_is_turned_long_side_to_x():
    box = trimesh.creation.box((1.8, 4.5, 1.5))  # lying along y: forward declared wrong
    s = _ok(standardize(_raw(((box.vertices, box.faces),), category="Car", subclass="sedan", units="m")))
    np.testing.assert_allclose(s.asset.extent, [4.5, 1.8, 1.5], atol=1e-9)
    assert "quarter" in s.asset.notes
    # a building may be wider than deep: left as declared
    b = _ok(standardize(_raw(((box.vertices * 4, box.faces),), category="Building", subclass="house", units="m")))
    np.testing.assert_allclose(b.asset.extent, [7.2, 18.0, 6.0], atol=1e-9)


# --------------------------------------------------------------------------------------------
# degenerate extents (issue 17): solid objects (Building, road users) are solid, the rest may be flat
# --------------------------------------------------------------------------------------------

THING_CLASSES = [c for c in taxonomy.CLASSES if c.name in SOLID_CLASSES]
FLAT_STUFF = ["Road", "RoadLine", "Ground", "Sidewalk", "Terrain", "Water", "Fence", "TrafficSign"]


def _sheet(length: float, width: float, zero_axis: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Two triangles spanning ``length`` x ``width`` with no extent along ``zero_axis``."""
    quad = np.array([[0.0, 0.0], [length, 0.0], [length, width], [0.0, width]])
    v = np.insert(quad, zero_axis, 0.0, axis=1)
    return v, np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)


@pytest.mark.parametrize("cls", THING_CLASSES, ids=lambda c: c.name)
def test_a_flat_triangle_is_never_a_thing(cls):
    # the case: one flat triangle ingested as a car (zero height), for every thing class
    _, typical, _ = size_range(cls.name, cls.subclasses[0])[1:]
    v = np.array([[0.0, 0.0, 0.0], [typical, 0.0, 0.0], [0.0, typical / 2, 0.0]])
    r = _rejected(_raw([(v, np.array([[0, 1, 2]]))], category=cls.name, subclass=cls.subclasses[0]))
    assert r.reason == "flat mesh"
    assert "along z" in r.hint and cls.name in r.hint and "up axis" in r.hint


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cls=st.sampled_from(THING_CLASSES), axis=st.integers(0, 2), units=st.sampled_from(["m", "cm", "unknown"]))
def test_things_flat_on_any_axis_are_quarantined(cls, axis, units):
    typ = size_range(cls.name, cls.subclasses[0])[2]
    scale = 100.0 if units == "cm" else 1.0
    v, f = _sheet(typ * scale, typ * scale / 2, zero_axis=axis)
    r = standardize(_raw([(v, f)], category=cls.name, subclass=cls.subclasses[0], units=units))
    assert isinstance(r, Rejection) and r.reason == "flat mesh", r
    assert "no extent along" in r.hint  # the axis of the asset frame (vehicles may be turned first)


@pytest.mark.parametrize("name", FLAT_STUFF)
def test_flat_stuff_is_kept(name):
    cls = taxonomy.by_name(name)
    dim, lo, typ, hi = size_range(name, cls.subclasses[0])
    # ground-like stuff lies flat (no height); sheets measured by height stand up (no depth)
    v, f = _sheet(typ, typ / 2, zero_axis=2 if dim == "length" else 1)
    s = _ok(standardize(_raw([(v, f)], category=name, subclass=cls.subclasses[0])))
    assert min(s.asset.extent) == 0.0 and s.asset.face_count == 2


def test_a_thing_far_too_thin_for_its_class_is_quarantined():
    car = trimesh.creation.box((4.5, 1.8, 0.05))  # a 5 cm "car": a decal, not a vehicle
    r = _rejected(_raw([(car.vertices, car.faces)], category="Car", subclass="sedan", units="m"))
    assert r.reason == "too thin" and "z below 0.175 m" in r.hint and "3.5" in r.hint
    # the limit follows the sub-class range: 1/20 of its smallest size, on every axis
    assert min_extent("Car", "sedan") == pytest.approx(3.5 / THIN_FACTOR)
    assert min_extent("Car", "hatchback") == pytest.approx(2.5 / THIN_FACTOR)
    ok = trimesh.creation.box((4.5, 1.8, 0.2))  # thin, but not absurdly so
    assert isinstance(standardize(_raw([(ok.vertices, ok.faces)], category="Car", subclass="sedan", units="m")),
                      StandardizedAsset)
    person = trimesh.creation.box((0.3, 0.02, 1.75))  # a cut-out figure, 2 cm deep
    r = _rejected(_raw([(person.vertices, person.faces)], category="Pedestrian", subclass="adult", units="m"))
    assert r.reason == "too thin" and "y below" in r.hint


def test_min_extent_is_zero_exactly_for_what_may_be_flat():
    assert SOLID_CLASSES == {"Building", "Pedestrian", "Rider", "Car", "Truck", "Bus", "Train", "Motorcycle", "Bicycle"}
    for c in taxonomy.CLASSES:
        for sub in c.subclasses or ("",):
            m = min_extent(c.name, sub)
            assert (m > 0.0) == (c.name in SOLID_CLASSES), (c.name, sub, m)


def test_source_notes_come_first_in_the_record_notes():
    box = trimesh.creation.box((4.5, 1.8, 1.5))
    src_notes = ("car.obj: material library 'car.mtl' not found (materials default: no transparency or texture)",)
    s = _ok(standardize(_raw([(box.vertices, box.faces)], category="Car", subclass="sedan", notes=src_notes)))
    assert s.notes[0] == src_notes[0] and s.asset.notes.startswith(src_notes[0])
    plain = _ok(standardize(_raw([(box.vertices, box.faces)], category="Car", subclass="sedan")))
    assert plain.asset.notes == "" and s.asset.asset_id == plain.asset.asset_id  # notes are not identity


def test_material_colour_and_texture_follow_cleaning_and_winding_repair():
    v, f = _cube()
    # a duplicate face and a degenerate one that cleaning drops; one face wound the wrong way
    bad = np.vstack([f[:3], f[:1], [[0, 0, 1]], f[3:]])
    bad[5] = bad[5][::-1]
    m = len(bad)
    # each input face's corners carry (face index, corner index): where they end up says it all
    corner = np.stack([np.stack([np.full(3, k, np.float32), np.arange(3, dtype=np.float32)], 1)
                       for k in range(m)])
    image = np.zeros((4, 4, 3), np.uint8)
    painted = SourcePart("body", v, bad, color=(10, 20, 30, 255))
    textured = SourcePart("decal", v + [0, 0, 1.0], bad, corner_uv=corner, image=image)
    s = _ok(standardize(_raw([painted, textured], category="Car", units="unknown", target_length=4.0)))
    body, decal = s.geometry.parts
    assert body.color == (10, 20, 30, 255) and body.image is None  # the material's colour
    assert decal.color == (255, 255, 255, 255)  # a texture without a colour factor: the texture is the colour
    assert decal.image is image or np.array_equal(decal.image, image)
    assert decal.corner_uv.shape == (len(decal.faces), 3, 2) == (12, 3, 2)
    kept = decal.corner_uv[:, 0, 0].astype(int)
    assert 3 not in kept and 4 not in kept  # the duplicate and the degenerate face are gone
    assert sorted(kept) == [k for k in range(m) if k not in (3, 4)]
    # the repaired face's corners reversed with it: corner order (2, 1, 0)
    fixed = np.flatnonzero(kept == 5)[0]
    assert list(decal.corner_uv[fixed, :, 1]) == [2.0, 1.0, 0.0]
    assert all(list(decal.corner_uv[j, :, 1]) == [0.0, 1.0, 2.0] for j in range(12) if j != fixed)
