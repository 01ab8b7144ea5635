"""Adapter kinds by name: ``adapter("folder", category_map="map.csv")``."""

from __future__ import annotations

import inspect

from carlaocc.catalog.sources.buildingnet import BuildingNetAdapter
from carlaocc.catalog.sources.carla import CarlaAdapter
from carlaocc.catalog.sources.carla_recording import CarlaRecordingAdapter
from carlaocc.catalog.sources.folder import FolderAdapter
from carlaocc.catalog.sources.meshfleet import MeshFleetAdapter
from carlaocc.catalog.sources.shapenet import ShapeNetAdapter

ADAPTERS: dict[str, type] = {
    cls.kind: cls
    for cls in (FolderAdapter, ShapeNetAdapter, BuildingNetAdapter, MeshFleetAdapter, CarlaAdapter, CarlaRecordingAdapter)
}


def adapter(kind: str, **options):
    """A new adapter of ``kind`` built with ``options``. An option whose value is None counts as
    not given (callers pass ``category_map=None`` to every kind). ValueError naming the valid
    kinds for an unknown kind, and the accepted options for an option the adapter does not take."""
    options = {k: v for k, v in options.items() if v is not None}
    cls = ADAPTERS.get(kind)
    if cls is None:
        raise ValueError(f"unknown source kind {kind!r}; valid kinds: {', '.join(sorted(ADAPTERS))}")
    params = [p for p in inspect.signature(cls.__init__).parameters if p != "self"]
    unknown = sorted(set(options) - set(params))
    if unknown:
        accepted = ", ".join(params) or "none"
        raise ValueError(f"source kind {kind!r} takes no option(s) {', '.join(unknown)}; "
                         f"accepted: {accepted}")  # fmt: skip
    return cls(**options)
