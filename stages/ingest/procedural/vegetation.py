"""Procedural vegetation (class Vegetation): street trees, conifers, bushes, palms and hedges.

Asset frame: metres, Z up, trunk (or the plant's centre) at the origin.
"""

from __future__ import annotations

import numpy as np

from carlaocc.schemas.meshes import MeshPart
from carlaocc.stages.ingest.procedural.primitives import (
    cone, cylinder, ellipsoid, extrude, part, pick, rotate, rot_y, rot_z, uniform,
)


def tree(rng: np.random.Generator) -> list[MeshPart]:
    """Street tree: trunk and an ellipsoid crown pruned high (crown base 3.8-4.5 m, so trucks and
    buses pass under branches that overhang the road)."""
    crown_base = uniform(rng, 3.8, 4.5)
    rx, rz = uniform(rng, 1.5, 2.8), uniform(rng, 1.4, 2.4)
    trunk_r = uniform(rng, 0.12, 0.22)
    trunk = cylinder(trunk_r, (0.0, 0.0, 0.0), (0.0, 0.0, crown_base + rz), 8)
    crown = ellipsoid((0.0, 0.0, crown_base + rz), (rx, rx * uniform(rng, 0.85, 1.0), rz), 1)
    green = pick(rng, ((60, 120, 40, 255), (75, 130, 50, 255), (50, 100, 45, 255), (95, 125, 45, 255)))
    return [part("trunk", trunk, "Vegetation", "bark"), part("crown", crown, "Vegetation", "foliage", color=green)]


def conifer(rng: np.random.Generator) -> list[MeshPart]:
    """Conifer: trunk and a cone crown starting 1-2 m above ground, 6-12 m tall."""
    base, height, radius = uniform(rng, 1.0, 2.0), uniform(rng, 5.0, 10.0), uniform(rng, 1.2, 2.2)
    trunk = cylinder(uniform(rng, 0.12, 0.20), (0.0, 0.0, 0.0), (0.0, 0.0, base + 0.5), 8)
    crown = cone(radius, height, (0.0, 0.0, base), 12)
    return [part("trunk", trunk, "Vegetation", "bark"),
            part("crown", crown, "Vegetation", "foliage", color=(35, 85, 45, 255))]  # fmt: skip


def bush(rng: np.random.Generator) -> list[MeshPart]:
    """Bush: a flattened ellipsoid on the ground, 0.8-1.6 m high."""
    h, rx = uniform(rng, 0.8, 1.6), uniform(rng, 0.6, 1.3)
    crown = ellipsoid((0.0, 0.0, h / 2), (rx, rx * uniform(rng, 0.7, 1.0), h / 2), 1)
    return [part("crown", crown, "Vegetation", "foliage")]


def palm(rng: np.random.Generator) -> list[MeshPart]:
    """Palm: a slim, slightly leaning 6-11 m trunk, a crown head and 6-8 drooping fronds (one
    part each: the fronds overlap at the head)."""
    h, lean = uniform(rng, 6.0, 11.0), uniform(rng, 0.0, 0.5)
    heading = uniform(rng, 0.0, 2 * np.pi)
    top = np.array([lean * np.cos(heading), lean * np.sin(heading), h])
    parts = [
        part("trunk", cylinder(uniform(rng, 0.15, 0.22), (0.0, 0.0, 0.0), top, 8), "Vegetation", "bark"),
        part("crown_head", ellipsoid(top, (0.35, 0.35, 0.45), 1), "Vegetation", "foliage"),
    ]
    n = int(rng.integers(6, 9))
    for k in range(n):
        length, droop = uniform(rng, 2.0, 3.0), uniform(rng, 0.2, 0.6)
        R = rot_z(2 * np.pi * k / n + uniform(rng, -0.2, 0.2)) @ rot_y(droop)
        frond = rotate(ellipsoid((length / 2, 0.0, 0.0), (length / 2, 0.35, 0.06), 1), R, top + (0.0, 0.0, 0.15))
        parts.append(part(f"frond_{k}", frond, "Vegetation", "foliage", color=(80, 130, 45, 255)))
    return parts


def hedge(rng: np.random.Generator) -> list[MeshPart]:
    """Clipped hedge, 2-6 m long, 0.6-1.0 m wide, 0.8-1.8 m high, with bevelled top edges."""
    L, w, h = uniform(rng, 2.0, 6.0), uniform(rng, 0.6, 1.0), uniform(rng, 0.8, 1.8)
    b = 0.15
    profile = [(-w / 2, 0.0), (w / 2, 0.0), (w / 2, h - b), (w / 2 - b, h), (-w / 2 + b, h), (-w / 2, h - b)]
    return [part("hedge", extrude(profile, -L / 2, L / 2, "x"), "Vegetation", "foliage", color=(45, 95, 40, 255))]
