"""Our OBJ + MTL reader: texture coordinates per triangle corner (``vt``, ``i/t``, negative
indices, polygons fanned), corners without one, and the MTL's diffuse colour."""

from __future__ import annotations

import numpy as np
import pytest

from carlaocc.catalog.sources.obj import ObjError, parse_mtl, parse_obj

QUAD = """v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
vt 0.0 0.0
vt 1.0 0.0
vt 1.0 1.0
vt 0.0 1.0
usemtl paint
f 1/1 2/2 3/3 4/4
f -4/-4/1 -2/-2/1 -1/-1/1
"""


def test_corners_keep_their_texture_coordinates_through_the_fan():
    data = parse_obj(QUAD)
    (g,) = data.groups
    assert g.faces == [[0, 1, 2], [0, 2, 3], [0, 2, 3]]
    uv = data.corner_uv(g.uv_index)
    assert uv.dtype == np.float32 and uv.shape == (3, 3, 2)
    # every corner's coordinates are its vertex's (x, y) here: check against the positions
    np.testing.assert_array_equal(uv, data.vertices[np.asarray(g.faces)][..., :2])


def test_a_corner_without_coordinates_means_no_texture_for_the_part():
    data = parse_obj(QUAD + "f 1//1 2//1 3//1\n")
    (g,) = data.groups
    assert g.uv_index[-1] == [-1, -1, -1] and data.corner_uv(g.uv_index) is None
    assert data.corner_uv(g.uv_index[:3]) is not None


def test_a_texture_index_out_of_range_leaves_the_geometry_and_drops_the_texture():
    data = parse_obj(QUAD.replace("f 1/1 2/2", "f 1/9 2/2"))
    (g,) = data.groups
    assert g.faces[0] == [0, 1, 2] and data.bad_uv_lines == [10]
    assert data.corner_uv(g.uv_index) is None  # the part is untextured, not quarantined
    with pytest.raises(ObjError, match="line 10: vertex index 9/1 out of range"):
        parse_obj(QUAD.replace("f 1/1 2/2", "f 9/1 2/2"))


def test_mtl_diffuse_colour():
    mats = parse_mtl("newmtl a\nKd 1 0.5 0\nmap_Kd -s 2 2 1 tex/a.png\nnewmtl b\nKd spectral x.rfl\nnewmtl c\n")
    assert mats["a"].color == (255, 128, 0, 255) and mats["a"].texture == "tex/a.png"
    assert mats["b"].color is None and mats["c"].color is None
