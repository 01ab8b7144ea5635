"""Ingestion stage: source objects to standardized ADMesh assets, and the built-in procedural source.

* ``procedural/``  — the built-in procedural source (parametric assets by family; the catalogue
  and :func:`ingest_procedural`).
* ``standardize``  — a :class:`~carlaocc.schemas.meshes.SourceAsset` to an ADMesh asset (records
  and geometry in the asset frame) or a ``Rejection``; the driver of the steps below.
* ``checks``       — ``Rejection`` and the label and array checks.
* ``repair``       — mesh cleaning (weld, degenerate and duplicate faces) and winding repair.
* ``sizes``        — the size table per class and sub-class, the scale to metres and the
  smallest extent a class allows (things are never flat).
"""

from carlaocc.stages.ingest.procedural import IngestResult, asset_id_for, ingest_procedural

__all__ = ["IngestResult", "asset_id_for", "ingest_procedural"]
