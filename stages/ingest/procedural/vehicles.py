"""Procedural road vehicles: cars, trucks, buses and trains (classes Car, Truck, Bus, Train).

Asset frame: metres, +X forward (the driving direction), +Y left, Z up; wheels touch z = 0.
Windows and windscreens are transparent glass parts of the vehicle's class.
"""

from __future__ import annotations

import numpy as np

from carlaocc.schemas.meshes import MeshPart
from carlaocc.stages.ingest.procedural.primitives import (
    BLACK, BLUE, DARK, GREEN, ORANGE, PAINTS, RED, RGBA, WHITE, YELLOW, Builder, beam, box,
    chamfer_front_top, cone_between, cylinder, extrude, frustum, glass_part, part, pick, uniform, union,
)


def _wheels(
    xs, half_track: float, radius: float, width: float, semantic: str, sections: int = 16
) -> list[MeshPart]:
    """One wheel part per axle position in ``xs`` and side (axis along Y, touching z = 0)."""
    out = []
    for k, x in enumerate(xs):
        for side, sy in (("left", 1.0), ("right", -1.0)):
            y = sy * half_track
            mesh = cylinder(radius, (x, y - width / 2, radius), (x, y + width / 2, radius), sections)
            out.append(part(f"wheel_{k}_{side}", mesh, semantic, "rubber"))
    return out


def _greenhouse_vehicle(
    L: float, W: float, H: float, *, semantic: str, clearance: float, belt: float,
    gh_rear: float, gh_front: float, top_rear: float, top_front: float, top_side: float,
    hood: tuple[float, float], wheel_r: float, wheel_w: float, axles: list[float],
    paint: RGBA | None = None,
) -> list[MeshPart]:  # fmt: skip
    """Body box (with a hood chamfer) up to the belt line, a tapered glass greenhouse above it, a
    thin roof, and wheels. ``gh_rear``/``gh_front`` are greenhouse x limits (m); ``top_*`` are the
    insets of its top face (windshield rake, side tumblehome)."""
    roof_t = 0.06
    body = chamfer_front_top(box((-L / 2, -W / 2, clearance), (L / 2, W / 2, belt)), *hood)
    gy = W / 2 - 0.04
    glass_top = H - roof_t
    glass = frustum(
        (gh_rear, -gy, belt), (gh_front, gy, glass_top),
        (gh_rear + top_rear, -gy + top_side), (gh_front - top_front, gy - top_side),
    )  # fmt: skip
    roof = box((gh_rear + top_rear, -gy + top_side, glass_top), (gh_front - top_front, gy - top_side, H))
    parts = [
        part("body", body, semantic, "paint", color=paint),
        glass_part("windows", glass, semantic),
        part("roof", roof, semantic, "paint", color=paint),
    ]
    return parts + _wheels(axles, W / 2 - wheel_w / 2 - 0.03, wheel_r, wheel_w, semantic)


# sub-class -> ranges of length, width, height (m) and shape fractions; ``extra`` adds roof
# equipment, ``paints`` restricts the body colours
_SEDAN = dict(L=(4.3, 4.9), W=(1.75, 1.9), H=(1.40, 1.50), r=(0.31, 0.34), clear=0.17, belt=0.52,
              gh=(-0.30, 0.17), top=(0.38, 0.55), hood=(0.25, 0.10))  # fmt: skip
_CAR_SPECS: dict[str, dict] = {
    "sedan": _SEDAN,
    "hatchback": dict(L=(3.8, 4.3), W=(1.68, 1.80), H=(1.42, 1.55), r=(0.30, 0.33), clear=0.16,
                      belt=0.50, gh=(-0.47, 0.16), top=(0.12, 0.55), hood=(0.22, 0.10)),
    "suv": dict(L=(4.5, 5.0), W=(1.85, 2.0), H=(1.65, 1.85), r=(0.36, 0.40), clear=0.24,
                belt=0.55, gh=(-0.46, 0.19), top=(0.10, 0.50), hood=(0.20, 0.08)),
    "van": dict(L=(4.8, 5.4), W=(1.90, 2.05), H=(1.95, 2.30), r=(0.33, 0.36), clear=0.20,
                belt=0.45, gh=(-0.48, 0.33), top=(0.03, 0.38), hood=(0.30, 0.15)),
    "coupe": dict(L=(4.2, 4.7), W=(1.78, 1.90), H=(1.28, 1.38), r=(0.31, 0.34), clear=0.14,
                  belt=0.55, gh=(-0.27, 0.12), top=(0.60, 0.52), hood=(0.28, 0.10)),
    "wagon": dict(L=(4.6, 5.0), W=(1.78, 1.90), H=(1.45, 1.55), r=(0.31, 0.34), clear=0.16,
                  belt=0.52, gh=(-0.47, 0.17), top=(0.08, 0.55), hood=(0.25, 0.10)),
    "minivan": dict(L=(4.8, 5.2), W=(1.90, 2.00), H=(1.70, 1.80), r=(0.33, 0.35), clear=0.17,
                    belt=0.45, gh=(-0.47, 0.30), top=(0.06, 0.65), hood=(0.30, 0.14)),
    "taxi": dict(_SEDAN, extra="taxi_sign", paints=(YELLOW, BLACK)),
    "police": dict(_SEDAN, H=(1.42, 1.52), extra="light_bar", paints=(WHITE, BLACK, (20, 35, 80, 255))),
}  # fmt: skip


def car(subclass: str) -> Builder:
    """Builder of a Car sub-class from :data:`_CAR_SPECS`: a greenhouse vehicle, plus a roof
    sign (taxi) or light bar (police)."""
    spec = _CAR_SPECS[subclass]

    def build(rng: np.random.Generator) -> list[MeshPart]:
        L, W, H = uniform(rng, *spec["L"]), uniform(rng, *spec["W"]), uniform(rng, *spec["H"])
        r = uniform(rng, *spec["r"])
        paint = pick(rng, spec.get("paints", PAINTS))
        belt = spec["clear"] + (H - spec["clear"]) * spec["belt"]
        # axles: overhangs of about 19 % (front) and 21 % (rear) of the length
        axles = [L / 2 - 0.19 * L, -L / 2 + 0.21 * L]
        gh_rear, gh_front = spec["gh"][0] * L, spec["gh"][1] * L
        parts = _greenhouse_vehicle(
            L, W, H, semantic="Car", clearance=spec["clear"], belt=belt, gh_rear=gh_rear,
            gh_front=gh_front, top_rear=spec["top"][0], top_front=spec["top"][1], top_side=0.10,
            hood=spec["hood"], wheel_r=r, wheel_w=0.22, axles=axles, paint=paint,
        )  # fmt: skip
        # roof equipment centred on the roof panel
        xc = (gh_rear + spec["top"][0] + gh_front - spec["top"][1]) / 2
        if spec.get("extra") == "taxi_sign":
            sign = frustum((xc - 0.15, -0.40, H), (xc + 0.15, 0.40, H + 0.22), (xc - 0.12, -0.38), (xc + 0.12, 0.38))
            parts.append(part("taxi_sign", sign, "Car", "plastic", color=(250, 220, 60, 255)))
        elif spec.get("extra") == "light_bar":
            bar = box((xc - 0.14, -0.55, H), (xc + 0.14, 0.55, H + 0.11))
            parts.append(part("light_bar", bar, "Car", "lens", color=pick(rng, (BLUE, RED))))
        return parts

    return build


def convertible(rng: np.random.Generator) -> list[MeshPart]:
    """Open two-seater (4.0-4.6 m): a low body, a raked windscreen, two seats sticking out of the
    cockpit, an optional folded hood behind them."""
    L, W, H_body = uniform(rng, 4.0, 4.6), uniform(rng, 1.75, 1.88), uniform(rng, 0.92, 1.0)
    r, clear = uniform(rng, 0.31, 0.34), 0.14
    paint = pick(rng, PAINTS)
    body = chamfer_front_top(box((-L / 2, -W / 2, clear), (L / 2, W / 2, H_body)), 0.30, 0.12)
    # windscreen: a thin slab leaning back 0.35 m over its 0.42 m height
    xw, gy = 0.16 * L, W / 2 - 0.08
    screen = extrude([(xw, H_body), (xw + 0.05, H_body), (xw - 0.30, H_body + 0.42), (xw - 0.35, H_body + 0.42)],
                      -gy, gy)  # fmt: skip
    seat_x = -0.12 * L
    seats = union(*[
        box((seat_x - 0.12, sy * 0.42 - 0.24, H_body - 0.3), (seat_x + 0.0, sy * 0.42 + 0.24, H_body + 0.32))
        for sy in (-1.0, 1.0)
    ])  # fmt: skip
    parts = [
        part("body", body, "Car", "paint", color=paint),
        glass_part("windscreen", screen, "Car"),
        part("seats", seats, "Car", "leather"),
    ]
    if rng.uniform() < 0.5:
        hood = box((seat_x - 0.75, -W / 2 + 0.12, H_body), (seat_x - 0.25, W / 2 - 0.12, H_body + 0.18))
        parts.append(part("folded_hood", hood, "Car", "cloth", color=DARK))
    return parts + _wheels([L / 2 - 0.19 * L, -L / 2 + 0.21 * L], W / 2 - 0.14, r, 0.22, "Car")


def pickup(rng: np.random.Generator) -> list[MeshPart]:
    """Pickup truck (5.0-5.5 m): a cab greenhouse over the front, an open bed behind it (floor,
    side walls, tailgate)."""
    L, W, H = uniform(rng, 5.0, 5.5), uniform(rng, 1.90, 2.03), uniform(rng, 1.78, 1.92)
    r, clear = uniform(rng, 0.38, 0.41), 0.25
    paint = pick(rng, PAINTS)
    belt = uniform(rng, 1.05, 1.12)
    bed = uniform(rng, 0.33, 0.38) * L
    x_bed = -L / 2 + bed  # front wall of the bed
    front = chamfer_front_top(box((x_bed, -W / 2, clear), (L / 2, W / 2, belt)), 0.15, 0.06)
    floor_top = belt - 0.45
    bed_floor = box((-L / 2, -W / 2, clear + 0.1), (x_bed - 0.01, W / 2, floor_top))
    walls = union(
        box((-L / 2 + 0.07, W / 2 - 0.06, floor_top + 0.01), (x_bed - 0.01, W / 2, belt)),
        box((-L / 2 + 0.07, -W / 2, floor_top + 0.01), (x_bed - 0.01, -W / 2 + 0.06, belt)),
        box((-L / 2, -W / 2, floor_top + 0.01), (-L / 2 + 0.06, W / 2, belt - 0.02)),
    )
    gy = W / 2 - 0.05
    gh_rear, gh_front = x_bed + 0.02, 0.17 * L
    glass = frustum(
        (gh_rear, -gy, belt), (gh_front, gy, H - 0.06), (gh_rear + 0.06, -gy + 0.1), (gh_front - 0.5, gy - 0.1)
    )
    roof = box((gh_rear + 0.06, -gy + 0.1, H - 0.06), (gh_front - 0.5, gy - 0.1, H))
    parts = [
        part("body", union(front, bed_floor), "Car", "paint", color=paint),
        part("bed_walls", walls, "Car", "paint", color=paint),
        glass_part("windows", glass, "Car"),
        part("roof", roof, "Car", "paint", color=paint),
    ]
    return parts + _wheels([L / 2 - 0.18 * L, -L / 2 + 0.22 * L], W / 2 - 0.16, r, 0.26, "Car")


def _truck_cab(
    xf: float, W: float, cab_len: float, cab_h: float, paint: RGBA, *, floor: float = 0.70,
    belt: float = 1.65, glass_top: float | None = None,
) -> tuple[list[MeshPart], float]:  # fmt: skip
    """A truck cab whose front is at ``xf``: lower cab (hood chamfer), a raked glass greenhouse, a
    thin roof (or, with ``glass_top`` below the cab height, a tapered roof fairing of a sleeper cab)
    and the cab's back wall. Returns the parts and the cab's rear x."""
    cab_x0 = xf - cab_len
    gy = W / 2 - 0.05
    top = cab_h - 0.08 if glass_top is None else glass_top
    cab = chamfer_front_top(box((cab_x0, -W / 2, floor), (xf, W / 2, belt)), 0.08, 0.05)
    glass = frustum(
        (cab_x0 + 0.3, -gy, belt), (xf - 0.05, gy, top), (cab_x0 + 0.3, -gy + 0.05), (xf - 0.30, gy - 0.05)
    )
    if glass_top is None:
        roof = box((cab_x0 + 0.3, -gy + 0.05, top), (xf - 0.30, gy - 0.05, cab_h))
    else:
        roof = frustum((cab_x0, -gy, top), (xf - 0.30, gy, cab_h), (cab_x0, -gy + 0.12), (xf - 0.9, gy - 0.12))
    back = box((cab_x0, -gy, belt), (cab_x0 + 0.3, gy, top))
    return [
        part("cab", cab, "Truck", "paint", color=paint),
        glass_part("cab_windows", glass, "Truck"),
        part("cab_roof", roof, "Truck", "paint", color=paint),
        part("cab_back", back, "Truck", "paint", color=paint),
    ], cab_x0


def _chassis(x0: float, x1: float, z0: float = 0.55, z1: float = 1.0, half: float = 0.55) -> MeshPart:
    """Truck chassis beam from ``x0`` to ``x1``."""
    return part("chassis", box((x0, -half, z0), (x1, half, z1)), "Truck", "metal", color=DARK)


_BODY_COLOURS = (WHITE, (200, 200, 195, 255), (150, 155, 160, 255), (30, 75, 165, 255), (200, 85, 25, 255))


def truck(subclass: str) -> Builder:
    """Trucks: a cab with its own windows at the front, a body behind it (cargo box, tank, fire
    equipment body with a ladder, semi-trailer, refuse compactor, flatbed, mixer drum, tipper),
    a chassis beam and 4-12 wheels."""

    def build(rng: np.random.Generator) -> list[MeshPart]:
        paint = pick(rng, PAINTS)
        r, wheel_w = 0.50, 0.32
        if subclass in ("box_truck", "tanker"):
            L = uniform(rng, 6.5, 9.0) if subclass == "box_truck" else uniform(rng, 8.0, 10.0)
            W, H = uniform(rng, 2.30, 2.50), uniform(rng, 3.0, 3.6)
            xf = L / 2
            parts, cab_x0 = _truck_cab(xf, W, uniform(rng, 2.0, 2.3), uniform(rng, 2.6, 2.9), paint)
            parts.append(_chassis(-L / 2 + 0.3, cab_x0 - 0.15))
            cargo_x0, cargo_x1 = -L / 2, cab_x0 - 0.15
            if subclass == "box_truck":
                cargo = box((cargo_x0, -W / 2, 1.0), (cargo_x1, W / 2, H))
                parts.append(part("cargo_box", cargo, "Truck", "paint", color=pick(rng, _BODY_COLOURS)))
            else:
                tr = min((H - 1.0) / 2, W / 2 - 0.02)
                tank = cylinder(tr, (cargo_x0, 0.0, 1.0 + tr), (cargo_x1, 0.0, 1.0 + tr), 20)
                parts.append(part("tank", tank, "Truck", "metal", color=(190, 192, 195, 255)))
            axles = [xf - 1.2, -L / 2 + 1.6 + 1.35, -L / 2 + 1.6]
        elif subclass == "fire_truck":
            L, W = uniform(rng, 8.5, 10.5), uniform(rng, 2.45, 2.55)
            xf, cab_h, body_h = L / 2, uniform(rng, 2.9, 3.1), uniform(rng, 2.8, 3.1)
            parts, cab_x0 = _truck_cab(xf, W, uniform(rng, 2.7, 3.1), cab_h, RED)
            parts += [
                _chassis(-L / 2 + 0.3, cab_x0 - 0.1),
                part("equipment_body", box((-L / 2, -W / 2, 0.9), (cab_x0 - 0.1, W / 2, body_h)), "Truck", "paint",
                      color=RED),
            ]  # fmt: skip
            # a ladder lying on top, reaching over the cab; rungs between (not touching) the rails
            zl, x0, x1 = max(body_h, cab_h) + 0.25, -L / 2 + 0.2, xf - 0.6
            rails = union(box((x0, 0.30, zl), (x1, 0.36, zl + 0.15)), box((x0, -0.36, zl), (x1, -0.30, zl + 0.15)))
            n = int((x1 - x0) // 0.9)
            rung_x = [x0 + 0.45 + 0.9 * k for k in range(n)]
            rungs = union(*[box((x - 0.03, -0.29, zl + 0.05), (x + 0.03, 0.29, zl + 0.09)) for x in rung_x])
            turntable = cylinder(0.6, (-L / 2 + 1.3, 0.0, body_h), (-L / 2 + 1.3, 0.0, zl - 0.01), 16)
            light = box((xf - 1.3, -0.6, cab_h), (xf - 1.0, 0.6, cab_h + 0.12))
            parts += [
                part("ladder_rails", rails, "Truck", "metal"),
                part("ladder_rungs", rungs, "Truck", "metal"),
                part("turntable", turntable, "Truck", "metal"),
                part("light_bar", light, "Truck", "lens", color=RED),
            ]
            axles = [xf - 1.5, -L / 2 + 2.2]
        elif subclass == "semi_truck":
            L, W = uniform(rng, 15.0, 16.5), uniform(rng, 2.45, 2.55)
            xf = L / 2
            parts, cab_x0 = _truck_cab(xf, W, uniform(rng, 2.3, 2.6), uniform(rng, 3.6, 3.9), paint, belt=1.75, glass_top=2.75)
            trailer_x1 = cab_x0 - 0.7
            xg = trailer_x1 - 4.5  # landing gear, clear of the tractor's rear wheels
            tanks = union(*[cylinder(0.30, (cab_x0 - 1.6, sy * 0.9, 0.75), (cab_x0 - 0.4, sy * 0.9, 0.75), 12)
                             for sy in (-1.0, 1.0)])  # fmt: skip
            parts += [
                _chassis(xf - 6.4, cab_x0 - 0.05, 0.6, 1.05, 0.5),
                part("fifth_wheel", box((xf - 5.8, -0.5, 1.06), (xf - 4.6, 0.5, 1.15)), "Truck", "metal"),
                part("fuel_tanks", tanks, "Truck", "metal", color=(200, 200, 205, 255)),
                part("trailer", box((-L / 2, -W / 2, 1.25), (trailer_x1, W / 2, uniform(rng, 3.9, 4.05))), "Truck",
                      "paint", color=pick(rng, _BODY_COLOURS)),
                part("landing_gear", union(*[box((xg, sy * 0.9 - 0.06, 0.3), (xg + 0.12, sy * 0.9 + 0.06, 1.24))
                                                for sy in (-1.0, 1.0)]), "Truck", "metal"),
            ]  # fmt: skip
            axles = [xf - 1.3, xf - 4.9, xf - 6.2, -L / 2 + 1.3, -L / 2 + 2.6, -L / 2 + 3.9]
        elif subclass == "garbage_truck":
            L, W, H = uniform(rng, 8.0, 10.0), uniform(rng, 2.45, 2.55), uniform(rng, 3.4, 3.7)
            xf = L / 2
            colour = pick(rng, (WHITE, (60, 130, 60, 255), ORANGE, (150, 155, 160, 255)))
            parts, cab_x0 = _truck_cab(xf, W, uniform(rng, 2.2, 2.5), uniform(rng, 2.7, 2.9), colour)
            xh = -L / 2 + 1.4  # the rear hopper, tapered, behind the compactor body
            hopper = extrude([(xh - 0.01, 0.9), (xh - 0.01, H - 0.05), (-L / 2 + 0.5, H - 0.35), (-L / 2, 1.9),
                               (-L / 2 + 0.3, 0.9)], -W / 2 + 0.05, W / 2 - 0.05)  # fmt: skip
            parts += [
                _chassis(-L / 2 + 0.5, cab_x0 - 0.15),
                part("compactor_body", box((xh, -W / 2, 1.0), (cab_x0 - 0.15, W / 2, H)), "Truck", "paint",
                      color=colour),
                part("hopper", hopper, "Truck", "paint", color=colour),
            ]  # fmt: skip
            axles = [xf - 1.3, -L / 2 + 2.4, -L / 2 + 3.7]
        elif subclass == "tow_truck":
            L, W = uniform(rng, 6.5, 8.0), uniform(rng, 2.30, 2.45)
            xf, cab_h = L / 2, uniform(rng, 2.6, 2.8)
            parts, cab_x0 = _truck_cab(xf, W, uniform(rng, 2.1, 2.3), cab_h, paint)
            xd = cab_x0 - 0.3
            parts += [
                _chassis(-L / 2 + 0.4, cab_x0 - 0.1),
                part("deck", box((-L / 2, -W / 2, 1.01), (xd, W / 2, 1.16)), "Truck", "metal"),
                part("headboard", box((xd + 0.01, -W / 2 + 0.1, 1.01), (xd + 0.14, W / 2 - 0.1, 2.3)), "Truck",
                      "metal"),
                part("light_bar", box((xf - 1.2, -0.6, cab_h), (xf - 0.9, 0.6, cab_h + 0.12)), "Truck", "lens",
                      color=ORANGE),
            ]  # fmt: skip
            axles = [xf - 1.2, -L / 2 + 1.8]
        elif subclass == "cement_mixer":
            L, W = uniform(rng, 8.0, 9.5), uniform(rng, 2.45, 2.50)
            xf = L / 2
            parts, cab_x0 = _truck_cab(xf, W, uniform(rng, 2.2, 2.4), uniform(rng, 2.7, 2.9), paint)
            R = uniform(rng, 1.05, 1.15)
            pf, pr = np.array([cab_x0 - 1.0, 0.0, 2.05]), np.array([-L / 2 + 1.3, 0.0, 2.55])
            d = (pr - pf) / np.linalg.norm(pr - pf)
            colour = pick(rng, (WHITE, ORANGE, BLUE, (200, 200, 195, 255)))
            parts += [
                _chassis(-L / 2 + 0.3, cab_x0 - 0.15),
                part("drum", cylinder(R, pf, pr, 16), "Truck", "paint", color=colour),
                part("drum_front", cone_between(R, pf, pf - 0.8 * d, 16), "Truck", "paint", color=colour),
                part("drum_rear", cone_between(R, pr, pr + 1.0 * d, 16), "Truck", "paint", color=colour),
            ]
            axles = [xf - 1.3, -L / 2 + 1.6, -L / 2 + 2.95]
        elif subclass == "dump_truck":
            L, W = uniform(rng, 7.0, 8.8), uniform(rng, 2.45, 2.55)
            xf, cab_h, Ht = L / 2, uniform(rng, 2.8, 3.0), uniform(rng, 2.5, 2.9)
            parts, cab_x0 = _truck_cab(xf, W, uniform(rng, 2.1, 2.4), cab_h, paint)
            profile = [(-W / 2 + 0.15, 1.1), (W / 2 - 0.15, 1.1), (W / 2, Ht), (-W / 2, Ht)]  # flared sides
            tipper = extrude(profile, -L / 2, cab_x0 - 0.2, "x")
            zg = max(Ht, cab_h) + 0.02
            guard = box((cab_x0 - 0.19, -W / 2 + 0.1, zg), (cab_x0 + 0.9, W / 2 - 0.1, zg + 0.1))
            colour = pick(rng, (YELLOW, ORANGE, (150, 155, 160, 255), RED))
            parts += [
                _chassis(-L / 2 + 0.3, cab_x0 - 0.15),
                part("tipper", tipper, "Truck", "metal", color=colour),
                part("cab_guard", guard, "Truck", "metal", color=colour),
            ]
            axles = [xf - 1.3, -L / 2 + 1.6, -L / 2 + 2.95]
        else:  # pragma: no cover - the catalogue only names the sub-classes above
            raise ValueError(subclass)
        return parts + _wheels(axles, W / 2 - 0.18, r, wheel_w, "Truck")

    return build


# sub-class -> length, width, height ranges, wheel radius, clearance, belt height, front and rear
# axle distances from the ends (a second rear distance: tandem axle)
_BUS_SPECS: dict[str, dict] = {
    "city_bus": dict(L=(10.5, 12.5), W=(2.50, 2.55), H=(3.0, 3.2), r=0.50, clear=0.30, belt=1.15,
                     front=2.7, rear=(3.0,), top_front=0.15),
    "minibus": dict(L=(6.5, 7.8), W=(2.10, 2.30), H=(2.6, 2.9), r=0.40, clear=0.30, belt=1.0,
                    front=1.4, rear=(1.5,), top_front=0.15),
    "coach": dict(L=(12.0, 13.8), W=(2.50, 2.55), H=(3.5, 3.8), r=0.52, clear=0.35, belt=1.80,
                  front=2.6, rear=(3.2, 4.6), top_front=0.25),
}  # fmt: skip


def bus(subclass: str) -> Builder:
    """City bus (10.5-12.5 m), minibus (6.5-7.8 m) or coach (12-13.8 m, high window band, tandem
    rear axle): a full-length window band over the body."""
    spec = _BUS_SPECS[subclass]

    def build(rng: np.random.Generator) -> list[MeshPart]:
        L, W, H = uniform(rng, *spec["L"]), uniform(rng, *spec["W"]), uniform(rng, *spec["H"])
        paint = pick(rng, PAINTS)
        axles = [L / 2 - spec["front"]] + [-L / 2 + d for d in spec["rear"]]
        return _greenhouse_vehicle(
            L, W, H, semantic="Bus", clearance=spec["clear"], belt=spec["belt"],
            gh_rear=-L / 2 + 0.05, gh_front=L / 2 - 0.05, top_rear=0.05, top_front=spec["top_front"],
            top_side=0.03, hood=(0.05, 0.02), wheel_r=spec["r"], wheel_w=0.30, axles=axles, paint=paint,
        )  # fmt: skip

    return build


def school_bus(rng: np.random.Generator) -> list[MeshPart]:
    """Conventional (bonneted) school bus, 9.5-12 m, yellow: an engine bonnet in front of the
    passenger box, a window band and roof."""
    L, W, H = uniform(rng, 9.5, 12.0), uniform(rng, 2.40, 2.50), uniform(rng, 3.0, 3.2)
    bonnet_len = uniform(rng, 1.4, 1.7)
    xb = L / 2 - bonnet_len  # the front of the passenger box
    gy, belt, glass_top = W / 2 - 0.04, 1.55, H - 0.3
    bonnet = chamfer_front_top(box((xb + 0.01, -W / 2 + 0.25, 0.45), (L / 2, W / 2 - 0.25, 1.55)), 0.25, 0.12)
    body = box((-L / 2, -W / 2, 0.35), (xb, W / 2, belt))
    glass = frustum((-L / 2 + 0.05, -gy, belt), (xb - 0.02, gy, glass_top), (-L / 2 + 0.05, -gy + 0.03),
                     (xb - 0.25, gy - 0.03))  # fmt: skip
    roof = box((-L / 2, -W / 2, glass_top), (xb - 0.2, W / 2, H))
    return [
        part("bonnet", bonnet, "Bus", "paint", color=YELLOW),
        part("body", body, "Bus", "paint", color=YELLOW),
        glass_part("windows", glass, "Bus"),
        part("roof", roof, "Bus", "paint", color=YELLOW),
    ] + _wheels([L / 2 - bonnet_len + 0.3, -L / 2 + 3.0], W / 2 - 0.18, 0.48, 0.30, "Bus")


def double_decker(rng: np.random.Generator) -> list[MeshPart]:
    """Double-decker bus, 10-11.5 m long and 4.2-4.4 m tall: two window bands separated by a
    body band."""
    L, W, H = uniform(rng, 10.0, 11.5), uniform(rng, 2.50, 2.55), uniform(rng, 4.2, 4.4)
    paint = pick(rng, (RED, RED, PAINTS[0], BLUE, GREEN))
    gy = W / 2 - 0.03
    lower = box((-L / 2, -W / 2, 0.30), (L / 2, W / 2, 1.0))
    mid = box((-L / 2, -W / 2, 2.05), (L / 2, W / 2, 2.45))
    roof = box((-L / 2 + 0.05, -W / 2 + 0.03, H - 0.22), (L / 2 - 0.05, W / 2 - 0.03, H))
    glass = union(
        box((-L / 2 + 0.05, -gy, 1.01), (L / 2 - 0.05, gy, 2.04)),
        box((-L / 2 + 0.05, -gy, 2.46), (L / 2 - 0.05, gy, H - 0.23)),
    )
    return [
        part("body", union(lower, mid), "Bus", "paint", color=paint),
        glass_part("windows", glass, "Bus"),
        part("roof", roof, "Bus", "paint", color=paint),
    ] + _wheels([L / 2 - 2.4, -L / 2 + 2.8], W / 2 - 0.18, 0.50, 0.30, "Bus")


def _rail_wheels(centres, spacing: float, per_bogie: int, radius: float) -> list[MeshPart]:
    """Rail wheels (standard gauge) of ``per_bogie`` axles ``spacing`` apart on each bogie."""
    xs = [c + (k - (per_bogie - 1) / 2) * spacing for c in centres for k in range(per_bogie)]
    return _wheels(xs, 0.72, radius, 0.14, "Train", 12)


def _doors(xs, half_w: float, y: float, z0: float, z1: float, colour: RGBA) -> MeshPart:
    """Door leaves on both sides of a rail car: thin boxes straddling the side walls at ``y``."""
    leaves = [box((x - half_w, sy * y - 0.03, z0), (x + half_w, sy * y + 0.03, z1)) for x in xs for sy in (-1.0, 1.0)]
    return part("doors", union(*leaves), "Train", "metal", color=colour)


def tram(rng: np.random.Generator) -> list[MeshPart]:
    """Low-floor articulated tram, 20-32 m: a window band with raked windscreens at both ends,
    side doors, skirted bogies and a roof pantograph."""
    L, W, H = uniform(rng, 20.0, 32.0), uniform(rng, 2.30, 2.65), uniform(rng, 3.3, 3.5)
    paint = pick(rng, (WHITE, RED, YELLOW, (30, 120, 160, 255), GREEN))
    floor, belt, glass_top = 0.35, 1.0, uniform(rng, 2.45, 2.6)
    gy = W / 2 - 0.04
    body = box((-L / 2, -W / 2, floor), (L / 2, W / 2, belt))
    glass = frustum((-L / 2 + 0.05, -gy, belt), (L / 2 - 0.05, gy, glass_top), (-L / 2 + 0.5, -gy + 0.03),
                     (L / 2 - 0.5, gy - 0.03))  # fmt: skip
    roof = box((-L / 2 + 0.5, -gy + 0.03, glass_top), (L / 2 - 0.5, gy - 0.03, H))
    n_bogie = 2 + int(L > 26.0)
    centres = [(-L / 2 + 2.6) + k * (L - 5.2) / (n_bogie - 1) for k in range(n_bogie)]
    bogies = union(*[box((c - 1.2, -W / 2 + 0.12, 0.0), (c + 1.2, W / 2 - 0.12, floor - 0.01)) for c in centres])
    n_doors = int(L // 6.5)
    doors = [(-L / 2 + 2.0) + (k + 0.5) * (L - 4.0) / n_doors for k in range(n_doors)]
    xp = float(centres[0] + centres[-1]) / 2 + 2.0
    return [
        part("body", body, "Train", "paint", color=paint),
        glass_part("windows", glass, "Train"),
        part("roof", roof, "Train", "paint", color=paint),
        part("bogies", bogies, "Train", "metal", color=DARK),
        _doors(doors, 0.65, W / 2, floor + 0.05, glass_top - 0.1, DARK),
        part("pantograph_base", box((xp - 0.6, -0.4, H), (xp + 0.6, 0.4, H + 0.12)), "Train", "metal"),
        part("pantograph_arm", beam((xp - 0.5, 0.0, H + 0.1), (xp + 0.2, 0.0, H + 0.57), 0.06, 0.06), "Train",
              "metal"),
        part("pantograph_bow", box((xp + 0.15, -0.75, H + 0.55), (xp + 0.25, 0.75, H + 0.6)), "Train", "metal"),
    ]


def metro(rng: np.random.Generator) -> list[MeshPart]:
    """Metro / subway car, 18-20.5 m: flat ends with windscreens, a window band, three doors a
    side, two bogies of two axles."""
    L, W, H = uniform(rng, 18.0, 20.5), uniform(rng, 2.80, 3.05), uniform(rng, 3.5, 3.8)
    paint = pick(rng, (PAINTS[2], WHITE, BLUE, (200, 200, 195, 255)))
    gy = W / 2 - 0.04
    body = box((-L / 2, -W / 2, 0.95), (L / 2, W / 2, 1.9))
    glass = frustum(
        (-L / 2 + 0.03, -gy, 1.9), (L / 2 - 0.03, gy, 2.9), (-L / 2 + 0.15, -gy + 0.02), (L / 2 - 0.15, gy - 0.02)
    )
    roof = box((-L / 2 + 0.15, -gy + 0.02, 2.9), (L / 2 - 0.15, gy - 0.02, H))
    centres = [-L / 2 + 2.6, L / 2 - 2.6]
    bogies = union(*[box((c - 1.3, -W / 2 + 0.35, 0.35), (c + 1.3, W / 2 - 0.35, 0.94)) for c in centres])
    return [
        part("body", body, "Train", "paint", color=paint),
        glass_part("windows", glass, "Train"),
        part("roof", roof, "Train", "paint", color=paint),
        part("bogies", bogies, "Train", "metal", color=DARK),
        _doors([-L / 4, 0.0, L / 4], 0.7, W / 2, 1.0, 2.8, pick(rng, (RED, YELLOW, DARK))),
    ] + _rail_wheels(centres, 1.8, 2, 0.43)


def locomotive(rng: np.random.Generator) -> list[MeshPart]:
    """Diesel locomotive (taxonomy sub-class ``train``), 16.5-21 m: a frame, a narrow hood, a
    full-width cab with windows near the front, a short nose, two three-axle bogies, a fuel tank."""
    L, W, H = uniform(rng, 16.5, 21.0), uniform(rng, 2.90, 3.10), uniform(rng, 4.0, 4.3)
    paint = pick(rng, (RED, BLUE, YELLOW, GREEN, ORANGE, DARK))
    gy = W / 2 - 0.05
    xc0, xc1 = L / 2 - 3.4, L / 2 - 0.6  # the cab
    frame = box((-L / 2, -W / 2, 1.05), (L / 2, W / 2, 1.45))
    hood = box((-L / 2 + 0.4, -W / 2 + 0.35, 1.46), (xc0 - 0.01, W / 2 - 0.35, H - 0.35))
    cab = box((xc0, -W / 2, 1.46), (xc1, W / 2, 2.6))
    glass = frustum((xc0, -gy, 2.6), (xc1, gy, H - 0.2), (xc0, -gy + 0.05), (xc1 - 0.25, gy - 0.05))
    roof = box((xc0, -gy + 0.05, H - 0.2), (xc1 - 0.25, gy - 0.05, H))
    nose = chamfer_front_top(box((xc1 + 0.01, -W / 2 + 0.3, 1.46), (L / 2, W / 2 - 0.3, 2.5)), 0.2, 0.2)
    centres = [-(L / 2 - 3.8), L / 2 - 3.8]
    bogies = union(*[box((c - 1.9, -W / 2 + 0.4, 0.45), (c + 1.9, W / 2 - 0.4, 1.04)) for c in centres])
    tank = box((-(L / 2 - 6.0), -W / 2 + 0.5, 0.5), (L / 2 - 6.0, W / 2 - 0.5, 1.04))
    return [
        part("frame", frame, "Train", "metal", color=DARK),
        part("hood", union(hood, nose), "Train", "paint", color=paint),
        part("cab", cab, "Train", "paint", color=paint),
        glass_part("cab_windows", glass, "Train"),
        part("cab_roof", roof, "Train", "paint", color=paint),
        part("bogies", bogies, "Train", "metal", color=DARK),
        part("fuel_tank", tank, "Train", "metal", color=DARK),
    ] + _rail_wheels(centres, 1.4, 3, 0.52)
