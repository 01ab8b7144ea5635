"""BuildingNet: building OBJs whose parts (components) carry BuildingNet labels.

Layout accepted
    ``<root>/**/<name>.obj`` with its label file ``<name>_label.json`` in the same directory, or
    in ``labels_dir`` (an option, relative to ``root``) for a split layout such as
    ``OBJ_MODELS/`` + ``component_labels/``. One item per OBJ, key = the OBJ path relative to
    ``root`` without ``.obj``. An OBJ without a label file is still listed; reading it raises
    ``SourceError("bad metadata")``.

Label file
    JSON, either a flat mapping ``{"<component>": <label>, ...}`` or an object
    ``{"labels": {...}, "subclass": "...", "licence": "..."}``. A component is an OBJ ``g`` group
    or ``o`` object name (BuildingNet writes ``o <component index>``): the group name is tried
    first, then the object name, each exact then case-insensitive, so an unlabeled group inherits
    its object's label. An ``o`` record starts a new object with no group. A label is a BuildingNet label
    name (``"window"``) or its id in BuildingNet's 32-label list (:data:`BUILDINGNET_LABELS`,
    0 = undetermined); a taxonomy class name is accepted too. A label file matching no component
    of the OBJ (e.g. BuildingNet's per-*point* ``_label.json``) is ``"bad metadata"``.

Label table (part ``semantic_id``; ``None`` = the asset's class, Building)
    ============================================================== =========================
    window, glass, door_glass, windowpane                           Building, transparent,
                                                                    material "glass"
    wall, roof, floor, ceiling, door, stairs, banister, beam, column, Building
    tower, chimney, corridor, balcony, garage, dome, parapet,
    buttress, dormer, arch, awning, shutters
    fence, gate                                                     Fence
    plant, vegetation, tree, bush, hedge                            Vegetation
    grass, terrain                                                  Terrain
    ground                                                          Ground
    road                                                            Road
    pool, water                                                     Water
    lighting                                                        Pole (lamp posts)
    furniture                                                       Static
    vehicle                                                         Car (a car modelled with the
                                                                    building, still one asset)
    undetermined, unlabeled parts                                   None (Building)
    ============================================================== =========================

    Window parts are transparent whatever their MTL says; other parts are transparent when their
    MTL material is (``d < 1`` or ``Tr > 0``).

Declarations
    One Building asset per file. Sub-class: the label file's ``subclass`` if given, else from
    BuildingNet's name prefix (``RESIDENTIALhouse_mesh0001``: RESIDENTIAL -> residential, with
    house/villa -> house and apartment -> apartment; RELIGIOUS -> religious; COMMERCIAL ->
    commercial; PUBLIC/CIVIC/EDUCATIONAL/GOVERNMENT -> public; INDUSTRIAL -> industrial),
    else ``"residential"``. Units ``"unknown"`` (3D Warehouse models in mixed units). BuildingNet
    OBJs are Y-up (its point-cloud pipeline rotates about y; the models come from SketchUp via
    Y-up COLLADA->OBJ conversion): up ``"+y"``, forward ``"+z"`` (no front is defined for
    buildings; +z is declared for a consistent frame). Licence: the file's ``licence`` or
    ``"BuildingNet terms of use"``; not required.
"""

from __future__ import annotations

import os
import re

from carlaocc.catalog.sources._common import (check_subclass, compact, is_excluded, make_part, obj_appearance,
                                              missing_file_notes, read_json_object, semantic_class,
                                              sidecar_files)
from carlaocc.catalog.sources.obj import ObjError, obj_materials, read_obj
from carlaocc.catalog.sources.base import SourceError, SourceItem
from carlaocc.schemas.meshes import SourceAsset
from carlaocc.schemas.taxonomy import by_name

LICENCE = "BuildingNet terms of use"

# BuildingNet's label ids (MinkowskiNet/lib/eval_utils.py LABELS of the BuildingNet release).
BUILDINGNET_LABELS: tuple[str, ...] = (
    "undetermined", "wall", "window", "vehicle", "roof", "plant", "door", "tower", "furniture",
    "ground", "beam", "stairs", "column", "banister", "floor", "chimney", "ceiling", "fence",
    "pool", "corridor", "balcony", "garage", "dome", "road", "gate", "parapet", "buttress",
    "dormer", "lighting", "arch", "awning", "shutters",
)  # fmt: skip

_TRANSPARENT = {"window", "glass", "doorglass", "windowpane", "windowglass"}
_BUILDING = {
    "wall", "roof", "floor", "ceiling", "door", "stairs", "banister", "beam", "column", "tower",
    "chimney", "corridor", "balcony", "garage", "dome", "parapet", "buttress", "dormer", "arch",
    "awning", "shutters",
}  # fmt: skip
# label -> taxonomy class name (None: the asset's class)
LABEL_CLASSES: dict[str, str | None] = {
    **{k: "Building" for k in _BUILDING | _TRANSPARENT},
    "fence": "Fence", "gate": "Fence",
    "plant": "Vegetation", "vegetation": "Vegetation", "tree": "Vegetation", "bush": "Vegetation",
    "hedge": "Vegetation",
    "grass": "Terrain", "terrain": "Terrain",
    "ground": "Ground", "road": "Road", "pool": "Water", "water": "Water",
    "lighting": "Pole", "furniture": "Static", "vehicle": "Car",
    "undetermined": None, "unlabeled": None, "unlabelled": None,
}  # fmt: skip

_PREFIXES: tuple[tuple[str, str], ...] = (
    ("RESIDENTIAL", "residential"), ("RELIGIOUS", "religious"), ("COMMERCIAL", "commercial"),
    ("PUBLIC", "public"), ("CIVIC", "public"), ("EDUCATIONAL", "public"),
    ("GOVERNMENT", "public"), ("INDUSTRIAL", "industrial"),
)  # fmt: skip


def _norm(label: str) -> str:
    return re.sub(r"[^0-9a-z]", "", label.lower())


def label_class(label) -> tuple[str | None, bool]:
    """(taxonomy class name or None, transparent) of a BuildingNet label (name or id).
    KeyError for an unknown label."""
    if isinstance(label, bool):
        raise KeyError(label)
    if isinstance(label, int) or (isinstance(label, str) and label.strip().isdigit()):
        i = int(label)
        if not 0 <= i < len(BUILDINGNET_LABELS):
            raise KeyError(f"label id {i} outside 0..{len(BUILDINGNET_LABELS) - 1}")
        label = BUILDINGNET_LABELS[i]
    if not isinstance(label, str):
        raise KeyError(f"label {label!r} is neither a name nor an id")
    key = _norm(label)
    if key in LABEL_CLASSES:
        return LABEL_CLASSES[key], key in _TRANSPARENT
    return by_name(label).name, False  # a taxonomy class name; KeyError if not


def subclass_from_name(name: str) -> str | None:
    """Building sub-class implied by a BuildingNet model name (``RESIDENTIALvilla_mesh3202``)."""
    for prefix, sub in _PREFIXES:
        if name.upper().startswith(prefix) and name[: len(prefix)].isupper():
            rest = name[len(prefix) :].lower()
            if prefix == "RESIDENTIAL":
                if rest.startswith(("house", "villa", "cottage", "cabin")):
                    return "house"
                if rest.startswith("apartment"):
                    return "apartment"
            return sub
    return None


class BuildingNetAdapter:
    """BuildingNet OBJ + component label JSON (see the module docstring)."""

    kind = "buildingnet"

    def __init__(self, labels_dir: str | None = None):
        self.labels_dir = labels_dir

    def _label_path(self, root: str, obj: str) -> str | None:
        stem = os.path.splitext(os.path.basename(obj))[0] + "_label.json"
        candidates = [os.path.join(os.path.dirname(obj), stem)]
        if self.labels_dir:
            candidates.append(os.path.join(root, self.labels_dir, stem))
        return next((c for c in candidates if os.path.isfile(c)), None)

    def list_items(self, root: str, exclude: tuple[str, ...] = ()) -> list[SourceItem]:
        root = os.path.abspath(root)
        if not os.path.isdir(root):
            raise SourceError("missing mesh", f"{root} is not a directory")
        items = []
        for d, dirs, files in os.walk(root):
            dirs[:] = sorted(x for x in dirs if not x.startswith(".")
                             and not is_excluded(os.path.join(d, x), exclude))
            if exclude and is_excluded(d, exclude):  # the root itself is excluded
                dirs[:] = []
                continue
            for name in sorted(files):
                if not name.lower().endswith(".obj") or name.startswith("."):
                    continue
                obj = os.path.join(d, name)
                key = os.path.splitext(os.path.relpath(obj, root))[0].replace(os.sep, "/")
                label = self._label_path(root, obj)
                # the OBJ, its MTL libraries (transparency lives there) and its label file
                files_ = (obj, *sidecar_files(obj), *((label,) if label else ()))
                items.append(SourceItem(key=key, files=files_, meta={"labels": label}))
        items.sort(key=lambda it: it.key)
        return items

    def _read_labels(self, path: str) -> tuple[dict, dict]:
        doc = read_json_object(path, "bad metadata")
        if isinstance(doc.get("labels"), dict):
            labels, meta = doc["labels"], {k: v for k, v in doc.items() if k != "labels"}
        else:
            labels, meta = doc, {}
        return {str(k): v for k, v in labels.items()}, meta

    def read(self, root: str, item: SourceItem) -> SourceAsset:
        root = os.path.abspath(root)
        obj = os.path.join(root, item.key + ".obj")
        if not os.path.isfile(obj):
            matches = [f for f in item.files if f.lower().endswith(".obj")]
            obj = matches[0] if matches else obj
        if not os.path.isfile(obj):
            raise SourceError("missing mesh", f"{obj} does not exist")
        label_path = self._label_path(root, obj)
        if label_path is None:
            stem = os.path.splitext(os.path.basename(obj))[0]
            also = f" or in {self.labels_dir}" if self.labels_dir else ""
            raise SourceError("bad metadata", f"no label file {stem}_label.json next to {obj}{also}")
        labels, meta = self._read_labels(label_path)
        lower = {k.lower(): v for k, v in labels.items()}

        building = semantic_class("Building")
        subclass = meta.get("subclass")
        if subclass is not None:
            why = check_subclass(building, str(subclass))
            if why:
                raise SourceError("bad metadata", f"{label_path}: {why}")
        else:
            subclass = subclass_from_name(os.path.basename(item.key)) or "residential"

        try:
            data = read_obj(obj)
        except OSError as e:
            raise SourceError("unreadable file", f"{obj}: {e}") from None
        except ObjError as e:
            raise SourceError("unreadable file", f"{obj}: {e}") from None
        mtl = obj_materials(obj, data.mtllibs)

        parts, matched, taken = [], 0, set()
        for g in data.groups:
            label = None
            for name in (g.group, g.obj):
                if name and name in labels:
                    label = labels[name]
                    break
                if name and name.lower() in lower:
                    label = lower[name.lower()]
                    break
            cls_name, glass = None, False
            if label is not None:
                matched += 1
                try:
                    cls_name, glass = label_class(label)
                except KeyError:
                    raise SourceError("bad metadata", f"{label_path}: unknown label {label!r} for "
                                                      f"component {g.group or g.obj!r}") from None  # fmt: skip
            semantic_id = semantic_class(cls_name).id if cls_name else None
            mat = mtl.get(g.material)
            name = g.group or g.obj or "part"
            k, base = 1, name
            while name in taken:
                name, k = f"{base}_{k}", k + 1
            taken.add(name)
            v, f = compact(data.vertices, g.faces)
            color, corner_uv, image = obj_appearance(data, mat, g.uv_index, os.path.dirname(obj))
            parts.append(make_part(
                name, v, f,
                material="glass" if glass else (g.material or "default"),
                transparent=glass or (mat.transparent if mat else False),
                texture=mat.texture if mat else "",
                semantic_id=semantic_id, color=color, corner_uv=corner_uv, image=image,
            ))  # fmt: skip
        if parts and labels and matched == 0:
            raise SourceError("bad metadata", f"{label_path}: no label key names a g/o component "
                                              f"of {obj} (a per-point label file?)")  # fmt: skip
        return SourceAsset(
            source=self.kind,
            source_path=obj,
            licence=str(meta.get("licence", meta.get("license", LICENCE))),
            category=building.name,
            subclass=str(subclass),
            parts=tuple(parts),
            up="+y",
            forward="+z",
            units="unknown",
            normalized=False,
            target_length=None,
            licence_required=False,
            notes=tuple(missing_file_notes(obj, parts, data.mtllibs)),
        )

