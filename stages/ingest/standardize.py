"""Standardization and validation of a source asset into an ADMesh asset: the driver.

Input: a :class:`~carlaocc.schemas.meshes.SourceAsset` (triangle parts in the source's frame and
units, with what the source declares about them; the catalog's source adapters return it).
Output: a :class:`StandardizedAsset` (records + geometry in the asset frame) or a
:class:`~carlaocc.stages.ingest.checks.Rejection` (quarantine). Bad data never raises.

The steps live with their concern: labels and arrays in ``checks``, cleaning and winding in
``repair``, the size table and the scale in ``sizes``; the frame and the order of the steps here.

Steps, in order:

1. **Labels and licence.** ``category`` None (or the empty class ``None``) -> ``"no category"``;
   a name the taxonomy does not know -> ``"unknown category 'X'"``; ``licence_required`` without a
   licence -> ``"missing licence"``. A sub-class outside the taxonomy's vocabulary is kept and
   recorded in :attr:`StandardizedAsset.notes` (never rejected). A part's ``semantic_id`` None
   means the asset's class.
2. **Arrays.** Faces must be ``(M, 3)`` integer triangles indexing the part's vertices
   (``"not triangles"``, ``"face index out of range"``); vertices finite
   (``"non-finite vertices"``); some faces at all (``"empty mesh"``).
3. **Cleaning, per part.** Degenerate faces (a repeated index, or zero area: twice the area below
   ``1e-12`` of the squared bounding-box diagonal) and duplicate faces (same vertex set, whatever
   the order or winding; the first is kept) are removed, then unreferenced vertices dropped. Parts
   left without faces are dropped; when none is left: ``"all faces degenerate"``. Before that,
   vertices closer than ``WELD_REL`` of the diagonal are welded (exporters split them at seams).
4. **Frame.** A proper rotation (det +1) maps the declared ``forward`` axis to +X and ``up`` to +Z
   (the source's left, ``up x forward``, goes to +Y); ``up`` and ``forward`` must be perpendicular
   (``"axes not perpendicular"``).
5. **Scale** (source units -> metres), first rule that applies:
   ``target_length`` (longest horizontal extent := target) > ``normalized`` (the measured dimension
   := the sub-class's typical size) > declared units (m, cm, mm, in: fixed factor) > ``unknown``:
   try factors 1, 0.01, 0.001, 0.0254, 0.3048 and keep one that lands the measured dimension
   inside the sub-class's [min, max] (1 when it fits, else the one closest to the typical size in
   log scale); none fits -> scale to the typical size (rule says ``"fallback"``) when the size is
   within ``FALLBACK_MAX_RATIO`` (100x) of the typical size (game units), else ``"absurd size"``.
   The measured dimension is ``"length"`` (longest horizontal extent, max of x and y) or
   ``"height"`` (z extent), per :func:`size_range`.
6. **Origin** at the bottom centre of the bounding box (x, y centred, z from 0); vertices rounded
   to 0.1 um so float noise never reaches hashes or files.
7. **Plausibility.** The measured dimension outside ``[min / 3, max * 3]`` -> ``"absurd size"``
   (the hint names the size, the range and the scale rule). A solid class (``sizes.min_extent``)
   with a zero extent on any axis -> ``"flat mesh"`` (checked before the scale), with an axis
   below its minimum extent -> ``"too thin"``; stuff may be flat (a road, a road line, a fence
   sheet).
8. **Watertightness, per part** with :func:`carlaocc.stages.geometry.is_watertight`. A part that is closed
   (every undirected edge shared by exactly two faces) but inconsistently wound is re-wound by a
   breadth-first walk over its faces; closed bodies whose signed volume is negative (inside out)
   are flipped unless they lie inside another body of the part (an inner shell of a hollow solid
   is meant to face inward). Both repairs are recorded in the notes.
9. **Fill figures.** How the voxelizer fills the asset under ``auto`` and how many of its voxels
   hole handling recovers, at a reference voxel size in the asset frame
   (:func:`carlaocc.stages.voxelize.breakdown.asset_fill`): ``AssetRecord.fill_method``,
   ``fill_voxel_size``, ``fill_voxels``, ``hole_fill_voxels``, ``hole_fill_fraction``.

Notes the source adapter attached (:attr:`SourceAsset.notes`: a missing material library or
texture file) come first in the notes; all of them end up in ``AssetRecord.notes`` (``"; "``
joined), so ``SELECT source_path, notes FROM assets WHERE notes <> ''`` finds them.

Identity: ``asset_id`` = first 16 hex digits of SHA-256 over ``category|subclass|geometry_hash|
part semantic ids``; the same standardized geometry and labels from two files give the same id.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from carlaocc.schemas import taxonomy
from carlaocc.schemas.meshes import AssetGeometry, MeshPart, SourceAsset, SourcePart
from carlaocc.schemas.records import AssetRecord, PartRecord
from carlaocc.stages.geometry import geometry_hash, is_watertight, signed_volume, surface_area
from carlaocc.stages.ingest.checks import Rejection, check_arrays, check_category
from carlaocc.stages.ingest.repair import (
    DEGENERATE_REL, WELD_REL, CleanedPart, clean_part, fix_inverted, is_closed, rewind,
)
from carlaocc.stages.ingest.sizes import (
    ABSURD_FACTOR, THIN_FACTOR, choose_scale, measured_size, min_extent, range_label, size_range,
)
from carlaocc.stages.voxelize.breakdown import asset_fill

__all__ = ["StandardizedAsset", "standardize", "rotation_to_asset_frame"]

# classes whose length runs along their forward axis: lying sideways (y > 1.1 x) is corrected
LONG_ALONG_X = frozenset({"Car", "Truck", "Bus", "Train", "Motorcycle", "Bicycle"})
SIDEWAYS_RATIO = 1.1

_AXES: dict[str, np.ndarray] = {
    f"{s}{a}": sign * np.eye(3)[i] for i, a in enumerate("xyz") for s, sign in (("+", 1.0), ("-", -1.0))
}


# --------------------------------------------------------------------------------------------
# result type
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class StandardizedAsset:
    """A standardized asset: its record (``mesh_path`` empty, no aliases), one record per part and
    the geometry in the asset frame (metres, +X forward, Z up, origin at the bottom centre).

    ``notes`` says what the source lacks (missing material or texture files), what cleaning and
    repair did and what was kept despite doubts (removed faces, re-wound parts, a sub-class
    outside the taxonomy); the asset record carries them joined in its ``notes``."""

    asset: AssetRecord
    parts: list[PartRecord]
    geometry: AssetGeometry
    notes: tuple[str, ...] = ()


# --------------------------------------------------------------------------------------------
# frame
# --------------------------------------------------------------------------------------------


def rotation_to_asset_frame(up: str, forward: str) -> np.ndarray | None:
    """3x3 proper rotation mapping the source's ``forward`` axis to +X and ``up`` to +Z (and
    ``up x forward``, the source's left, to +Y); None when the axes are not perpendicular.
    ``KeyError`` for an axis name other than ``+x``, ``-x``, ..., ``-z``."""
    u, f = _AXES[up], _AXES[forward]
    if abs(float(u @ f)) > 0.0:
        return None
    # rows: the source vectors that become +X, +Y, +Z; orthonormal with det +1 by construction
    return np.stack([f, np.cross(u, f), u])


# --------------------------------------------------------------------------------------------
# standardize
# --------------------------------------------------------------------------------------------


def _flat_axes(extent: np.ndarray) -> list[str]:
    """The axes (``"x"``, ``"y"``, ``"z"``) along which the extent is exactly zero."""
    return [a for a, e in zip("xyz", extent) if not e > 0.0]


def _fmt_extent(extent) -> str:
    return " x ".join(f"{float(e):.4g}" for e in extent)



UNCOLOURED = (200, 200, 200)
"""The colour of a part whose source gives none: cameras shade it in its class's base colour."""


def _base_colour(part: SourcePart, textured: bool) -> tuple[int, int, int, int]:
    """The part's RGBA base colour: the source material's, white under a texture that has no
    colour factor (the texture is the colour), else :data:`UNCOLOURED`; glass 110 alpha."""
    if part.color is not None:
        r, g, b = part.color[:3]
    else:
        r, g, b = (255, 255, 255) if textured else UNCOLOURED
    return (int(r), int(g), int(b), 110 if part.transparent else 255)


def _texture(part: SourcePart, face_index: np.ndarray | None, f_cleaned: np.ndarray,
             f_final: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The part's texture and its corner coordinates following the faces cleaning kept
    (``face_index``) and the faces winding repair reversed (a reversed face's corners reverse)."""
    uv = part.corner_uv
    if uv is None or part.image is None:
        return None, None
    uv = np.asarray(uv, dtype=np.float32)
    if uv.shape != (len(part.faces), 3, 2) or face_index is None:
        return None, None  # coordinates that do not describe the faces: no texture
    uv = uv[face_index]
    # a repair reverses a face as (a, b, c) -> (c, b, a): the same on its corners
    flipped = np.any(f_cleaned != f_final, axis=1)
    uv[flipped] = uv[flipped][:, ::-1]
    return np.ascontiguousarray(uv), np.ascontiguousarray(part.image, dtype=np.uint8)


def _appearance_digest(parts: list[MeshPart]) -> str:
    """``|`` and a digest of the parts' colours and textures, or "" when every part is uncoloured
    and untextured (so assets without appearance keep the ids they always had)."""
    plain = all(p.image is None and tuple(p.color[:3]) == UNCOLOURED for p in parts)
    if plain:
        return ""
    h = hashlib.sha256()
    for p in parts:
        h.update(bytes(int(c) for c in p.color))
        if p.image is not None:
            h.update(np.asarray(p.image.shape, np.int64).tobytes() + np.ascontiguousarray(p.image).tobytes())
            h.update(np.ascontiguousarray(p.corner_uv, dtype=np.float32).tobytes())
    return "|" + h.hexdigest()[:16]


def standardize(raw: SourceAsset) -> StandardizedAsset | Rejection:
    """Standardize one source asset (frame, units, cleaning, validation; see the module doc).
    Returns the records and geometry, or a :class:`Rejection` for data that cannot be used."""
    cls = check_category(raw)
    if isinstance(cls, Rejection):
        return cls
    category = cls.name
    if raw.licence_required and not (raw.licence or "").strip():
        return Rejection("missing licence", f"source '{raw.source}' requires a licence per object "
                         "and this one has none: add it to the source's metadata or drop the object")
    try:
        R = rotation_to_asset_frame(raw.up, raw.forward)
    except KeyError:
        return Rejection("bad axis", f"up {raw.up!r} / forward {raw.forward!r}: axes are one of "
                         f"{', '.join(_AXES)}")
    if R is None:
        return Rejection("axes not perpendicular", f"up {raw.up} and forward {raw.forward} must be "
                         "perpendicular axes: fix the source adapter's frame declaration")
    if not raw.parts:
        return Rejection("empty mesh", "the object has no mesh parts: check the source file")

    # arrays and part classes
    checked: list[tuple[SourcePart, np.ndarray, np.ndarray, int]] = []
    for k, part in enumerate(raw.parts):
        arrays = check_arrays(k, part)
        if isinstance(arrays, Rejection):
            return arrays
        sid = cls.id if part.semantic_id is None else part.semantic_id
        try:
            sid = taxonomy.by_id(sid).id
        except (KeyError, TypeError, ValueError):
            return Rejection("unknown part class", f"part {k} ({part.name}) has semantic id "
                             f"{part.semantic_id!r}; ids are 0..{len(taxonomy.CLASSES) - 1}")
        checked.append((part, arrays[0], arrays[1], sid))
    n_faces_in = sum(len(f) for _, _, f, _ in checked)
    if n_faces_in == 0:
        return Rejection("empty mesh", "the object's parts have no faces: check the source file")

    # cleaning, with a tolerance relative to the asset's size
    referenced = [v[np.unique(f)] for _, v, f, _ in checked if len(f)]
    allv = np.concatenate(referenced)
    diag = float(np.linalg.norm(allv.max(axis=0) - allv.min(axis=0)))
    tol2 = DEGENERATE_REL * diag * diag
    notes: list[str] = [str(n) for n in raw.notes]
    cleaned: list[tuple[SourcePart, CleanedPart, int]] = []
    for k, (part, v, f, sid) in enumerate(checked):
        c = clean_part(v, f, tol2, quantum=WELD_REL * diag)
        label = f"part {k} '{part.name}'"
        if c.degenerate or c.duplicates or c.unreferenced:
            notes.append(f"{label}: removed {c.degenerate} degenerate and {c.duplicates} duplicate "
                         f"faces, {c.unreferenced} unreferenced vertices")
        if len(c.faces) == 0:
            notes.append(f"{label}: dropped (no faces left)")
            continue
        cleaned.append((part, c, sid))
    if not cleaned:
        return Rejection("all faces degenerate", f"all {n_faces_in} faces have zero area, repeat a "
                         "vertex or duplicate another: nothing is left after cleaning")

    # frame, scale, origin
    rotated = [c.vertices @ R.T for _, c, _ in cleaned]
    allv = np.concatenate(rotated)
    lo, hi = allv.min(axis=0), allv.max(axis=0)
    # a vehicle is longer than wide: one lying sideways had its forward axis mis-declared, so its
    # long side is turned to +X (a quarter turn about +Z; front and back stay ambiguous)
    if category in LONG_ALONG_X and (hi[1] - lo[1]) > SIDEWAYS_RATIO * (hi[0] - lo[0]):
        quarter = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # +Y -> +X
        rotated = [v @ quarter.T for v in rotated]
        allv = np.concatenate(rotated)
        lo, hi = allv.min(axis=0), allv.max(axis=0)
        notes.append(f"turned a quarter about +Z: its long side lay along Y (declared forward "
                     f"{raw.forward} is sideways)")
    flat = _flat_axes(hi - lo)
    if flat and min_extent(category, raw.subclass) > 0.0:
        return Rejection("flat mesh", f"{range_label(category, raw.subclass)} is a solid object but the mesh has no "
                         f"extent along {' and '.join(flat)} of the asset frame (z up; extent {_fmt_extent(hi - lo)} in source "
                         f"units): a flat "
                         f"mesh cannot be a {category}; check the category, the up axis ({raw.up}) or the file")
    chosen = choose_scale(raw, category, hi - lo)
    if isinstance(chosen, Rejection):
        return chosen
    scale, rule = chosen
    shift = -np.array([(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0, lo[2]]) * scale
    placed = [np.round(v * scale + shift, 7) + 0.0 for v in rotated]
    allv = np.concatenate(placed)
    extent = allv.max(axis=0) - allv.min(axis=0)
    dim, rmin, _, rmax = size_range(category, raw.subclass)
    size = measured_size(extent, dim)
    if not (rmin / ABSURD_FACTOR <= size <= rmax * ABSURD_FACTOR):
        return Rejection("absurd size", f"{range_label(category, raw.subclass)} {dim} {size:.4g} m "
                         f"after standardization is outside {rmin / ABSURD_FACTOR:.3g}-"
                         f"{rmax * ABSURD_FACTOR:.3g} m (range {rmin:g}-{rmax:g} m, scale x{scale:.6g}: "
                         f"{rule}): declare the units, fix the up axis or the category")
    thin = min_extent(category, raw.subclass)
    below = [a for a, e in zip("xyz", extent) if e < thin]
    if below:
        kind = "flat mesh" if all(extent["xyz".index(a)] <= 0.0 for a in below) else "too thin"
        return Rejection(kind, f"{range_label(category, raw.subclass)} extent {_fmt_extent(extent)} m after "
                         f"standardization: {' and '.join(below)} below {thin:.3g} m (1/{THIN_FACTOR:g} of the "
                         f"smallest {dim} {rmin:g} m of the class): a {category} is not a sheet; check the "
                         "category, the up axis or the file")

    if raw.subclass not in cls.subclasses and (raw.subclass or cls.subclasses):
        known = ", ".join(cls.subclasses) or "none"
        notes.append(f"sub-class {raw.subclass!r} is not in the taxonomy's {category} sub-classes "
                     f"({known}); kept as given")

    # watertightness and winding, per part
    mesh_parts: list[MeshPart] = []
    closed: list[bool] = []
    for k, ((part, c, sid), v) in enumerate(zip(cleaned, placed)):
        f = c.faces
        f_cleaned = f
        label = f"part {k} '{part.name}'"
        tight = is_watertight(f)
        if not tight and is_closed(f):
            f2, flipped = rewind(f)
            if is_watertight(f2):
                f, tight = f2, True
                notes.append(f"{label}: closed but inconsistently wound; winding fixed ({flipped} faces flipped)")
            else:
                notes.append(f"{label}: closed but not orientable; winding left as is")
        if tight:
            f2, bodies = fix_inverted(v, f)
            if bodies:
                f = f2
                notes.append(f"{label}: {bodies} inside-out bodies flipped outward")
        corner_uv, image = _texture(part, c.face_index, f_cleaned, f)
        mesh_parts.append(MeshPart(
            name=part.name or f"part_{k}", vertices=v, faces=f, semantic_id=sid,
            material=part.material, transparent=bool(part.transparent),
            color=_base_colour(part, image is not None), corner_uv=corner_uv, image=image,
        ))  # fmt: skip
        closed.append(tight)

    ghash = geometry_hash([(p.vertices, p.faces) for p in mesh_parts])
    # labels and surface properties are part of identity: two files are one asset only when
    # they agree on geometry, classes, materials and transparency
    ids = ",".join(f"{p.semantic_id}:{p.material}:{int(p.transparent)}" for p in mesh_parts)
    # ... and on appearance where the source gives one (colours, textures): two copies of a mesh
    # painted or textured differently are two assets (the same bytes are always one)
    look = _appearance_digest(mesh_parts)
    aid = hashlib.sha256(f"{category}|{raw.subclass}|{ghash}|{ids}{look}".encode()).hexdigest()[:16]
    watertight = all(closed)
    geometry = AssetGeometry(asset_id=aid, parts=tuple(mesh_parts), part_closed=tuple(closed))
    # how the voxelizer fills it, and how much of its volume hole handling recovers
    fill = asset_fill(geometry)
    asset = AssetRecord(
        asset_id=aid, source=raw.source, source_path=raw.source_path, licence=raw.licence or "",
        category_id=cls.id, category=category, subclass=raw.subclass,
        extent=[float(e) for e in extent],
        vertex_count=int(sum(len(p.vertices) for p in mesh_parts)),
        face_count=int(sum(len(p.faces) for p in mesh_parts)),
        part_count=len(mesh_parts), transparent_part_count=sum(p.transparent for p in mesh_parts),
        surface_area=float(sum(surface_area(p.vertices, p.faces) for p in mesh_parts)),
        volume=float(sum(signed_volume(p.vertices, p.faces) for p in mesh_parts)) if watertight else None,
        watertight=watertight, **fill.record_fields(), scale_applied=float(scale), scale_rule=rule,
        geometry_hash=ghash, aliases=[], notes="; ".join(notes), mesh_path="",
    )  # fmt: skip
    part_records = [
        PartRecord(
            asset_id=aid, part_index=k, name=p.name, material=p.material, transparent=p.transparent,
            semantic_id=p.semantic_id, face_count=int(len(p.faces)), watertight=t, texture=part.texture or "",
            color=[int(v) for v in p.color],
        )  # fmt: skip
        for k, (p, t, (part, _, _)) in enumerate(zip(mesh_parts, closed, cleaned))
    ]
    return StandardizedAsset(asset=asset, parts=part_records, geometry=geometry, notes=tuple(notes))
