"""Reading a user's mesh file (catalog/mesh_files.py): the numpy reader of binary triangle PLYs
gives trimesh's arrays; every other file goes to trimesh; a broken file is named."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from carlaocc.catalog.mesh_files import MeshFileError, read_binary_ply, read_mesh


def _trimesh_arrays(path) -> tuple[np.ndarray, np.ndarray]:
    m = trimesh.load(str(path), force="mesh", process=False)
    return np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64)


def _ply(path, fmt: str, vertex_props: list[tuple[str, str]], V: np.ndarray, F: np.ndarray, face_count="uchar",
         face_index="int", counts=None, extra_face: list[tuple[str, str]] = (), tail: bytes = b"") -> None:
    """A PLY written by hand (what other exporters write: other orders, types and properties)."""
    order = {"binary_little_endian": "<", "binary_big_endian": ">"}[fmt]
    types = {"float": "f4", "double": "f8", "uchar": "u1", "int": "i4", "uint": "u4", "short": "i2"}
    head = [f"ply", f"format {fmt} 1.0", "comment written by the test", f"element vertex {len(V)}"]
    head += [f"property {t} {n}" for n, t in vertex_props]
    head += [f"element face {len(F)}", f"property list {face_count} {face_index} vertex_indices"]
    head += [f"property {t} {n}" for n, t in extra_face]
    head += ["end_header"]
    vdt = np.dtype([(n, order + types[t]) for n, t in vertex_props])
    vrows = np.zeros(len(V), vdt)
    for axis, n in enumerate("xyz"):
        vrows[n] = V[:, axis]
    fdt = np.dtype([("n", order + types[face_count]), ("i", order + types[face_index], (3,))]
                   + [(n, order + types[t]) for n, t in extra_face])
    frows = np.zeros(len(F), fdt)
    frows["n"] = 3 if counts is None else counts
    frows["i"] = F
    path.write_bytes(("\n".join(head) + "\n").encode() + vrows.tobytes() + frows.tobytes() + tail)


@pytest.fixture
def box() -> trimesh.Trimesh:
    m = trimesh.creation.box(extents=(1.0, 2.0, 0.5))
    m.apply_translation((0.25, -3.0, 1.125))
    return m


def test_trimesh_export_reads_the_same(tmp_path, box):
    path = tmp_path / "box.ply"
    box.export(path)  # binary little-endian, double vertices
    got = read_binary_ply(path)
    assert got is not None
    want = _trimesh_arrays(path)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
    assert got[0].dtype == np.float64 and got[1].dtype == np.int64


@pytest.mark.parametrize("fmt", ["binary_little_endian", "binary_big_endian"])
def test_other_types_orders_and_properties(tmp_path, box, fmt):
    path = tmp_path / "odd.ply"
    props = [("nx", "float"), ("z", "float"), ("x", "float"), ("red", "uchar"), ("y", "float")]
    _ply(path, fmt, props, box.vertices, box.faces, face_count="uchar", face_index="uint",
         extra_face=[("flags", "short")])
    V, F = read_binary_ply(path)
    np.testing.assert_array_equal(V, box.vertices.astype(np.float32).astype(np.float64))
    np.testing.assert_array_equal(F, box.faces)
    V2, F2 = _trimesh_arrays(path)
    np.testing.assert_array_equal(V, V2)
    np.testing.assert_array_equal(F, F2)


def test_polygons_and_ascii_go_to_trimesh(tmp_path, box):
    quads = tmp_path / "quads.ply"
    _ply(quads, "binary_little_endian", [("x", "float"), ("y", "float"), ("z", "float")], box.vertices,
         box.faces, counts=np.r_[4, np.full(len(box.faces) - 1, 3)])
    assert read_binary_ply(quads) is None  # a count other than 3: rows of another size
    text = tmp_path / "ascii.ply"
    box.export(text, encoding="ascii")
    assert read_binary_ply(text) is None
    V, F = read_mesh(text)
    np.testing.assert_allclose(V, box.vertices)
    np.testing.assert_array_equal(F, box.faces)


def test_broken_files_are_named(tmp_path, box):
    path = tmp_path / "cut.ply"
    box.export(path)
    path.write_bytes(path.read_bytes()[:-20])  # truncated: not read by numpy, trimesh names it
    assert read_binary_ply(path) is None
    with pytest.raises(MeshFileError, match="cut.ply: cannot read the mesh"):
        read_mesh(path)
    longer = tmp_path / "longer.ply"
    _ply(longer, "binary_little_endian", [("x", "float"), ("y", "float"), ("z", "float")], box.vertices,
         box.faces, tail=b"bytes no element describes")
    assert read_binary_ply(longer) is None
    with pytest.raises(MeshFileError, match="longer.ply: cannot read the mesh"):
        read_mesh(longer)
    bad = tmp_path / "bad.ply"
    _ply(bad, "binary_little_endian", [("x", "double"), ("y", "double"), ("z", "double")], box.vertices,
         box.faces + 100)
    with pytest.raises(MeshFileError, match="bad.ply: face indices outside the 8 vertices"):
        read_mesh(bad)
