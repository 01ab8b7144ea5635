"""MeshFleet: a metadata CSV of Objaverse-XL vehicles plus a folder of their meshes.

Layout accepted
    The MeshFleet CSV (``meshfleet_with_vehicle_categories_df.csv`` as published; columns used:
    ``sha256``, ``category``, ``license``, ``fileType``, ``mesh_filename``,
    ``normalized_height_of_object``, ``normalized_depth_of_object``,
    ``normalized_width_of_object``, optional ``length_m``) and a folder of meshes named by the
    row's Objaverse-XL sha256: ``<sha256>.<ext>`` (``ext`` any case, ``fileType`` tried first,
    then ``.glb .gltf .obj .ply .stl .off .dae``); a file named as the row's ``mesh_filename``
    (the Sketchfab uid for Sketchfab rows) is accepted too.

    Options: ``csv=`` the CSV path (default: ``<root>/meshfleet_with_vehicle_categories_df.csv``,
    else the only ``*.csv`` in root), ``meshes=`` the mesh folder (default ``<root>/meshes`` if
    it exists, else ``root``); relative paths are taken from ``root``.

Items
    One per CSV row, key = sha256, listed whether or not its mesh is there: reading a row whose
    mesh is absent raises ``SourceError("missing mesh")`` naming the expected file, so the batch
    reports it and goes on. A mesh in a format trimesh cannot read (``.fbx``, ``.blend``: about
    9 % of the rows) is ``"unreadable file"`` with a conversion hint. A CSV lacking a used
    column, or unreadable, makes ``list_items`` raise ``SourceError("bad metadata")``.

Categories (``category`` column, case/separators ignored; :data:`CATEGORIES`)
    Sedan, SUV, Coupe, Hatchback, Convertible, Pickup, Minivan, Van, Wagon, Taxi -> Car with that
    sub-class; Sports Car and race car -> Car/coupe (road-legal GT/race cars); MPV -> minivan;
    police car -> police; truck -> Truck; bus -> Bus; motorcycle -> Motorcycle; bicycle ->
    Bicycle. Anything else (other, boat...) raises ``SourceError("no category")``.

Sizes
    MeshFleet's ``normalized_*_of_object`` columns are proportions, not lengths: they are
    measured on renders (view widths in pixels over the mean pixel height), so the height is 1.0
    in every published row and ``normalized_depth_of_object`` is the vehicle's length over its
    height, ``normalized_width_of_object`` its width over its height. They never become
    ``target_length``; they are kept in ``SourceItem.meta`` (``length_to_height``,
    ``width_to_height``) for checks. ``target_length`` comes only from a ``length_m`` column
    (metres) when a user adds one. ``normalized=True`` (MeshFleet sizes are normalized, the
    Objaverse originals are in arbitrary units), units ``"unknown"``: sizes are inferred from the
    sub-class size range.

Declarations
    Axes by mesh format (glTF +y up / +z forward per the spec; Objaverse-XL is mostly GLB), or the
    ``up=``/``forward=`` options for a mesh folder known to follow another convention (MeshFleet
    itself records no orientation: its sizes are measured on renders).
    Licence: the row's ``license`` column (``""`` when empty), ``licence_required=True``: a row
    without a licence is quarantined.
"""

from __future__ import annotations

import csv
import math
import os
import re
import sys

from carlaocc.catalog.sources._common import (
    MESH_EXTS,
    check_axes,
    default_axes,
    drop_excluded,
    load_parts,
    missing_file_notes,
    semantic_class,
    sidecar_files,
)
from carlaocc.catalog.sources.base import SourceError, SourceItem
from carlaocc.schemas.meshes import SourceAsset

DEFAULT_CSV = "meshfleet_with_vehicle_categories_df.csv"
_REQUIRED = ("sha256", "category", "license")
_UNSUPPORTED = (".fbx", ".blend", ".3ds", ".max", ".usdz", ".usd", ".abc")

# normalized category -> (class, sub-class)
CATEGORIES: dict[str, tuple[str, str]] = {
    "sedan": ("Car", "sedan"), "saloon": ("Car", "sedan"), "suv": ("Car", "suv"),
    "coupe": ("Car", "coupe"), "sportscar": ("Car", "coupe"), "racecar": ("Car", "coupe"),
    "hatchback": ("Car", "hatchback"), "convertible": ("Car", "convertible"),
    "cabriolet": ("Car", "convertible"), "wagon": ("Car", "wagon"),
    "stationwagon": ("Car", "wagon"), "estate": ("Car", "wagon"), "van": ("Car", "van"),
    "minivan": ("Car", "minivan"), "mpv": ("Car", "minivan"), "pickup": ("Car", "pickup"),
    "pickuptruck": ("Car", "pickup"), "taxi": ("Car", "taxi"), "policecar": ("Car", "police"),
    "car": ("Car", "sedan"),
    "truck": ("Truck", "box_truck"), "boxtruck": ("Truck", "box_truck"),
    "firetruck": ("Truck", "fire_truck"), "semitruck": ("Truck", "semi_truck"),
    "bus": ("Bus", "city_bus"), "schoolbus": ("Bus", "school_bus"), "minibus": ("Bus", "minibus"),
    "motorcycle": ("Motorcycle", "sport"), "motorbike": ("Motorcycle", "sport"),
    "scooter": ("Motorcycle", "scooter"),
    "bicycle": ("Bicycle", "city_bike"), "bike": ("Bicycle", "city_bike"),
}  # fmt: skip


def _norm(s: str) -> str:
    return re.sub(r"[^0-9a-z]", "", s.lower())


def _float(s) -> float | None:
    try:
        v = float(s)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


class MeshFleetAdapter:
    """MeshFleet CSV + sha256-named meshes (see the module docstring)."""

    kind = "meshfleet"

    def __init__(self, csv: str | None = None, meshes: str | None = None,
                 up: str | None = None, forward: str | None = None):  # fmt: skip
        self.csv = csv
        self.meshes = meshes
        if (up is None) != (forward is None):
            raise ValueError("meshfleet: give both up and forward, or neither")
        if up is not None:
            why = check_axes(up, forward)
            if why:
                raise ValueError(f"meshfleet: {why}")
        self.up, self.forward = up, forward

    def _csv_path(self, root: str) -> str:
        if self.csv:
            return os.path.abspath(os.path.join(root, self.csv))
        default = os.path.join(root, DEFAULT_CSV)
        if os.path.isfile(default):
            return default
        names = os.listdir(root) if os.path.isdir(root) else []
        found = sorted(n for n in names if n.lower().endswith(".csv"))
        if len(found) == 1:
            return os.path.join(root, found[0])
        raise SourceError("bad metadata", f"no {DEFAULT_CSV} in {root}"
                                          + (f" and {len(found)} other CSVs" if found else "")
                                          + "; pass csv=<path>")  # fmt: skip

    def _mesh_dir(self, root: str) -> str:
        if self.meshes:
            return os.path.abspath(os.path.join(root, self.meshes))
        sub = os.path.join(root, "meshes")
        return sub if os.path.isdir(sub) else root

    def _rows(self, path: str) -> list[dict]:
        csv.field_size_limit(min(sys.maxsize, 2**31 - 1))  # captions run to several kB
        try:
            with open(path, newline="", encoding="utf-8-sig") as f:
                reader = csv.DictReader(f)
                header = reader.fieldnames or []
                missing = [c for c in _REQUIRED if c not in header]
                if missing:
                    raise SourceError("bad metadata", f"{path}: lacks column(s) {', '.join(missing)}")
                return list(reader)
        except FileNotFoundError:
            raise SourceError("bad metadata", f"{path} not found") from None
        except (OSError, UnicodeDecodeError, csv.Error) as e:
            raise SourceError("bad metadata", f"{path}: {e}") from None

    @staticmethod
    def _candidates(row: dict) -> list[str]:
        sha = (row.get("sha256") or "").strip().lower()
        ftype = "." + (row.get("fileType") or "").strip().lower().lstrip(".")
        exts = ([ftype] if ftype in MESH_EXTS else []) + [e for e in MESH_EXTS if e != ftype]
        names = [sha + e for e in exts]
        mf = (row.get("mesh_filename") or "").strip()
        if mf and os.path.basename(mf) == mf:
            names.append(mf)
        return names

    def list_items(self, root: str, exclude: tuple[str, ...] = ()) -> list[SourceItem]:
        root = os.path.abspath(root)
        path = self._csv_path(root)
        mesh_dir = self._mesh_dir(root)
        rows = self._rows(path)
        try:
            present = {n.lower(): n for n in os.listdir(mesh_dir)}
        except OSError:
            present = {}
        items, seen = [], set()
        for no, row in enumerate(rows, start=2):
            sha = (row.get("sha256") or "").strip().lower()
            key = sha or f"row{no}"
            if key in seen:
                key = f"{key}#row{no}"
            seen.add(key)
            mesh = next((present[n.lower()] for n in self._candidates(row) if n.lower() in present), None)
            meta = {
                "csv": path,
                "line": no,
                "mesh_dir": mesh_dir,
                "mesh": os.path.join(mesh_dir, mesh) if mesh else None,
                "sha256": sha,
                "category": (row.get("category") or "").strip(),
                "license": (row.get("license") or "").strip(),
                "fileType": (row.get("fileType") or "").strip(),
                "mesh_filename": (row.get("mesh_filename") or "").strip(),
                "length_to_height": _ratio(row, "normalized_depth_of_object"),
                "width_to_height": _ratio(row, "normalized_width_of_object"),
                "length_m": _float(row.get("length_m")),
            }
            files = (meta["mesh"], *sidecar_files(meta["mesh"])) if mesh else ()
            items.append(SourceItem(key=key, files=files, meta=meta))
        items.sort(key=lambda it: it.key)
        return items

    def read(self, root: str, item: SourceItem) -> SourceAsset:
        meta = item.meta
        sha = meta.get("sha256", "")
        where = f"{meta.get('csv')}, line {meta.get('line')}"
        if not re.fullmatch(r"[0-9a-f]{64}", sha or ""):
            raise SourceError("bad metadata", f"{where}: sha256 {sha!r} is not 64 hex digits")
        cat = CATEGORIES.get(_norm(meta.get("category", "")))
        if cat is None:
            raise SourceError("no category", f"{where}: vehicle category "
                                             f"{meta.get('category')!r} is not mapped; known: "
                                             + ", ".join(sorted(CATEGORIES)))  # fmt: skip
        mesh_dir = meta.get("mesh_dir") or self._mesh_dir(os.path.abspath(root))
        mesh = meta.get("mesh")
        if not mesh or not os.path.isfile(mesh):
            ftype = (meta.get("fileType") or "glb").lower().lstrip(".")
            other = [os.path.join(mesh_dir, sha + e) for e in _UNSUPPORTED]
            other = [p for p in other if os.path.isfile(p)]
            if other:
                raise SourceError("unreadable file", f"{other[0]}: format not readable here; "
                                                     "convert it to .glb (e.g. with Blender)")  # fmt: skip
            raise SourceError("missing mesh", f"expected {os.path.join(mesh_dir, sha + '.' + ftype)}"
                                              " (Objaverse-XL object of that sha256; other mesh "
                                              "extensions and the row's mesh_filename accepted)")  # fmt: skip
        parts = load_parts(mesh)
        up, forward = (self.up, self.forward) if self.up else default_axes(mesh)
        cls_name, subclass = cat
        semantic_class(cls_name)  # the table names real classes
        length = meta.get("length_m")
        return SourceAsset(
            source=self.kind,
            source_path=mesh,
            licence=meta.get("license", ""),
            category=cls_name,
            subclass=subclass,
            parts=tuple(parts),
            up=up,
            forward=forward,
            units="unknown",
            normalized=True,
            target_length=length if length and length > 0 else None,
            licence_required=True,
            notes=tuple(missing_file_notes(mesh, parts)),
        )


def _ratio(row: dict, col: str) -> float | None:
    """A MeshFleet size proportion (column / normalized height), None when absent."""
    v, h = _float(row.get(col)), _float(row.get("normalized_height_of_object"))
    if v is None:
        return None
    return v / h if h else None
