"""Mesh cleaning and winding repair of standardization, per part (vertices ``(N, 3)`` float64,
faces ``(M, 3)`` int64, any frame and units).

Cleaning (:func:`clean_part`): coincident vertices welded, degenerate and duplicate faces dropped,
then unreferenced vertices. Winding (:func:`rewind`, :func:`fix_inverted`): a closed but
inconsistently wound part is re-wound by a breadth-first walk over its faces; closed bodies that
are inside out are flipped unless they are the inner shell of a hollow solid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

from carlaocc.stages.geometry import DEGENERATE_REL

# vertices closer than this fraction of the asset's bounding-box diagonal are one vertex
WELD_REL = 1e-9



# --------------------------------------------------------------------------------------------
# cleaning
# --------------------------------------------------------------------------------------------


@dataclass
class CleanedPart:
    """A part after :func:`clean_part`: its arrays and how many faces and vertices were removed."""

    vertices: np.ndarray
    faces: np.ndarray
    degenerate: int
    duplicates: int
    unreferenced: int
    face_index: np.ndarray | None = None  # (M,) int64: the input face each kept face is


def _weld(v: np.ndarray, f: np.ndarray, quantum: float) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices at the same position (to ``quantum``): exporters split vertices along
    seams (normals, UVs), which would make every closed mesh look open. First occurrence wins."""
    if len(v) == 0 or quantum <= 0:
        return v, f
    keys = np.round(v / quantum).astype(np.int64)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    # keep the welded vertices in their original order
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return v[first[order]], rank[inverse.reshape(-1)][f]


def clean_part(v: np.ndarray, f: np.ndarray, tol2: float, quantum: float = 0.0) -> CleanedPart:
    """Weld coincident vertices, drop degenerate then duplicate faces, then unreferenced
    vertices (order kept)."""
    v, f = _weld(v, f, quantum)
    n_in = len(f)
    # repeated index, or (twice the) area below the tolerance
    repeated = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 2] == f[:, 0])
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    flat = np.einsum("ij,ij->i", cross, cross) <= tol2 * tol2
    index = np.flatnonzero(~(repeated | flat))  # which input faces survive, in order
    f = f[index]
    degenerate = n_in - len(f)
    # duplicates: same sorted vertex triple; the first occurrence wins
    if len(f):
        _, first = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
        keep = np.sort(first)
        duplicates = len(f) - len(keep)
        f, index = f[keep], index[keep]
    else:
        duplicates = 0
    # unreferenced vertices: renumber the used ones in their original order
    used = np.zeros(len(v), dtype=bool)
    used[f.ravel()] = True
    remap = np.cumsum(used) - 1
    return CleanedPart(v[used], remap[f].reshape(-1, 3).astype(np.int64), degenerate, duplicates,
                       int(len(v) - used.sum()), index.astype(np.int64))


# --------------------------------------------------------------------------------------------
# winding
# --------------------------------------------------------------------------------------------


def _edges(f: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Directed edges (a -> b) of every face, and the face each belongs to (3M each)."""
    a = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
    b = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    return a, b, np.tile(np.arange(len(f)), 3)


def is_closed(f: np.ndarray) -> bool:
    """Every undirected edge shared by exactly two faces (orientation not considered)."""
    if len(f) == 0:
        return False
    a, b, _ = _edges(f)
    n = int(f.max()) + 1
    _, counts = np.unique(np.minimum(a, b) * n + np.maximum(a, b), return_counts=True)
    return bool(np.all(counts == 2))


def _flip(f: np.ndarray, mask: np.ndarray) -> np.ndarray:
    out = f.copy()
    out[mask] = out[mask][:, ::-1]
    return out


def rewind(f: np.ndarray) -> tuple[np.ndarray, int]:
    """Make a closed (edge-manifold) mesh consistently wound: breadth-first over the faces of each
    connected body, keeping each body's first face as it is. Returns the faces and how many were
    flipped. A non-orientable surface stays inconsistent (the caller re-checks)."""
    m = len(f)
    a, b, face = _edges(f)
    n = int(f.max()) + 1
    key = np.minimum(a, b) * n + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    # closed: sorted keys come in pairs (i, j) sharing one undirected edge
    i, j = order[0::2], order[1::2]
    fi, fj = face[i], face[j]
    # the two faces agree when they walk the shared edge in opposite directions
    rel = (a[i] == a[j]).astype(np.int8)  # 1: one of them must be flipped relative to the other
    pair = np.minimum(fi, fj).astype(np.int64) * m + np.maximum(fi, fj)
    pair, first = np.unique(pair, return_index=True)
    fi, fj, rel = pair // m, pair % m, rel[first]
    # a virtual root (index m) linked to one face of every body, so one BFS covers all bodies
    adj = sparse.coo_matrix((np.ones(len(fi)), (fi, fj)), shape=(m + 1, m + 1)).tocsr()
    _, body = csgraph.connected_components(adj[:m, :m], directed=False)
    _, seeds = np.unique(body, return_index=True)
    rows = np.concatenate([fi, fj, seeds, np.full(len(seeds), m)])
    cols = np.concatenate([fj, fi, np.full(len(seeds), m), seeds])
    vals = np.concatenate([rel, rel, np.zeros(2 * len(seeds), np.int8)]).astype(np.float64) + 1.0
    graph = sparse.csr_matrix((vals, (rows, cols)), shape=(m + 1, m + 1))
    _, pred = csgraph.breadth_first_order(graph, m, directed=False, return_predecessors=True)
    # parity of every face relative to its body's seed, by pointer jumping up the BFS tree
    ptr = np.where(pred < 0, np.arange(m + 1), pred)
    ptr[m] = m
    nodes = np.arange(m + 1)
    parity = (np.asarray(graph[nodes, ptr]).ravel() - 1.0).clip(0).astype(np.int8)
    parity[m] = 0
    parity[seeds] = 0
    ptr[seeds] = m
    while np.any(ptr != m):
        parity = parity ^ parity[ptr]
        ptr = ptr[ptr]
    flip = parity[:m].astype(bool)
    return _flip(f, flip), int(flip.sum())


def fix_inverted(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, int]:
    """Flip the closed bodies of a consistently wound part whose signed volume is negative,
    unless the body lies inside another body's bounding box (an inner shell of a hollow solid).
    Returns the faces and how many bodies were flipped."""
    n = len(v)
    adj = sparse.coo_matrix((np.ones(2 * len(f)), (np.r_[f[:, 0], f[:, 1]], np.r_[f[:, 1], f[:, 2]])), shape=(n, n))
    count, label = csgraph.connected_components(adj, directed=False)
    body = label[f[:, 0]]
    tri = v[f]
    vol = np.bincount(body, weights=np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])),
                      minlength=count) / 6.0
    negative = np.flatnonzero(vol < 0.0)
    if len(negative) == 0:
        return f, 0
    lo = np.full((count, 3), np.inf)
    hi = np.full((count, 3), -np.inf)
    np.minimum.at(lo, label, v)
    np.maximum.at(hi, label, v)
    flip_bodies = []
    for c in negative:
        inside = np.all(lo <= lo[c], axis=1) & np.all(hi >= hi[c], axis=1)
        inside[c] = False
        if not inside.any():
            flip_bodies.append(c)
    if not flip_bodies:
        return f, 0
    return _flip(f, np.isin(body, flip_bodies)), len(flip_bodies)
