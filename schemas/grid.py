"""The occupancy grid specification.

A :class:`GridSpec` is a region of the LiDAR frame (metres; x forward, y left, z up, origin at the
LiDAR, 1.73 m above the ground) cut into cubic voxels of edge ``voxel_size``. Voxel ``(i, j, k)``
covers ``[origin + (i, j, k) * voxel_size, origin + (i + 1, j + 1, k + 1) * voxel_size]``.

When an axis of the region is not a whole number of voxels (0.5 m on the default 76.8 m x range is
153.6 voxels) the grid **grows the region to whole voxels and keeps the origin**: the shape is
rounded up and :attr:`GridSpec.effective_max` (recorded in every array's attributes) is where the
grid really ends. Counts within 1e-6 voxel of an integer are taken as that integer, so 0.1 m on
76.8 m is 768 voxels, not 769.
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import BaseModel, ConfigDict, field_validator, model_validator

DEFAULT_REGION_MIN: tuple[float, float, float] = (-25.6, -25.6, -3.0)
DEFAULT_REGION_MAX: tuple[float, float, float] = (51.2, 25.6, 10.0)
_WHOLE_TOLERANCE = 1e-6
_AXES = "xyz"


def voxel_size_key(voxel_size: float) -> str:
    """Store key of a voxel size: ``0.05`` -> ``"0.05"``, ``0.2`` -> ``"0.2"`` (no float noise)."""
    return f"{voxel_size:.6f}".rstrip("0").rstrip(".")


class GridSpec(BaseModel):
    """A region of the LiDAR frame and a voxel size; derives the shape and the effective region."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    region_min: tuple[float, float, float] = DEFAULT_REGION_MIN
    region_max: tuple[float, float, float] = DEFAULT_REGION_MAX
    voxel_size: float
    frame: Literal["lidar"] = "lidar"

    @field_validator("voxel_size")
    @classmethod
    def _positive_finite(cls, v: float) -> float:
        if not math.isfinite(v) or v <= 0:
            raise ValueError(f"voxel size must be a positive finite number of metres, got {v!r}")
        return v

    @field_validator("region_min", "region_max")
    @classmethod
    def _finite_corner(cls, v: tuple[float, float, float]) -> tuple[float, float, float]:
        if not all(math.isfinite(c) for c in v):
            raise ValueError(f"region corner must be finite, got {v!r}")
        return v

    @model_validator(mode="after")
    def _at_least_one_voxel(self) -> GridSpec:
        for axis, lo, hi in zip(_AXES, self.region_min, self.region_max):
            extent = hi - lo
            if extent < self.voxel_size * (1 - _WHOLE_TOLERANCE):
                raise ValueError(
                    f"region {axis} extent {extent:g} m is smaller than one voxel ({self.voxel_size:g} m)"
                )
        return self

    @property
    def origin(self) -> tuple[float, float, float]:
        """Minimum corner of voxel (0, 0, 0), metres in the LiDAR frame."""
        return self.region_min

    @property
    def shape(self) -> tuple[int, int, int]:
        """Voxel counts (X, Y, Z); partial voxels round up (the region grows, the origin stays)."""
        out = []
        for lo, hi in zip(self.region_min, self.region_max):
            n = (hi - lo) / self.voxel_size
            whole = round(n)
            out.append(int(whole) if abs(n - whole) <= _WHOLE_TOLERANCE else int(math.ceil(n)))
        return (out[0], out[1], out[2])

    @property
    def effective_max(self) -> tuple[float, float, float]:
        """Maximum corner of the last voxel: ``origin + shape * voxel_size``."""
        return tuple(  # type: ignore[return-value]
            round(lo + n * self.voxel_size, 9) for lo, n in zip(self.region_min, self.shape)
        )

    @property
    def grown(self) -> bool:
        """True when the region was grown to whole voxels on some axis."""
        return any(abs(e - m) > 1e-9 for e, m in zip(self.effective_max, self.region_max))

    @property
    def key(self) -> str:
        """Store key of this voxel size, e.g. ``"0.05"``."""
        return voxel_size_key(self.voxel_size)

    def attrs(self) -> dict:
        """JSON-able description recorded on every array written on this grid."""
        return {
            "grid_spec": self.model_dump(mode="json"),
            "voxel_size": self.voxel_size,
            "origin": list(self.origin),
            "shape": list(self.shape),
            "region": [list(self.region_min), list(self.region_max)],
            "effective_region": [list(self.region_min), list(self.effective_max)],
            "frame": self.frame,
        }
