"""Occupancy pictures: BEV colours, orientation and height shading, the 3D voxel view, pooling,
surface voxels and the two figures, on small synthetic grids (a road plane, a car box, a pole)."""

from __future__ import annotations

import numpy as np
import pytest

from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.taxonomy import by_name, palette
from carlaocc.stages.render.colours import instance_colors
from carlaocc.stages.render.figures import multi_voxel_size_figure, occupancy_figure
from carlaocc.stages.render.occupancy import (FREE_RGB, bev_height_map, classes_present, perspective_view,
                                             pool_occupancy, surface_voxels, top_surface)  # fmt: skip

ROAD, CAR, POLE, SIGN = (by_name(n).id for n in ("Road", "Car", "Pole", "TrafficSign"))
CAR_ID = 7
WHITE = np.array([255, 255, 255], np.uint8)


def _grid(voxel_size=0.25, lo=(-4.0, -4.0, -2.0), hi=(8.0, 4.0, 3.0)) -> GridSpec:
    return GridSpec(region_min=lo, region_max=hi, voxel_size=voxel_size)


def _index(grid: GridSpec, value: float, axis: int) -> int:
    return int(np.floor((value - grid.origin[axis]) / grid.voxel_size + 1e-9))


def _box(sem, inst, grid, x, y, z, cls, ident=0):
    """Fill the voxels of the metric box x, y, z (pairs) with a class and an instance id."""
    sl = tuple(slice(_index(grid, a, k), _index(grid, b, k)) for k, (a, b) in enumerate((x, y, z)))
    sem[sl] = cls
    inst[sl] = ident


def _scene(voxel_size=0.25):
    """Road plane (top at z = -1.5) with a hole, a car (x 3..5, y -2..-1) and a pole (x 1, y 2)."""
    grid = _grid(voxel_size)
    sem = np.zeros(grid.shape, np.uint8)
    inst = np.zeros(grid.shape, np.uint32)
    _box(sem, inst, grid, (-4, 8), (-4, 4), (-2, -1.5), ROAD)
    _box(sem, inst, grid, (-4, -3), (-4, -3), (-2, -1.5), 0)  # a hole: free columns
    _box(sem, inst, grid, (3, 5), (-2, -1), (-1.5, 0), CAR, CAR_ID)
    _box(sem, inst, grid, (1, 1.25), (2, 2.25), (-1.5, 2), POLE)
    return sem, inst, grid


def _pixel(img, grid, x, y, f=1):
    """BEV pixel of the metric point (x, y): row from the top (+x), column from the left (+y);
    with ``f`` x ``f`` blocks the grid is padded to whole blocks at its +x / +y ends."""
    cell = f * grid.voxel_size
    top = grid.origin[0] + -(-grid.shape[0] // f) * cell
    left = grid.origin[1] + -(-grid.shape[1] // f) * cell
    return img[int((top - x) // cell), int((left - y) // cell)]


def _is_shade_of(pixel, base, tol=2.0) -> bool:
    """``pixel`` is ``base`` times one brightness factor in (0, 1] (up to rounding)."""
    pixel, base = np.asarray(pixel, float), np.asarray(base, float)
    s = pixel.sum() / base.sum()
    return 0.0 < s <= 1.0 + 1e-6 and np.abs(pixel - base * s).max() <= tol


# ---------------------------------------------------------------------------------------------
# bird's-eye view
# ---------------------------------------------------------------------------------------------


def test_bev_shape_dtype_and_colours():
    sem, inst, grid = _scene()
    img = bev_height_map(sem, inst, grid)
    assert img.shape == (grid.shape[0], grid.shape[1], 3) and img.dtype == np.uint8
    car = _pixel(img, grid, 4.0, -1.5)
    assert _is_shade_of(car, instance_colors(CAR_ID))
    assert not _is_shade_of(car, palette()[CAR], tol=10)
    assert _is_shade_of(_pixel(img, grid, 6.0, 2.5), palette()[ROAD])
    assert _is_shade_of(_pixel(img, grid, 1.1, 2.1), palette()[POLE])
    assert (_pixel(img, grid, -3.5, -3.5) == FREE_RGB).all()
    # semantic mode: every voxel by its class colour
    sem_img = bev_height_map(sem, inst, grid, "semantic")
    assert _is_shade_of(_pixel(sem_img, grid, 4.0, -1.5), palette()[CAR])
    # height mode: a colour ramp, the pole top differs from the road
    h = bev_height_map(sem, inst, grid, "height")
    assert not (_pixel(h, grid, 1.1, 2.1) == _pixel(h, grid, 6.0, 2.5)).all()
    # deterministic, and instance=None works (stuff colours only)
    assert (bev_height_map(sem, inst, grid) == img).all()
    assert _is_shade_of(_pixel(bev_height_map(sem, None, grid), grid, 4.0, -1.5), palette()[CAR])


def test_bev_orientation_forward_is_up_and_left_is_left():
    grid = _grid(0.25, lo=(-6.0, -6.0, -1.0), hi=(6.0, 6.0, 1.0))  # square: a transpose keeps the shape
    sem = np.zeros(grid.shape, np.uint8)
    inst = np.zeros(grid.shape, np.uint32)
    _box(sem, inst, grid, (3.5, 4.5), (-0.5, 0.5), (-1, 0), CAR)  # ahead (+x)
    _box(sem, inst, grid, (-0.5, 0.5), (3.5, 4.5), (-1, 0), SIGN)  # to the left (+y)
    img = bev_height_map(sem, inst, grid, "semantic", mark_ego=True)
    white = np.argwhere((img == WHITE).all(axis=2))  # the ego marker, centred on the LiDAR
    ego = (white.min(axis=0) + white.max(axis=0)) / 2
    ahead = np.argwhere((img[..., 2] > 60) & (img[..., 0] < 30)).mean(axis=0)  # Car is blue
    left = np.argwhere((img[..., 0] > 60) & (img[..., 2] < 30)).mean(axis=0)  # TrafficSign is yellow
    assert ahead[0] < ego[0] - 10 and abs(ahead[1] - ego[1]) < 2  # above the ego, same column
    assert left[1] < ego[1] - 10 and abs(left[0] - ego[0]) < 2  # left of the ego, same row


@pytest.mark.parametrize("relief", [True, False])
def test_bev_higher_voxel_of_the_same_class_is_brighter(relief):
    grid = _grid()
    sem = np.zeros(grid.shape, np.uint8)
    inst = np.zeros(grid.shape, np.uint32)
    _box(sem, inst, grid, (-4, 8), (-4, 4), (-2, -1.5), ROAD)
    _box(sem, inst, grid, (0, 1), (-2, -1), (-1.5, -1.0), ROAD)  # a low road block
    _box(sem, inst, grid, (0, 1), (1, 2), (-1.5, 1.0), ROAD)  # a high road block
    img = bev_height_map(sem, inst, grid, relief=relief).astype(int)
    ground, low, high = (_pixel(img, grid, *p).sum() for p in ((5.0, 0.0), (0.5, -1.5), (0.5, 1.5)))
    assert ground < low < high
    assert _is_shade_of(_pixel(img, grid, 0.5, 1.5), palette()[ROAD])


def test_bev_max_pixels_keeps_the_top_most_voxel_per_block():
    sem, inst, grid = _scene()
    img = bev_height_map(sem, inst, grid, "semantic", max_pixels=200)
    # 48 x 32 columns: 3 is the smallest factor with ceil(48 / f) * ceil(32 / f) <= 200
    assert img.shape == (16, 11, 3)
    # the pole (one column) wins its 3 x 3 block over the road around it
    assert _is_shade_of(_pixel(img, grid, 1.1, 2.1, f=3), palette()[POLE])
    assert _is_shade_of(_pixel(img, grid, 6.0, -3.0, f=3), palette()[ROAD])


def test_top_surface_and_instance_colours():
    sem, inst, grid = _scene()
    k, s, i = top_surface(sem, inst)
    assert k.shape == grid.shape[:2] and (k[0, 0], s[0, 0], i[0, 0]) == (-1, 0, 0)  # the hole
    ci, cj = _index(grid, 4.0, 0), _index(grid, -1.5, 1)
    assert (s[ci, cj], i[ci, cj], k[ci, cj]) == (CAR, CAR_ID, _index(grid, 0, 2) - 1)
    cols = instance_colors(np.arange(1, 201))
    assert cols.shape == (200, 3) and cols.dtype == np.uint8
    assert (instance_colors(np.arange(1, 201)) == cols).all()
    assert len({tuple(c) for c in cols}) == 200
    hi, lo = cols.max(axis=1).astype(int), cols.min(axis=1).astype(int)
    assert (hi >= 200).all() and ((hi - lo) / hi >= 0.6).all()  # bright, saturated


# ---------------------------------------------------------------------------------------------
# voxels: surfaces and pooling
# ---------------------------------------------------------------------------------------------


def test_surface_voxels_of_a_cube_skip_the_inside():
    sem = np.zeros((5, 5, 5), np.uint8)
    sem[1:4, 1:4, 1:4] = 3
    idx, mask = surface_voxels(sem)
    assert len(idx) == 26 and not ((idx == 2).all(axis=1)).any()
    corner = mask[(idx == 1).all(axis=1)][0]
    assert corner == 1 | 4 | 16  # -x, -y, -z exposed
    # outside the grid counts as free
    idx, mask = surface_voxels(np.ones((1, 1, 1), np.uint8))
    assert len(idx) == 1 and mask[0] == 63


def test_pool_occupancy_takes_the_top_most_voxel_of_each_block():
    sem = np.zeros((4, 4, 4), np.uint8)
    inst = np.zeros((4, 4, 4), np.uint32)
    sem[0, 0, 0], sem[1, 1, 1], inst[1, 1, 1] = ROAD, CAR, 5  # block (0, 0, 0): Car is higher
    sem[3, 3, 2] = POLE
    psem, pinst = pool_occupancy(sem, inst, 2)
    assert psem.shape == (2, 2, 2)
    assert (psem[0, 0, 0], pinst[0, 0, 0], psem[1, 1, 1]) == (CAR, 5, POLE)
    assert np.count_nonzero(psem) == 2
    assert pool_occupancy(np.ones((5, 5, 5), np.uint8), None, 2)[0].shape == (3, 3, 3)
    assert list(classes_present(sem)) == [ROAD, POLE, CAR]


# ---------------------------------------------------------------------------------------------
# 3D view
# ---------------------------------------------------------------------------------------------


def test_perspective_view_of_an_empty_grid_is_the_background():
    grid = _grid()
    empty = np.zeros(grid.shape, np.uint8)
    img = perspective_view(empty, np.zeros(grid.shape, np.uint32), grid, size=(60, 100))
    assert img.shape == (60, 100, 3) and img.dtype == np.uint8 and (img == WHITE).all()


def test_perspective_view_draws_the_voxels_from_behind_the_ego():
    sem, inst, grid = _scene()
    img = perspective_view(sem, inst, grid, size=(120, 200), mode="semantic")
    assert img.shape == (120, 200, 3) and img.dtype == np.uint8
    fg = (img != WHITE).any(axis=2)
    assert fg.mean() > 0.3
    # chase camera: the car (y < 0, right of the ego) is right of the pole (y > 0)
    car = np.argwhere((img[..., 2] > 40) & (img[..., 0] < 30) & (img[..., 1] < 30)).mean(axis=0)
    pole = np.argwhere((np.ptp(img.astype(int), axis=2) < 8) & (img[..., 0] > 60) & (img[..., 0] < 200))
    assert len(pole) and car[1] > pole[:, 1].mean()
    # orthographic, other angles, instance colours, pooling by a tiny voxel budget
    for kw in ({"fov_deg": 0}, {"azimuth_deg": 0, "elevation_deg": 60}, {"max_voxels": 5000}):
        other = perspective_view(sem, inst, grid, size=(60, 100), **kw)
        assert (other != WHITE).any(axis=2).mean() > 0.2
    assert (perspective_view(sem, inst, grid, size=(120, 200), mode="semantic") == img).all()


def test_bad_inputs_are_rejected():
    sem, inst, grid = _scene()
    with pytest.raises(ValueError, match="grid shape"):
        bev_height_map(sem[:-1], inst[:-1], grid)
    with pytest.raises(ValueError, match="instance shape"):
        perspective_view(sem, inst[:, :, :-1], grid)
    with pytest.raises(ValueError, match="mode"):
        bev_height_map(sem, inst, grid, mode="panoptic")


# ---------------------------------------------------------------------------------------------
# figures
# ---------------------------------------------------------------------------------------------


def _sheet_pixel(sheet, panel: int, x: float, y: float, extent) -> np.ndarray:
    """The sheet's colour at metric (x, y) inside a top-view panel with ``extent`` (left, right,
    bottom, top) = (y_left, y_right, x_bottom, x_top)."""
    r0, r1, c0, c1 = sheet.boxes[panel]
    yl, yr, xb, xt = extent
    row = r0 + int((xt - x) / (xt - xb) * (r1 - r0))
    col = c0 + int((yl - y) / (yl - yr) * (c1 - c0))
    return sheet.image[row, col]


def test_occupancy_figure_states_its_colouring():
    sem, inst, grid = _scene()
    fig = occupancy_figure(sem, inst, grid, "high_seq frame 000042", height=160)
    assert fig.image.dtype == np.uint8 and fig.image.ndim == 3
    assert fig.titles == ["top view, 0.25 m voxels", "3D, 0.25 m: from behind, 35 deg up"]
    (key,) = fig.keys
    assert key.heading == "colour: class; things one colour per instance"
    by = {e.label.split(":")[0]: e for e in key.entries}
    # stuff by its class colour; the car, drawn in its instance's colour, claims no class colour
    assert by["Road"].colours == (tuple(palette()[ROAD]),) and by["Pole"].colours == (tuple(palette()[POLE]),)
    car = by["Car"]
    assert car.kind == "instances" and car.label == "Car: one colour per instance (1 here)"
    assert car.colours == (tuple(int(v) for v in instance_colors(CAR_ID)),)
    assert all(tuple(palette()[CAR]) not in e.colours for e in key.entries)
    assert "TrafficSign" not in by
    assert by["ego (LiDAR origin), tip forward"].kind == "marker"
    # the top view's metric axes: the car (x 3..5, y -2..-1) is in its instance colour (shaded by
    # height), the ego at the origin is the white marker, the hole (free) is FREE_RGB
    extent = (4.0, -4.0, -4.0, 8.0)
    assert _shade_mask(_sheet_pixel(fig, 0, 4.0, -1.5, extent)[None, None], instance_colors(CAR_ID))[0, 0]
    assert (_sheet_pixel(fig, 0, 0.0, 0.0, extent) == WHITE).all()
    # semantic mode: the car is a class swatch again
    sem_fig = occupancy_figure(sem, inst, grid, "t", height=160, mode="semantic")
    car = next(e for e in sem_fig.keys[0].entries if e.label == "Car")
    assert car.kind == "swatch" and car.colours == (tuple(palette()[CAR]),)
    assert _shade_mask(_sheet_pixel(sem_fig, 0, 4.0, -1.5, extent)[None, None], palette()[CAR])[0, 0]


def test_height_mode_has_a_scale_in_metres():
    sem, inst, grid = _scene()
    fig = occupancy_figure(sem, inst, grid, "t", height=160, mode="height")
    key = fig.keys[0]
    assert key.scale is not None and "m" in key.scale.label
    assert not any(e.kind == "swatch" and e.label == "Car" for e in key.entries)
    # the scale's ends are the lowest and highest occupied voxel centres, found independently
    ks = np.flatnonzero(sem.any(axis=(0, 1)))
    lo, hi = (grid.origin[2] + (k + 0.5) * grid.voxel_size for k in (ks[0], ks[-1]))
    ticks = dict(key.scale.ticks)
    assert ticks[0.0] == f"{lo:.1f}" and ticks[1.0] == f"{hi:.1f}"


def test_figures_use_a_real_font():
    """The title is drawn with matplotlib's anti-aliased font: many grey levels, not the two
    colours of a bitmap font."""
    sem, inst, grid = _scene()
    fig = occupancy_figure(sem, inst, grid, "high_seq frame 0", height=120)
    title = fig.image[: fig.boxes[0][0] - 24]
    assert len(np.unique(title.reshape(-1, 3), axis=0)) > 8


def test_multi_voxel_size_figure_has_one_labelled_column_per_voxel_size():
    frames = [(f"{voxel_size:g} m", *_scene(voxel_size)) for voxel_size in (0.25, 0.5)]
    window = ((-2.0, 6.0), (-4.0, 4.0))
    two = multi_voxel_size_figure(frames, window=window, cell_size=96)
    assert two.titles == ["0.25 m: 3D from behind", "0.5 m: 3D from behind", "0.25 m: top view", "0.5 m: top view"]
    # both top views are 96 x 96 pixels of the same metric window: the car at the same place
    extent = (4.0, -4.0, -2.0, 6.0)
    for panel in (2, 3):
        r0, r1, c0, c1 = two.boxes[panel]
        assert (r1 - r0, c1 - c0) == (96, 96)
        assert _shade_mask(_sheet_pixel(two, panel, 4.0, -1.5, extent)[None, None], instance_colors(CAR_ID))[0, 0]
    left, right = (two.image[r0:r1, c0:c1] for r0, r1, c0, c1 in two.boxes[2:])
    assert len(np.unique(right.reshape(-1, 3), axis=0)) <= len(np.unique(left.reshape(-1, 3), axis=0))
    classes, top = two.keys
    assert [e.label.split(":")[0] for e in classes.entries] == ["Road", "Pole", "Car"]
    assert "ego (LiDAR origin), tip forward" in top.labels


def _shade_mask(img, base) -> np.ndarray:
    """Pixels whose colour is a shade of ``base``."""
    img, base = img.astype(float), np.asarray(base, float)
    s = img.sum(axis=2, keepdims=True) / base.sum()
    return (np.abs(img - s * base).max(axis=2) <= 3) & (s[..., 0] > 0.3)


def test_orthographic_extent_places_a_voxel_where_the_view_draws_it():
    from carlaocc.stages.render.occupancy import orthographic_extent
    from carlaocc.stages.render.raster import camera_axes

    grid = _grid(0.25)
    sem = np.zeros(grid.shape, np.uint8)
    inst = np.zeros(grid.shape, np.uint32)
    _box(sem, inst, grid, (2.0, 2.5), (-1.0, -0.5), (0.5, 1.0), POLE)  # a 0.5 m cube
    bounds = ((-4.0, 8.0), (-4.0, 4.0), (-2.0, 3.0))
    for el, az in ((0.0, 90.0), (0.0, 180.0), (20.0, 30.0)):
        img = perspective_view(sem, inst, grid, size=(200, 300), elevation_deg=el, azimuth_deg=az, fov_deg=0.0,
                               bounds=bounds, mode="semantic", outline=False, antialias=1)
        left, right, bottom, top = orthographic_extent(bounds, (200, 300), el, az)
        r_, u_, _ = camera_axes(el, az)
        p = np.array([2.25, -0.75, 0.75]) - np.array([2.0, 0.0, 0.5])  # cube centre from the bounds' centre
        col = (p @ r_ - left) / (right - left) * 300
        row = (top - p @ u_) / (top - bottom) * 200
        drawn = np.argwhere(np.any(img != 255, axis=2)).mean(axis=0)
        assert abs(drawn[0] - row) < 1.5 and abs(drawn[1] - col) < 1.5, (el, az, drawn, row, col)
        # square pixels: as many metres per pixel across as down
        assert (right - left) / 300 == pytest.approx((top - bottom) / 200)
