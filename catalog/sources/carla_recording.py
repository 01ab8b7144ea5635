"""The foreground meshes of a CARLA recording in the CarlaOcc release layout
(:mod:`carlaocc.catalog.carla_recording`) as an ADMesh source (``carlaocc ingest carla-recording``).

Items, keyed by their path under ``SceneMeshes/fg_actors/``:

* **vehicle models** ``<Class>/<blueprint with '.' -> '_'>.obj`` (the class folder names a
  taxonomy class: Car, Truck, Bus, Motorcycle, Bicycle): the blueprint's mesh in its actor frame;
  sub-class from the blueprint's words (taxi, police, fire truck...), else the class's first;
* **the walk cycle** ``Pedestrians/standard_walking/frame_XX.obj``: CARLA's walker posed at each
  of the cycle's frames, class Pedestrian, sub-class ``adult``.

Declared frames: the export's mesh axes, y up; vehicles face +x (metres), the walk cycle walks
along +z (units undeclared: the export converted it at scale 1 from an animation in centimetres,
so standardization infers them from the walker's size). Standardization turns them into the asset frame, so
the importer places an asset with ``actor pose @ T(offset)``, the offset being the bottom centre
of the mesh's bounds in the actor frame (see :func:`model_offset`). The walk cycle's bone files
are read by the importer, not ingested. Anything else under ``fg_actors/`` (FBX, ``frame_info``)
is ignored. Licence: CARLA's assets are CC-BY 4.0.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from carlaocc.catalog.carla_recording import MESH_TO_WORLD, RecordingError, discover, read_mesh
from carlaocc.catalog.sources._common import default_subclass, drop_excluded, semantic_class
from carlaocc.catalog.sources.base import SourceError, SourceItem
from carlaocc.schemas.meshes import SourceAsset, SourcePart

__all__ = ["CarlaRecordingAdapter", "model_offset", "WALK_CYCLE", "vehicle_subclass"]

LICENCE = "CC-BY-4.0 (CARLA assets)"
WALK_CYCLE = "Pedestrians/standard_walking"
_FRAME = re.compile(r"^frame_(\d+)$")
# blueprint words -> sub-class (first match wins)
_SUBCLASS_WORDS = (("taxi", "taxi"), ("police", "police"), ("dodgecop", "police"), ("patrol", "suv"),
                   ("firetruck", "fire_truck"), ("ambulance", "box_truck"), ("carlacola", "box_truck"),
                   ("sprinter", "van"), ("mini", "hatchback"), ("mustang", "coupe"), ("tt", "coupe"),
                   ("impala", "sedan"), ("mkz", "sedan"), ("charger", "sedan"), ("fuso", "city_bus"))  # fmt: skip


def vehicle_subclass(category: str, blueprint: str) -> str:
    """The sub-class of a vehicle blueprint (``vehicle.taxi.ford`` -> taxi), else the class's first."""
    cls = semantic_class(category)
    words = set(re.split(r"[._]", blueprint.lower()))
    for word, sub in _SUBCLASS_WORDS:
        if word in words and sub in cls.subclasses:
            return sub
    return default_subclass(cls)


def model_offset(vertices: np.ndarray) -> np.ndarray:
    """The asset frame's origin in the actor frame: the bottom centre of the bounds of
    ``vertices`` (the model in our axes, actor frame), where standardization puts the origin."""
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    return np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])


class CarlaRecordingAdapter:
    """Vehicle models and walk-cycle frames of a recording (see the module docstring)."""

    kind = "carla-recording"

    def list_items(self, root: str, exclude: tuple[str, ...] = ()) -> list[SourceItem]:
        try:
            rec = discover(root)
        except RecordingError as exc:
            raise SourceError("not a CARLA recording", str(exc)) from None
        fg = rec.root / "SceneMeshes" / "fg_actors"
        if not fg.is_dir():
            raise SourceError("not a CARLA recording", f"{fg}: missing (the vehicle models and the walk cycle)")
        items = []
        for obj in sorted(fg.rglob("*.obj")):
            rel = obj.relative_to(fg).as_posix()
            parent = obj.parent.relative_to(fg).as_posix()
            if parent == WALK_CYCLE and _FRAME.match(obj.stem):
                meta = {"kind": "walk", "frame": int(_FRAME.match(obj.stem)[1])}
            elif "/" not in parent and parent != "Pedestrians":
                meta = {"kind": "vehicle", "category": parent, "blueprint": obj.stem}
            else:
                continue
            items.append(SourceItem(key=rel, files=(str(obj),), meta={**meta, "path": str(obj)}))
        return drop_excluded(items, exclude)

    def read(self, root: str, item: SourceItem) -> SourceAsset:
        meta = item.meta
        try:
            V, F = read_mesh(meta["path"])
        except RecordingError as exc:
            raise SourceError("unreadable file" if os.path.exists(meta["path"]) else "missing mesh", str(exc)) from None
        # back to the export's mesh axes: standardization is told them (y up) and does the turn
        parts = (SourcePart(name=Path(meta["path"]).stem, vertices=V @ MESH_TO_WORLD, faces=F),)
        if meta["kind"] == "walk":
            return SourceAsset(source=self.kind, source_path=f"fg_actors/{item.key}", licence=LICENCE,
                               category="Pedestrian", subclass="adult", parts=parts, up="+y", forward="+z",
                               units="unknown")  # fmt: skip
        try:
            cls = semantic_class(meta["category"])
        except KeyError:
            raise SourceError("unknown category", f"{meta['path']}: class folder {meta['category']!r} is not a "
                                                  f"taxonomy class") from None  # fmt: skip
        return SourceAsset(source=self.kind, source_path=f"fg_actors/{item.key}", licence=LICENCE, category=cls.name,
                           subclass=vehicle_subclass(cls.name, meta["blueprint"]), parts=parts, up="+y", forward="+x",
                           units="m")  # fmt: skip
