"""Dataset-quality scores over occupancy grids (paper 4.2): spatial continuity (`continuity`: isolated voxels per class, per frame and sequence) and temporal consistency (`temporal`: a frame warped into the previous one by the LiDAR poses, IoU of static classes)."""

from carlaocc.stages.quality.continuity import (
    ContinuityCounts,
    continuity_and_ranges,
    isolated_mask_reference,
    pooled_continuity,
    sequence_continuity,
    spatial_continuity_counts,
)
from carlaocc.stages.quality.temporal import (
    TemporalCounts,
    column_ranges,
    pooled_temporal,
    relative_pose,
    sequence_temporal,
    static_table,
    temporal_consistency_counts,
)

__all__ = [
    "ContinuityCounts",
    "TemporalCounts",
    "column_ranges",
    "continuity_and_ranges",
    "isolated_mask_reference",
    "pooled_continuity",
    "pooled_temporal",
    "relative_pose",
    "sequence_continuity",
    "sequence_temporal",
    "spatial_continuity_counts",
    "static_table",
    "temporal_consistency_counts",
]
