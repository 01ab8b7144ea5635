"""Procedural two-wheelers: bicycles and motorcycles (classes Bicycle, Motorcycle), parked or as
the ride of a rider (:mod:`.people`).

Asset frame: metres, +X forward, +Y left, Z up; wheels touch z = 0.
"""

from __future__ import annotations

import numpy as np

from carlaocc.schemas.meshes import MeshPart
from carlaocc.stages.ingest.procedural.primitives import (
    PAINTS, Builder, beam, box, cylinder, ellipsoid, extrude, frustum, glass_part, part, pick, uniform,
    union,
)


# two-wheeler kind -> wheel radius, tyre width, wheelbase, seat and handlebar heights, handlebar
# width (m); bicycles also their tube size, motorcycles their foot-peg (x, z)
_BIKES: dict[str, dict] = {
    "city_bike": dict(r=(0.33, 0.35), tw=0.04, wb=(1.02, 1.10), seat=(0.85, 0.95), bar=(0.98, 1.06),
                      bar_w=(0.50, 0.60), tube=0.035),
    "road_bike": dict(r=(0.34, 0.35), tw=0.025, wb=(0.97, 1.02), seat=(0.92, 1.00), bar=(0.88, 0.95),
                      bar_w=(0.40, 0.44), tube=0.03),
    "mountain_bike": dict(r=(0.35, 0.37), tw=0.06, wb=(1.10, 1.20), seat=(0.85, 0.95), bar=(0.98, 1.05),
                          bar_w=(0.70, 0.78), tube=0.045),
    "cargo_bike": dict(r=(0.33, 0.35), tw=0.045, wb=(1.90, 2.10), seat=(0.88, 0.95), bar=(1.00, 1.06),
                       bar_w=(0.55, 0.62), tube=0.04),
}  # fmt: skip
_MOTOS: dict[str, dict] = {
    "sport": dict(r=(0.29, 0.32), tw=0.13, wb=(1.35, 1.50), seat=(0.78, 0.85), bar=(1.00, 1.10),
                  bar_w=(0.70, 0.80), peg=(0.0, 0.30)),
    "cruiser": dict(r=(0.31, 0.34), tw=0.15, wb=(1.55, 1.75), seat=(0.66, 0.72), bar=(1.05, 1.15),
                    bar_w=(0.85, 0.95), peg=(0.30, 0.32)),
    "scooter": dict(r=(0.20, 0.24), tw=0.11, wb=(1.25, 1.35), seat=(0.76, 0.82), bar=(1.00, 1.06),
                    bar_w=(0.62, 0.70), peg=(0.10, 0.37)),
    "moped": dict(r=(0.27, 0.30), tw=0.08, wb=(1.15, 1.25), seat=(0.80, 0.86), bar=(1.00, 1.08),
                  bar_w=(0.60, 0.66), peg=(0.0, 0.30)),
}  # fmt: skip


def _bicycle_parts(rng: np.random.Generator, kind: str) -> tuple[list[MeshPart], dict[str, np.ndarray]]:
    """Bicycle parts (class Bicycle) of ``kind`` (:data:`_BIKES`) and the rider anchor points."""
    s = _BIKES[kind]
    r, tw, wb = uniform(rng, *s["r"]), s["tw"], uniform(rng, *s["wb"])
    seat_z, bar_z, bar_w, t = uniform(rng, *s["seat"]), uniform(rng, *s["bar"]), uniform(rng, *s["bar_w"]), s["tube"]
    frame_c = pick(rng, PAINTS)
    xf, xr = wb / 2, -wb / 2
    cargo = kind == "cargo_bike"
    rf = 0.25 if cargo else r  # a long-john cargo bike has a small front wheel
    seat = np.array([xr + 0.30, 0.0, seat_z])
    pedal = np.array([xr + 0.55, 0.0, 0.30]) if cargo else np.array([0.0, 0.0, 0.30])
    bar = np.array([xr + 0.85, 0.0, bar_z]) if cargo else np.array([xf - 0.12, 0.0, bar_z])

    def tube(name: str, p0, p1, size: float = t) -> MeshPart:
        return part(name, beam(p0, p1, size, size), "Bicycle", "metal", color=frame_c)

    parts = [
        part("wheel_front", cylinder(rf, (xf, -tw / 2, rf), (xf, tw / 2, rf), 20), "Bicycle", "rubber"),
        part("wheel_rear", cylinder(r, (xr, -tw / 2, r), (xr, tw / 2, r), 20), "Bicycle", "rubber"),
        tube("top_tube", seat + (0.05, 0, -0.08), bar + (-0.05, 0, -0.12)),
        tube("down_tube", pedal, bar + (-0.03, 0, -0.18)),
        tube("seat_tube", pedal + (0.0, 0, 0.02), seat + (0.0, 0, -0.04)),
        tube("chain_stay", pedal + (-0.02, 0, 0.0), (xr + 0.02, 0.0, r)),
        part("saddle", box(seat + (-0.12, -0.07, -0.02), seat + (0.12, 0.07, 0.04)), "Bicycle", "leather"),
        part("handlebar", box(bar + (-0.02, -bar_w / 2, -0.02), bar + (0.02, bar_w / 2, 0.02)), "Bicycle", "metal"),
    ]
    if cargo:
        parts += [
            tube("cargo_beam", pedal + (0.02, 0, 0.0), (xf - 0.12, 0.0, 0.30)),
            tube("fork", (xf - 0.12, 0.0, 0.33), (xf - 0.01, 0.0, rf + 0.02)),
            part("cargo_box", box((bar[0] + 0.12, -0.33, 0.36), (xf - 0.30, 0.33, 0.85)), "Bicycle", "wood"),
        ]
    else:
        fork_t = t * 1.6 if kind == "mountain_bike" else t
        parts.append(tube("fork", bar + (-0.02, 0, -0.10), (xf - 0.01, 0.0, r + 0.02), fork_t))
    if kind == "city_bike":
        parts.append(part("rack", box((xr - 0.15, -0.08, 2 * r + 0.05), (xr + 0.22, 0.08, 2 * r + 0.08)), "Bicycle",
                           "metal"))  # fmt: skip
        if rng.uniform() < 0.5:
            basket = box((bar[0] + 0.06, -0.18, bar_z - 0.33), (bar[0] + 0.40, 0.18, bar_z - 0.06))
            parts.append(part("basket", basket, "Bicycle", "wood"))
    elif kind == "road_bike":
        drops = union(*[beam(bar + (0.0, sy * (bar_w / 2 - 0.02), 0.0), bar + (0.09, sy * (bar_w / 2 - 0.02), -0.13),
                               0.025, 0.025) for sy in (-1.0, 1.0)])  # fmt: skip
        parts.append(part("drops", drops, "Bicycle", "metal"))
    return parts, {"seat": seat, "bar": bar, "pedal": pedal}


def _motorcycle_parts(rng: np.random.Generator, kind: str) -> tuple[list[MeshPart], dict[str, np.ndarray]]:
    """Motorcycle / scooter / moped parts (class Motorcycle) of ``kind`` (:data:`_MOTOS`) and the
    rider anchor points."""
    s = _MOTOS[kind]
    r, tw, wb = uniform(rng, *s["r"]), s["tw"], uniform(rng, *s["wb"])
    seat_z, bar_z, bar_w = uniform(rng, *s["seat"]), uniform(rng, *s["bar"]), uniform(rng, *s["bar_w"])
    paint = pick(rng, PAINTS)
    sem = "Motorcycle"
    xf, xr = wb / 2, -wb / 2
    seat = np.array([xr + (0.45 if kind == "cruiser" else 0.35 if kind == "scooter" else 0.30), 0.0, seat_z])
    bar = np.array([xf - 0.12, 0.0, bar_z])
    peg = np.array([s["peg"][0], 0.0, s["peg"][1]])
    parts = [
        part("wheel_front", cylinder(r, (xf, -tw / 2, r), (xf, tw / 2, r), 20), sem, "rubber"),
        part("wheel_rear", cylinder(r, (xr, -tw / 2, r), (xr, tw / 2, r), 20), sem, "rubber"),
        part("fork", beam(bar + (-0.03, 0, -0.06), (xf - 0.02, 0.0, r + 0.05), 0.07, 0.07), sem, "metal"),
        part("handlebar", box(bar + (-0.02, -bar_w / 2, -0.02), bar + (0.02, bar_w / 2, 0.02)), sem, "metal"),
    ]
    windscreen = kind == "sport" or rng.uniform() < 0.35
    if kind == "sport":
        parts += [
            part("engine", frustum((xr + 0.35, -0.20, 0.28), (xf - 0.35, 0.20, 0.62),
                                     (xr + 0.30, -0.17), (xf - 0.40, 0.17)), sem, "metal"),  # fmt: skip
            part("tank", box((0.0, -0.17, 0.62), (xf - 0.25, 0.17, bar_z - 0.18)), sem, "paint", color=paint),
            part("seat", box((xr + 0.05, -0.15, 0.62), (-0.02, 0.15, seat_z)), sem, "leather"),
        ]
    elif kind == "cruiser":
        xt = (0.05 + xf - 0.35) / 2
        parts += [
            part("engine", frustum((xr + 0.45, -0.22, 0.24), (xf - 0.45, 0.22, 0.62),
                                     (xr + 0.40, -0.18), (xf - 0.50, 0.18)), sem, "metal"),  # fmt: skip
            part("tank", ellipsoid((xt, 0.0, bar_z - 0.30), ((xf - 0.35 - 0.05) / 2, 0.16, 0.11)), sem, "paint",
                  color=paint),  # fmt: skip
            part("seat", box((xr + 0.20, -0.17, 0.55), (0.0, 0.17, seat_z)), sem, "leather"),
            part("exhaust", cylinder(0.05, (xr + 0.05, -0.26, 0.36), (0.35, -0.26, 0.30), 10), sem, "metal",
                  color=(200, 200, 205, 255)),  # fmt: skip
        ]
    elif kind == "scooter":
        parts += [
            part("floorboard", box((xr + 0.45, -0.15, 0.22), (xf - 0.36, 0.15, 0.32)), sem, "plastic"),
            part("legshield", extrude([(xf - 0.34, 0.22), (xf - 0.22, 0.22), (xf - 0.13, 0.95), (xf - 0.25, 0.95)],
                                        -0.21, 0.21), sem, "paint", color=paint),  # fmt: skip
            part("rear_body", ellipsoid((xr + 0.33, 0.0, 0.50), (0.42, 0.19, 0.22)), sem, "paint", color=paint),
            part("seat", box((xr + 0.08, -0.14, 0.66), (xr + 0.68, 0.14, seat_z)), sem, "leather"),
        ]
    else:  # moped: a light frame with a small engine and tank
        parts += [
            part("frame", beam((xr + 0.30, 0.0, 0.62), bar + (-0.05, 0, -0.15), 0.05, 0.05), sem, "metal",
                  color=paint),
            part("engine", box((-0.25, -0.12, 0.20), (0.15, 0.12, 0.45)), sem, "metal"),
            part("tank", box((xr + 0.05, -0.13, 0.50), (xr + 0.55, 0.13, 0.62)), sem, "paint", color=paint),
            part("seat", box((xr + 0.10, -0.13, 0.64), (xr + 0.60, 0.13, seat_z)), sem, "leather"),
        ]
    if windscreen:
        screen = beam(bar + (-0.02, 0, 0.02), bar + (0.10, 0, 0.30), 0.36, 0.01)
        parts.append(glass_part("windscreen", screen, sem))
    return parts, {"seat": seat, "bar": bar, "pedal": peg}


def two_wheeler(rng: np.random.Generator, kind: str) -> tuple[list[MeshPart], dict[str, np.ndarray]]:
    """Bicycle or motorcycle parts of ``kind`` and the rider anchor points (``seat``, ``bar``,
    ``pedal``: hip, hands and feet of a rider)."""
    return _bicycle_parts(rng, kind) if kind in _BIKES else _motorcycle_parts(rng, kind)


def parked(kind: str) -> Builder:
    """A parked bicycle or motorcycle of ``kind`` (no rider)."""

    def build(rng: np.random.Generator) -> list[MeshPart]:
        return two_wheeler(rng, kind)[0]

    return build
