"""Scenes stage: procedural towns, traffic sequences driven through them, and per-frame
panoptic scene meshes in the LiDAR frame."""

from stages.scenes.compose import compose_frame_scene
from stages.scenes.town import LaneSegment, Town, WalkLoop, build_town
from stages.scenes.traffic import SequenceResult, simulate_sequences

__all__ = [
    "LaneSegment",
    "SequenceResult",
    "Town",
    "WalkLoop",
    "build_town",
    "compose_frame_scene",
    "simulate_sequences",
]
