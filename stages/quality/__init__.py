"""Dataset-quality scores over occupancy grids (paper 4.2): spatial continuity (`continuity`: isolated voxels per class, per frame and sequence) and temporal consistency (`temporal`: a frame warped into the previous one by the LiDAR poses, IoU of static classes)."""

from carlaocc.stages.quality.continuity import (
    ContinuityCounts,
    isolated_mask_reference,
    sequence_continuity,
    spatial_continuity_counts,
)
from carlaocc.stages.quality.temporal import (
    TemporalCounts,
    column_ranges,
    relative_pose,
    sequence_temporal,
    static_table,
    temporal_consistency_counts,
)

__all__ = [
    "ContinuityCounts",
    "TemporalCounts",
    "column_ranges",
    "isolated_mask_reference",
    "relative_pose",
    "sequence_continuity",
    "sequence_temporal",
    "spatial_continuity_counts",
    "static_table",
    "temporal_consistency_counts",
]
