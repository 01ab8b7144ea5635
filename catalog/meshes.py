"""Standardized meshes as GLB files: one node per part, written atomically.

glTF is Y-up; our frames are Z-up (+X forward). The conversion happens here and nowhere else:
on save ``(x, y, z) -> (x, z, -y)``, on load the inverse. It is an exact permutation and sign
flip, so nothing but float32 rounding (glTF positions are float32) changes a vertex.
"""

from __future__ import annotations

import io
import typing

import numpy as np
import trimesh

from carlaocc.catalog.store import Store, StoreError
from carlaocc.schemas.meshes import MeshPart

_Z_UP_TO_Y_UP = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])


def to_gltf_axes(vertices: np.ndarray) -> np.ndarray:
    """Our Z-up points (N, 3) in glTF's Y-up axes (x, z, -y)."""
    return np.asarray(vertices, dtype=np.float64) @ _Z_UP_TO_Y_UP.T


def from_gltf_axes(vertices: np.ndarray) -> np.ndarray:
    """glTF Y-up points (N, 3) back in our Z-up axes (the inverse rotation)."""
    return np.asarray(vertices, dtype=np.float64) @ _Z_UP_TO_Y_UP


def glb_bytes(parts: typing.Sequence[MeshPart]) -> bytes:
    """Serialize parts (asset frame, Z up, metres) into one GLB (geometry names ``p000``, ``p001``...
    keep the part order; each part's RGBA ``color`` becomes its face colour)."""
    scene = trimesh.Scene()
    for i, part in enumerate(parts):
        mesh = trimesh.Trimesh(vertices=to_gltf_axes(part.vertices), faces=part.faces,
                               process=False)
        mesh.visual = trimesh.visual.ColorVisuals(mesh, face_colors=np.tile(part.color, (len(part.faces), 1)))
        # names carry only the order: part names live in the parts table, so identical geometry
        # from two files is byte-identical on disk
        scene.add_geometry(mesh, geom_name=f"p{i:03d}", node_name=f"p{i:03d}")
    return scene.export(file_type="glb")


def load_glb_arrays(data: bytes) -> list[tuple[np.ndarray, np.ndarray]]:
    """(vertices, faces) per part of a GLB written by :func:`glb_bytes`, in part order, Z-up."""
    scene = trimesh.load(io.BytesIO(data), file_type="glb", force="scene", process=False)
    out = []
    for name in sorted(scene.geometry):
        g = scene.geometry[name]
        v = from_gltf_axes(g.vertices)
        out.append((v, np.asarray(g.faces, dtype=np.int64)))
    return out


class MeshStore:
    """GLB meshes in a store, addressed by store-relative path."""

    def __init__(self, store: Store):
        self.store = store

    def save(self, rel: str, parts: typing.Sequence[MeshPart]) -> str:
        if not parts:
            raise ValueError(f"{rel}: a mesh needs at least one part")
        return self.store.write_bytes(rel, glb_bytes(parts))

    def exists(self, rel: str) -> bool:
        return self.store.exists(rel)

    def load(self, rel: str) -> list[tuple[np.ndarray, np.ndarray]]:
        try:
            return load_glb_arrays(self.store.read_bytes(rel))
        except StoreError:
            raise
        except Exception as exc:
            raise StoreError(f"cannot read mesh {rel} in {self.store.url}: {exc}") from None
