"""The registered stages, in dependency order: ingest -> scenes -> splits, voxelize, sensors ->
quality -> aggregate -> report. Each stage's spec (partitions, prepare, task) lives in its wiring module,
``carlaocc.pipeline.tasks.<stage>``; this module only lists them."""

from __future__ import annotations

from carlaocc.pipeline.engine.spec import StageSpec
from carlaocc.pipeline.tasks import aggregate, ingest, quality, report, scenes, sensors, splits, voxelize

STAGES: dict[str, StageSpec] = {m.SPEC.name: m.SPEC for m in (ingest, scenes, splits, voxelize, sensors, quality,
                                                                aggregate, report)}
# earlier stage names, refused with the name to use instead
RETIRED_STAGES: dict[str, str] = {"metrics": "quality"}
