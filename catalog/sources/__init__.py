"""External mesh sources: one adapter per layout, all behind :class:`carlaocc.catalog.sources.base.SourceAdapter`.

Each adapter lists a source root as items and reads one item into a
:class:`~carlaocc.schemas.meshes.SourceAsset` (parts in the source's own frame and units);
``carlaocc.stages.ingest.standardize`` makes it an ADMesh asset.

* ``base``        — the adapter interface: ``SourceItem``, ``SourceError``, ``SourceAdapter``.
* ``registry``    — adapter kinds by name (``adapter("folder", category_map=...)``).
* ``folder``      — any directory of mesh files, classified by a category map.
* ``shapenet``    — ShapeNetCore v2.
* ``buildingnet`` — BuildingNet building OBJs with labelled components.
* ``meshfleet``   — MeshFleet: a metadata CSV of Objaverse-XL vehicles plus their meshes.
* ``carla``       — CARLA / Unreal Engine asset exports (Unreal's frame converted here only).
* ``_common``     — shared reading helpers: mesh files to ``SourcePart`` s, licences, taxonomy.
* ``_obj``        — a small Wavefront OBJ + MTL reader (groups, materials).
* ``_collada``    — a small COLLADA (.dae) reader (geometry, node transforms, materials).
"""
