"""A small Wavefront OBJ + MTL reader that keeps what trimesh's OBJ loader drops.

trimesh groups OBJ faces by material (or by ``o`` object) and loses ``g`` group names; the
BuildingNet adapter labels parts by group/component name and the carla adapter wants the raw
component geometry, so both read OBJ here. The folder and shapenet adapters load OBJ with trimesh
and use :func:`read_mtl` for what trimesh does not expose (``d``/``Tr`` transparency, the
``map_Kd`` texture path).

Supported: ``v`` (extra colour components ignored), ``vt`` (texture coordinates: u, v up from the
image's bottom-left corner), ``f`` with ``i``, ``i/t``, ``i//n``, ``i/t/n`` corners and negative
(relative) indices, polygons (fan-triangulated), ``o``, ``g``, ``usemtl``, ``mtllib``, ``\\``
line continuations, comments. An ``o`` record clears the current ``g`` group (a new object does
not inherit the previous object's group). Everything else (``vn``, ``l``, ``s``, curves) is
ignored. MTL: ``d``/``Tr`` (transparency), ``Kd`` (diffuse colour), ``map_Kd`` (its texture).
"""

from __future__ import annotations

import os
import posixpath
from dataclasses import dataclass, field

import numpy as np

# map_* options and how many arguments they take (None: 1 to 3 numbers).
_MAP_OPTIONS: dict[str, int | None] = {
    "-blendu": 1, "-blendv": 1, "-bm": 1, "-boost": 1, "-cc": 1, "-clamp": 1, "-imfchan": 1,
    "-texres": 1, "-type": 1, "-mm": 2, "-o": None, "-s": None, "-t": None,
}  # fmt: skip


class ObjError(ValueError):
    """The OBJ (or MTL) text cannot be parsed; the message says where."""


@dataclass(frozen=True)
class MtlMaterial:
    """What we keep of an MTL material: transparency and the diffuse texture path (as written,
    relative to the MTL file's directory)."""

    name: str
    transparent: bool = False
    texture: str = ""
    color: tuple[int, int, int, int] | None = None  # Kd as RGBA 0-255 (None: not stated)


@dataclass
class ObjGroup:
    """Faces sharing one (object, group, material) run of an OBJ file."""

    obj: str
    group: str
    material: str
    faces: list = field(default_factory=list)  # triangles as lists of 0-based vertex indices
    # per triangle, its corners' 0-based ``vt`` indices (-1 where a corner has none)
    uv_index: list = field(default_factory=list)


@dataclass
class ObjData:
    vertices: np.ndarray  # (N, 3) float64
    groups: list[ObjGroup]  # in order of first appearance
    mtllibs: list[str]  # as written
    uv: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (T, 2) float64, the ``vt`` records
    bad_uv_lines: list[int] = field(default_factory=list)  # faces whose texture index has no ``vt`` (untextured)

    def corner_uv(self, uv_index) -> np.ndarray | None:
        """(M, 3, 2) float32 texture coordinates of triangles with ``uv_index`` (M, 3) corners;
        None when a corner has no coordinates."""
        idx = np.asarray(uv_index, dtype=np.int64).reshape(-1, 3)
        if idx.size == 0 or idx.min() < 0:
            return None
        return np.ascontiguousarray(self.uv[idx], dtype=np.float32)


def _logical_lines(text: str):
    """Physical lines joined on trailing backslashes, with 1-based line numbers."""
    buf, start = "", 0
    for no, line in enumerate(text.splitlines(), 1):
        if not buf:
            start = no
        if line.endswith("\\"):
            buf += line[:-1] + " "
            continue
        yield start, buf + line
        buf = ""
    if buf:
        yield start, buf


def _statements(text: str):
    """(line number, tokens) of every non-empty statement, comments stripped."""
    for no, line in _logical_lines(text):
        parts = line.split("#", 1)[0].split()
        if parts:
            yield no, parts


def parse_obj(text: str) -> ObjData:
    """Parse OBJ text. Raises :class:`ObjError` naming the line of a malformed record."""
    verts: list[tuple[float, float, float]] = []
    uvs: list[tuple[float, float]] = []
    bad_uv: list[int] = []  # lines with a texture index out of range
    groups: dict[tuple[str, str, str], ObjGroup] = {}
    mtllibs: list[str] = []
    obj, grp, mat = "", "", ""
    for no, parts in _statements(text):
        tag = parts[0]
        try:
            if tag == "v":
                verts.append((float(parts[1]), float(parts[2]), float(parts[3])))
            elif tag == "vt":
                uvs.append((float(parts[1]), float(parts[2]) if len(parts) > 2 else 0.0))
            elif tag == "f":
                n, nt = len(verts), len(uvs)
                idx, tdx = [], []
                for corner in parts[1:]:
                    fields = corner.split("/")
                    i = int(fields[0])
                    i = i - 1 if i > 0 else n + i
                    if not 0 <= i < n:
                        raise ObjError(f"line {no}: vertex index {corner} out of range (1..{n})")
                    idx.append(i)
                    t = -1
                    if len(fields) > 1 and fields[1]:
                        t = int(fields[1])
                        t = t - 1 if t > 0 else nt + t
                        if not 0 <= t < nt:
                            t = -1  # a texture index without its vt: the geometry stands, the part has no texture
                            bad_uv.append(no)
                    tdx.append(t)
                if len(idx) < 3:
                    raise ObjError(f"line {no}: a face needs 3 vertices, got {len(idx)}")
                key = (obj, grp, mat)
                g = groups.get(key)
                if g is None:
                    g = groups[key] = ObjGroup(obj, grp, mat)
                g.faces.extend([idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1))
                g.uv_index.extend([tdx[0], tdx[k], tdx[k + 1]] for k in range(1, len(idx) - 1))
            elif tag == "o":  # a new object starts without the previous object's group
                obj, grp = " ".join(parts[1:]), ""
            elif tag == "g":
                grp = " ".join(parts[1:])
            elif tag == "usemtl":
                mat = " ".join(parts[1:])
            elif tag == "mtllib":
                mtllibs.extend(parts[1:])
        except (IndexError, ValueError) as e:
            if isinstance(e, ObjError):
                raise
            raise ObjError(f"line {no}: malformed {tag!r} record") from None
    vertices = np.asarray(verts, dtype=np.float64).reshape(-1, 3)
    return ObjData(vertices, list(groups.values()), mtllibs, np.asarray(uvs, dtype=np.float64).reshape(-1, 2),
                   bad_uv_lines=bad_uv)


def read_obj(path: str) -> ObjData:
    """Parse an OBJ file (UTF-8, undecodable bytes replaced). OSError / ObjError propagate."""
    with open(path, encoding="utf-8", errors="replace") as f:
        return parse_obj(f.read())


def _map_path(args: list[str]) -> str:
    """The file name of a ``map_*`` statement, its options skipped."""
    i = 0
    while i < len(args) and args[i].lower() in _MAP_OPTIONS:
        n = _MAP_OPTIONS[args[i].lower()]
        i += 1
        if n is None:  # 1 to 3 numbers
            k = 0
            while k < 3 and i < len(args):
                try:
                    float(args[i])
                except ValueError:
                    break
                i += 1
                k += 1
        else:
            i += n
    return " ".join(args[i:]).replace("\\", "/")


def parse_mtl(text: str) -> dict[str, MtlMaterial]:
    """Materials of an MTL file by name.

    Transparent when ``d < 1`` (dissolve: 1 is opaque) or ``Tr > 0`` (transparency = 1 - d).
    When a material states both, ``d`` wins: some exporters write ``Tr`` with the opposite
    meaning, ``d`` is the standard statement."""
    out: dict[str, MtlMaterial] = {}
    cur: dict | None = None

    def close():
        if cur is not None:
            if cur["d"] is not None:
                transparent = cur["d"] < 1.0
            else:
                transparent = cur["tr"] is not None and cur["tr"] > 0.0
            out[cur["name"]] = MtlMaterial(cur["name"], transparent, cur["map"], cur["kd"])

    for _, parts in _statements(text):
        tag = parts[0].lower()
        if tag == "newmtl":
            close()
            cur = {"name": " ".join(parts[1:]), "d": None, "tr": None, "map": "", "kd": None}
        elif cur is None:
            continue
        elif tag in ("d", "tr") and len(parts) > 1:
            try:
                value = float(parts[-1])  # "d -halo 0.5": the factor is last
            except ValueError:
                continue
            cur["d" if tag == "d" else "tr"] = value
        elif tag == "kd" and len(parts) >= 4:
            try:
                rgb = [min(max(float(x), 0.0), 1.0) for x in parts[1:4]]
            except ValueError:
                continue  # "Kd spectral file.rfl", "Kd xyz ...": not an RGB we read
            cur["kd"] = (*(int(round(255 * c)) for c in rgb), 255)
        elif tag == "map_kd" and len(parts) > 1:
            cur["map"] = _map_path(parts[1:])
    close()
    return out


def read_mtl(path: str) -> dict[str, MtlMaterial]:
    with open(path, encoding="utf-8", errors="replace") as f:
        return parse_mtl(f.read())


def mtllib_names(path: str, limit: int = 1 << 20) -> list[str]:
    """``mtllib`` file names of an OBJ without parsing the geometry (scans at most ``limit``
    bytes of text: exporters write ``mtllib`` in the header)."""
    names: list[str] = []
    with open(path, encoding="utf-8", errors="replace") as f:
        head = f.read(limit)
    for line in head.splitlines():
        s = line.strip()
        if s.startswith("mtllib"):
            names.extend(s.split()[1:])
    return names


def obj_materials(obj_path: str, mtllibs: list[str] | None = None) -> dict[str, MtlMaterial]:
    """Every material of the MTL libraries an OBJ names (``<stem>.mtl`` when it names none),
    texture paths rewritten relative to the OBJ's directory. Missing or unreadable libraries are
    skipped (the geometry is still valid)."""
    base = os.path.dirname(obj_path)
    if mtllibs is None:
        mtllibs = mtllib_names(obj_path)
    if not mtllibs:
        stem = os.path.splitext(os.path.basename(obj_path))[0] + ".mtl"
        mtllibs = [stem] if os.path.isfile(os.path.join(base, stem)) else []
    out: dict[str, MtlMaterial] = {}
    for lib in mtllibs:
        lib_path = os.path.join(base, lib.replace("\\", "/"))
        try:
            mats = read_mtl(lib_path)
        except OSError:
            continue
        lib_dir = posixpath.dirname(lib.replace("\\", "/"))
        for name, m in mats.items():
            tex = posixpath.normpath(posixpath.join(lib_dir, m.texture)) if m.texture else ""
            out.setdefault(name, MtlMaterial(name, m.transparent, tex, m.color))
    return out


def missing_mtl_libraries(obj_path: str, mtllibs: list[str] | None = None) -> list[str]:
    """The ``mtllib`` names of an OBJ (as written, in order) whose files do not exist next to it.
    An OBJ that names no library misses none (its ``<stem>.mtl`` is optional)."""
    base = os.path.dirname(obj_path)
    if mtllibs is None:
        try:
            mtllibs = mtllib_names(obj_path)
        except OSError:
            return []
    out: list[str] = []
    for lib in mtllibs:
        if not os.path.isfile(os.path.join(base, lib.replace("\\", "/"))) and lib not in out:
            out.append(lib)
    return out


def mtl_files(obj_path: str) -> list[str]:
    """Absolute paths of the existing MTL libraries of an OBJ (for fingerprints)."""
    base = os.path.dirname(obj_path)
    try:
        names = mtllib_names(obj_path)
    except OSError:
        return []
    if not names:
        names = [os.path.splitext(os.path.basename(obj_path))[0] + ".mtl"]
    out = []
    for n in names:
        p = os.path.abspath(os.path.join(base, n.replace("\\", "/")))
        if os.path.isfile(p) and p not in out:
            out.append(p)
    return out
