"""The viewer's preparation (stages/render/viewer.py) against brute-force references on random
grids: surface voxels, level of detail, prediction outcomes, flow arrows, box edges, frustums."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from carlaocc.schemas.taxonomy import palette
from carlaocc.stages.geometry import pose_matrix, rotation_from_quaternion
from carlaocc.stages.render.viewer import (OUTCOMES, block_surface, box_edges, camera_frustum, class_colours,
                                           flow_arrows, ghost, label_colours, level_of_detail, linear_index,
                                           prediction_outcome, surface_voxels, voxel_centres)

grids = arrays(np.uint8, st.tuples(st.integers(1, 6), st.integers(1, 6), st.integers(1, 5)),
               elements=st.sampled_from([0, 0, 1, 14]))


def _surface_loop(occ: np.ndarray) -> set:
    """Occupied voxels with a free or out-of-grid face neighbour, one voxel at a time."""
    out = set()
    X, Y, Z = occ.shape
    for i, j, k in zip(*np.nonzero(occ)):
        for d in ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)):
            a, b, c = i + d[0], j + d[1], k + d[2]
            if not (0 <= a < X and 0 <= b < Y and 0 <= c < Z) or occ[a, b, c] == 0:
                out.add((int(i), int(j), int(k)))
                break
    return out


@settings(max_examples=60, deadline=None)
@given(grids)
def test_surface_voxels_match_a_loop(occ):
    ijk = np.argwhere(occ)
    mask = surface_voxels(ijk, occ.shape)
    assert {tuple(int(v) for v in r) for r in ijk[mask]} == _surface_loop(occ)


@settings(max_examples=60, deadline=None)
@given(grids, st.integers(1, 4), st.integers(1, 4))
def test_block_surface_cut_into_blocks_matches_the_whole_grid(occ, cx, cy):
    # the grid cut into (cx, cy, Z) column blocks as the store chunks it, each given only its
    # neighbours' facing planes: the union of the blocks' surfaces is the whole grid's
    X, Y, _ = occ.shape
    got = set()
    for x0 in range(0, X, cx):
        for y0 in range(0, Y, cy):
            x1, y1 = min(x0 + cx, X), min(y0 + cy, Y)
            block = occ[x0:x1, y0:y1]
            flat = block_surface(block, occ[x0 - 1, y0:y1] if x0 else None, occ[x1, y0:y1] if x1 < X else None,
                                 occ[x0:x1, y0 - 1] if y0 else None, occ[x0:x1, y1] if y1 < Y else None)
            assert np.all(np.diff(flat) > 0)  # sorted, C order within the block
            got |= {(x0 + int(i), y0 + int(j), int(k)) for i, j, k in zip(*np.unravel_index(flat, block.shape))}
    assert got == _surface_loop(occ)


def test_block_surface_refuses_a_halo_of_the_wrong_shape():
    import pytest

    with pytest.raises(ValueError, match="halo plane"):
        block_surface(np.ones((2, 3, 4), np.uint8), x_lo=np.ones((2, 4), np.uint8))


def test_a_solid_block_shows_only_its_shell():
    occ = np.ones((5, 5, 5), np.uint8)
    mask = surface_voxels(np.argwhere(occ), occ.shape)
    assert mask.sum() == 125 - 27  # the 3x3x3 core is hidden


@settings(max_examples=40, deadline=None)
@given(grids, st.integers(1, 40))
def test_level_of_detail_keeps_one_voxel_per_block_within_budget(occ, budget):
    ijk = np.argwhere(occ)
    keep, factor = level_of_detail(ijk, budget)
    assert len(keep) <= budget
    # every occupied block is represented exactly once, and the factor is the smallest that fits
    blocks = {tuple(b) for b in ijk // factor}
    assert {tuple(b) for b in ijk[keep] // factor} == blocks and len(blocks) == len(keep)
    if factor > 1:
        assert len(np.unique(ijk // (factor // 2), axis=0)) > budget


def test_voxel_centres_and_flat_index():
    ijk = np.array([[0, 0, 0], [2, 1, 3]])
    np.testing.assert_allclose(voxel_centres(ijk, (-10.0, -5.0, -2.0), 0.2), [[-9.9, -4.9, -1.9], [-9.5, -4.7, -1.3]],
                               atol=1e-6)
    shape = (4, 3, 5)
    assert list(linear_index(ijk, shape)) == list(np.ravel_multi_index(tuple(ijk.T), shape))


@settings(max_examples=60, deadline=None)
@given(grids, grids)
def test_prediction_outcome_matches_a_dense_reference(gt, pred):
    shape = tuple(min(a, b) for a, b in zip(gt.shape, pred.shape))
    gt, pred = gt[:shape[0], :shape[1], :shape[2]], pred[:shape[0], :shape[1], :shape[2]]
    g_flat, p_flat = np.flatnonzero(gt), np.flatnonzero(pred)
    flat, outcome, shown = prediction_outcome(g_flat, gt.reshape(-1)[g_flat], p_flat, pred.reshape(-1)[p_flat])
    g, p = gt.reshape(-1), pred.reshape(-1)
    expect = {}
    for f in range(g.size):  # the dense reference, voxel by voxel
        if g[f] == 0 and p[f] == 0:
            continue
        code = "false positive" if g[f] == 0 else "false negative" if p[f] == 0 else \
            "true positive" if g[f] == p[f] else "wrong class"
        expect[f] = (code, p[f] if p[f] else g[f])
    assert {int(f): (OUTCOMES[o], s) for f, o, s in zip(flat, outcome, shown)} == expect


def test_colours_come_from_the_label_table_and_ghosting_fades_to_white():
    sem = np.array([1, 14, 9], np.uint8)
    assert [tuple(c) for c in class_colours(sem)] == [tuple(palette()[i]) for i in sem]
    inst = class_colours(sem, np.array([0, 7, 0], np.uint32), "instance")
    assert tuple(inst[0]) == tuple(palette()[1]) and tuple(inst[1]) != tuple(palette()[14])
    g = ghost(class_colours(sem), np.array([True, False, False]), 0.75)
    assert tuple(g[0]) == tuple(palette()[1])
    assert all(g[1] >= class_colours(sem)[1]) and g[1].min() >= 0.75 * 255 - 1


def test_flow_arrows_one_per_moving_instance():
    centres = np.array([[0, 0, 0], [2, 0, 0], [5, 5, 0], [9, 9, 9]], np.float32)
    inst = np.array([3, 3, 4, 0])
    flow = np.array([[1, 0, 0], [3, 0, 0], [0.01, 0, 0], [5, 5, 5]], np.float32)
    start, end, ids = flow_arrows(centres, inst, flow, min_speed=0.1, seconds=0.5)
    assert list(ids) == [3]  # 4 is too slow, 0 is stuff
    np.testing.assert_allclose(start, [[1, 0, 0]])
    np.testing.assert_allclose(end, [[2, 0, 0]])  # mean flow 2 m/s for 0.5 s


def test_box_edges_are_the_twelve_edges_of_the_posed_box():
    pose = pose_matrix(10.0, -2.0, 1.0, np.pi / 2)[None]
    seg = box_edges(pose, np.array([[4.0, 2.0, 1.5]]))
    assert seg.shape == (12, 2, 3)
    np.testing.assert_allclose(np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1).round(5).tolist().count(4.0), 4)
    # yawed 90 degrees: the 4 m length lies along y; the corners span x 9..11, y -4..0, z 0.25..1.75
    pts = seg.reshape(-1, 3)
    np.testing.assert_allclose(pts.min(0), [9, -4, 0.25], atol=1e-5)
    np.testing.assert_allclose(pts.max(0), [11, 0, 1.75], atol=1e-5)


def test_camera_frustum_fov_and_pose_round_trip():
    K = np.array([[800.0, 0, 800], [0, 800.0, 450], [0, 0, 1]])
    T = pose_matrix(1.5, 0.2, 1.6, 0.3, 0.1, -0.2)
    cam = camera_frustum(K, T, 1600, 900)
    assert abs(cam["fov"] - 2 * np.arctan(450 / 800)) < 1e-12 and abs(cam["aspect"] - 16 / 9) < 1e-12
    np.testing.assert_allclose(rotation_from_quaternion(cam["wxyz"]), T[:3, :3], atol=1e-9)
    np.testing.assert_allclose(cam["position"], T[:3, 3])


def test_another_label_space_takes_its_first_carlaocc_class_colour():
    from carlaocc.schemas.taxonomy import by_name, label_table
    from carlaocc.stages.evaluation import label_map

    lm = label_map("occ3d")
    col = label_colours(lm.from_carlaocc)
    pal = palette()
    for occ3d_name, ours in (("car", "Car"), ("driveable_surface", "Road"), ("vegetation", "Vegetation")):
        assert tuple(col[lm.names.index(occ3d_name)]) == tuple(pal[by_name(ours).id])
    # every id a class maps to has the colour of the lowest such class; CarlaOcc's own map is the palette
    table = label_table()
    for t in set(lm.from_carlaocc) - {255}:
        first = min(c.id for c in table.classes if c.id and lm.from_carlaocc[c.id] == t) \
            if any(c.id and lm.from_carlaocc[c.id] == t for c in table.classes) else None
        if first is not None:
            assert tuple(col[t]) == tuple(pal[first])
    own = label_colours(label_map("carlaocc").from_carlaocc)
    assert all(tuple(own[c]) == tuple(pal[c]) for c in range(1, len(pal)))
    # instance mode with another space's colours: stuff by that colour, things by instance
    sem, inst = np.array([lm.names.index("driveable_surface"), lm.names.index("car")], np.uint8), np.array([0, 7])
    out = class_colours(sem, inst, "instance", col)
    assert tuple(out[0]) == tuple(col[sem[0]]) and tuple(out[1]) != tuple(col[sem[1]])
