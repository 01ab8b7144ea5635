"""Reading a user's mesh file (``carlaocc voxelize``): the vertices and triangles as they are in it.

Anything trimesh reads (OBJ, PLY, STL, OFF, GLB/glTF; a multi-mesh file concatenated, polygons
triangulated) goes through ``trimesh.load(force="mesh", process=False)``. A binary PLY whose faces
are all triangles -- what most exporters write for large scenes -- is read directly with numpy
instead (the same arrays as trimesh's, without importing trimesh, ~0.8 s, or copying per
element): the header gives a structured dtype per element and the body is viewed through it.
Anything else about a PLY (ASCII, polygons, list properties beside the faces' indices) falls
back to trimesh.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["read_mesh", "read_binary_ply", "MeshFileError"]

_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


class MeshFileError(ValueError):
    """A mesh file that cannot be read; the message names it."""


def read_mesh(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices (N, 3) float64, faces (M, 3) int64)`` of the file at ``path``."""
    path = Path(path)
    if path.suffix.lower() == ".ply":
        found = read_binary_ply(path)
        if found is not None:
            return found
    import trimesh

    try:
        loaded = trimesh.load(str(path), force="mesh", process=False)
    except Exception as exc:  # trimesh raises many kinds for a corrupt file
        raise MeshFileError(f"{path}: cannot read the mesh ({type(exc).__name__}: {exc})") from exc
    V = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64).reshape(-1, 3)
    F = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64).reshape(-1, 3)
    return V, F


def _header(fh) -> tuple[str, list[tuple[str, int, list[tuple]]]] | None:
    """(format, [(element, count, [(name, type) or (name, count type, item type)])]) of a PLY."""
    if fh.readline().strip() != b"ply":
        return None
    fmt, elements = "", []
    while True:
        line = fh.readline()
        if not line:
            return None
        words = line.decode("ascii", "replace").split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "end_header":
            return fmt, elements
        if words[0] == "format" and len(words) >= 2:
            fmt = words[1]
        elif words[0] == "element" and len(words) == 3:
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements:
            if words[1] == "list" and len(words) == 5:
                elements[-1][2].append((words[4], words[2], words[3]))
            elif len(words) == 3:
                elements[-1][2].append((words[2], words[1]))
            else:
                return None
        else:
            return None


def read_binary_ply(path: str | Path) -> tuple[np.ndarray, np.ndarray] | None:
    """The vertices and triangles of a binary PLY whose faces are all triangles, read with numpy;
    None when the file is not such a PLY (the caller falls back to a general reader)."""
    try:
        with open(path, "rb") as fh:
            head = _header(fh)
            if head is None:
                return None
            fmt, elements = head
            order = {"binary_little_endian": "<", "binary_big_endian": ">"}.get(fmt)
            if order is None:
                return None
            body = fh.read()
    except (OSError, ValueError):
        return None
    V = F = None
    offset = 0
    for name, count, props in elements:
        fields = []
        for prop in props:
            if len(prop) == 2:  # scalar
                if prop[1] not in _PLY_TYPES:
                    return None
                fields.append((prop[0], order + _PLY_TYPES[prop[1]]))
            elif name == "face" and prop[0] in ("vertex_indices", "vertex_index") and F is None:
                # 1. a list property, read as if every face were a triangle (checked below)
                if prop[1] not in _PLY_TYPES or prop[2] not in _PLY_TYPES:
                    return None
                fields += [("_n", order + _PLY_TYPES[prop[1]]), ("_i", order + _PLY_TYPES[prop[2]], (3,))]
            else:
                return None  # another list property: rows of varying size
        dtype = np.dtype(fields)
        if count < 0 or offset + count * dtype.itemsize > len(body):
            return None  # truncated
        rows = np.frombuffer(body, dtype=dtype, count=count, offset=offset)
        offset += count * dtype.itemsize
        if name == "vertex":
            if not {"x", "y", "z"} <= set(dtype.names):
                return None
            V = np.stack([rows["x"], rows["y"], rows["z"]], axis=1).astype(np.float64)
        elif name == "face":
            if "_n" not in dtype.names:
                return None
            # 2. the faces were triangles only if every count is 3 (else the rows are misread)
            if count and not np.all(rows["_n"] == 3):
                return None
            F = rows["_i"].astype(np.int64)
    if V is None or F is None or offset != len(body):
        return None  # (bytes left over: a corrupt file, which the general reader names)
    if len(F) and (F.min() < 0 or F.max() >= len(V)):
        raise MeshFileError(f"{path}: face indices outside the {len(V)} vertices")
    return V, F
