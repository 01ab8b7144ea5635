"""Dataset-quality metrics over occupancy grids."""

from stages.metrics.continuity import (
    ContinuityCounts,
    isolated_mask_reference,
    sequence_continuity,
    spatial_continuity_counts,
)

__all__ = [
    "ContinuityCounts",
    "isolated_mask_reference",
    "sequence_continuity",
    "spatial_continuity_counts",
]
