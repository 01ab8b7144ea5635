"""Dataset-quality metrics over occupancy grids."""

from carlaocc.stages.metrics.continuity import (
    ContinuityCounts,
    isolated_mask_reference,
    sequence_continuity,
    spatial_continuity_counts,
)
from carlaocc.stages.metrics.temporal import (
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
