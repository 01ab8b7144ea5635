"""Procedural road vehicles: cars, trucks, buses and trains (classes Car, Truck, Bus, Train).

Asset frame: metres, +X forward (the driving direction), +Y left, Z up; wheels touch z = 0.
Windows and windscreens are transparent glass parts of the vehicle's class.
"""

from __future__ import annotations

import numpy as np

from carlaocc.schemas.meshes import MeshPart
from carlaocc.stages.ingest.procedural.primitives import (
    _BLACK, _BLUE, _DARK, _GREEN, _ORANGE, _PAINTS, _RED, RGBA, _WHITE, _YELLOW, Builder, _beam, _box,
    _chamfer_front_top, _cone_between, _cylinder, _extrude, _frustum, _glass, _part, _pick, _u, _union,
)


def _wheels(
    xs, half_track: float, radius: float, width: float, semantic: str, sections: int = 16
) -> list[MeshPart]:
    """One wheel part per axle position in ``xs`` and side (axis along Y, touching z = 0)."""
    out = []
    for k, x in enumerate(xs):
        for side, sy in (("left", 1.0), ("right", -1.0)):
            y = sy * half_track
            mesh = _cylinder(radius, (x, y - width / 2, radius), (x, y + width / 2, radius), sections)
            out.append(_part(f"wheel_{k}_{side}", mesh, semantic, "rubber"))
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
    body = _chamfer_front_top(_box((-L / 2, -W / 2, clearance), (L / 2, W / 2, belt)), *hood)
    gy = W / 2 - 0.04
    glass_top = H - roof_t
    glass = _frustum(
        (gh_rear, -gy, belt), (gh_front, gy, glass_top),
        (gh_rear + top_rear, -gy + top_side), (gh_front - top_front, gy - top_side),
    )  # fmt: skip
    roof = _box((gh_rear + top_rear, -gy + top_side, glass_top), (gh_front - top_front, gy - top_side, H))
    parts = [
        _part("body", body, semantic, "paint", color=paint),
        _glass("windows", glass, semantic),
        _part("roof", roof, semantic, "paint", color=paint),
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
    "taxi": dict(_SEDAN, extra="taxi_sign", paints=(_YELLOW, _BLACK)),
    "police": dict(_SEDAN, H=(1.42, 1.52), extra="light_bar", paints=(_WHITE, _BLACK, (20, 35, 80, 255))),
}  # fmt: skip


def _car(subclass: str) -> Builder:
    """Builder of a Car sub-class from :data:`_CAR_SPECS`: a greenhouse vehicle, plus a roof
    sign (taxi) or light bar (police)."""
    spec = _CAR_SPECS[subclass]

    def build(rng: np.random.Generator) -> list[MeshPart]:
        L, W, H = _u(rng, *spec["L"]), _u(rng, *spec["W"]), _u(rng, *spec["H"])
        r = _u(rng, *spec["r"])
        paint = _pick(rng, spec.get("paints", _PAINTS))
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
            sign = _frustum((xc - 0.15, -0.40, H), (xc + 0.15, 0.40, H + 0.22), (xc - 0.12, -0.38), (xc + 0.12, 0.38))
            parts.append(_part("taxi_sign", sign, "Car", "plastic", color=(250, 220, 60, 255)))
        elif spec.get("extra") == "light_bar":
            bar = _box((xc - 0.14, -0.55, H), (xc + 0.14, 0.55, H + 0.11))
            parts.append(_part("light_bar", bar, "Car", "lens", color=_pick(rng, (_BLUE, _RED))))
        return parts

    return build


def _convertible(rng: np.random.Generator) -> list[MeshPart]:
    """Open two-seater (4.0-4.6 m): a low body, a raked windscreen, two seats sticking out of the
    cockpit, an optional folded hood behind them."""
    L, W, H_body = _u(rng, 4.0, 4.6), _u(rng, 1.75, 1.88), _u(rng, 0.92, 1.0)
    r, clear = _u(rng, 0.31, 0.34), 0.14
    paint = _pick(rng, _PAINTS)
    body = _chamfer_front_top(_box((-L / 2, -W / 2, clear), (L / 2, W / 2, H_body)), 0.30, 0.12)
    # windscreen: a thin slab leaning back 0.35 m over its 0.42 m height
    xw, gy = 0.16 * L, W / 2 - 0.08
    screen = _extrude([(xw, H_body), (xw + 0.05, H_body), (xw - 0.30, H_body + 0.42), (xw - 0.35, H_body + 0.42)],
                      -gy, gy)  # fmt: skip
    seat_x = -0.12 * L
    seats = _union(*[
        _box((seat_x - 0.12, sy * 0.42 - 0.24, H_body - 0.3), (seat_x + 0.0, sy * 0.42 + 0.24, H_body + 0.32))
        for sy in (-1.0, 1.0)
    ])  # fmt: skip
    parts = [
        _part("body", body, "Car", "paint", color=paint),
        _glass("windscreen", screen, "Car"),
        _part("seats", seats, "Car", "leather"),
    ]
    if rng.uniform() < 0.5:
        hood = _box((seat_x - 0.75, -W / 2 + 0.12, H_body), (seat_x - 0.25, W / 2 - 0.12, H_body + 0.18))
        parts.append(_part("folded_hood", hood, "Car", "cloth", color=_DARK))
    return parts + _wheels([L / 2 - 0.19 * L, -L / 2 + 0.21 * L], W / 2 - 0.14, r, 0.22, "Car")


def _pickup(rng: np.random.Generator) -> list[MeshPart]:
    """Pickup truck (5.0-5.5 m): a cab greenhouse over the front, an open bed behind it (floor,
    side walls, tailgate)."""
    L, W, H = _u(rng, 5.0, 5.5), _u(rng, 1.90, 2.03), _u(rng, 1.78, 1.92)
    r, clear = _u(rng, 0.38, 0.41), 0.25
    paint = _pick(rng, _PAINTS)
    belt = _u(rng, 1.05, 1.12)
    bed = _u(rng, 0.33, 0.38) * L
    x_bed = -L / 2 + bed  # front wall of the bed
    front = _chamfer_front_top(_box((x_bed, -W / 2, clear), (L / 2, W / 2, belt)), 0.15, 0.06)
    floor_top = belt - 0.45
    bed_floor = _box((-L / 2, -W / 2, clear + 0.1), (x_bed - 0.01, W / 2, floor_top))
    walls = _union(
        _box((-L / 2 + 0.07, W / 2 - 0.06, floor_top + 0.01), (x_bed - 0.01, W / 2, belt)),
        _box((-L / 2 + 0.07, -W / 2, floor_top + 0.01), (x_bed - 0.01, -W / 2 + 0.06, belt)),
        _box((-L / 2, -W / 2, floor_top + 0.01), (-L / 2 + 0.06, W / 2, belt - 0.02)),
    )
    gy = W / 2 - 0.05
    gh_rear, gh_front = x_bed + 0.02, 0.17 * L
    glass = _frustum(
        (gh_rear, -gy, belt), (gh_front, gy, H - 0.06), (gh_rear + 0.06, -gy + 0.1), (gh_front - 0.5, gy - 0.1)
    )
    roof = _box((gh_rear + 0.06, -gy + 0.1, H - 0.06), (gh_front - 0.5, gy - 0.1, H))
    parts = [
        _part("body", _union(front, bed_floor), "Car", "paint", color=paint),
        _part("bed_walls", walls, "Car", "paint", color=paint),
        _glass("windows", glass, "Car"),
        _part("roof", roof, "Car", "paint", color=paint),
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
    cab = _chamfer_front_top(_box((cab_x0, -W / 2, floor), (xf, W / 2, belt)), 0.08, 0.05)
    glass = _frustum(
        (cab_x0 + 0.3, -gy, belt), (xf - 0.05, gy, top), (cab_x0 + 0.3, -gy + 0.05), (xf - 0.30, gy - 0.05)
    )
    if glass_top is None:
        roof = _box((cab_x0 + 0.3, -gy + 0.05, top), (xf - 0.30, gy - 0.05, cab_h))
    else:
        roof = _frustum((cab_x0, -gy, top), (xf - 0.30, gy, cab_h), (cab_x0, -gy + 0.12), (xf - 0.9, gy - 0.12))
    back = _box((cab_x0, -gy, belt), (cab_x0 + 0.3, gy, top))
    return [
        _part("cab", cab, "Truck", "paint", color=paint),
        _glass("cab_windows", glass, "Truck"),
        _part("cab_roof", roof, "Truck", "paint", color=paint),
        _part("cab_back", back, "Truck", "paint", color=paint),
    ], cab_x0


def _chassis(x0: float, x1: float, z0: float = 0.55, z1: float = 1.0, half: float = 0.55) -> MeshPart:
    """Truck chassis beam from ``x0`` to ``x1``."""
    return _part("chassis", _box((x0, -half, z0), (x1, half, z1)), "Truck", "metal", color=_DARK)


_BODY_COLOURS = (_WHITE, (200, 200, 195, 255), (150, 155, 160, 255), (30, 75, 165, 255), (200, 85, 25, 255))


def _truck(subclass: str) -> Builder:
    """Trucks: a cab with its own windows at the front, a body behind it (cargo box, tank, fire
    equipment body with a ladder, semi-trailer, refuse compactor, flatbed, mixer drum, tipper),
    a chassis beam and 4-12 wheels."""

    def build(rng: np.random.Generator) -> list[MeshPart]:
        paint = _pick(rng, _PAINTS)
        r, wheel_w = 0.50, 0.32
        if subclass in ("box_truck", "tanker"):
            L = _u(rng, 6.5, 9.0) if subclass == "box_truck" else _u(rng, 8.0, 10.0)
            W, H = _u(rng, 2.30, 2.50), _u(rng, 3.0, 3.6)
            xf = L / 2
            parts, cab_x0 = _truck_cab(xf, W, _u(rng, 2.0, 2.3), _u(rng, 2.6, 2.9), paint)
            parts.append(_chassis(-L / 2 + 0.3, cab_x0 - 0.15))
            cargo_x0, cargo_x1 = -L / 2, cab_x0 - 0.15
            if subclass == "box_truck":
                box = _box((cargo_x0, -W / 2, 1.0), (cargo_x1, W / 2, H))
                parts.append(_part("cargo_box", box, "Truck", "paint", color=_pick(rng, _BODY_COLOURS)))
            else:
                tr = min((H - 1.0) / 2, W / 2 - 0.02)
                tank = _cylinder(tr, (cargo_x0, 0.0, 1.0 + tr), (cargo_x1, 0.0, 1.0 + tr), 20)
                parts.append(_part("tank", tank, "Truck", "metal", color=(190, 192, 195, 255)))
            axles = [xf - 1.2, -L / 2 + 1.6 + 1.35, -L / 2 + 1.6]
        elif subclass == "fire_truck":
            L, W = _u(rng, 8.5, 10.5), _u(rng, 2.45, 2.55)
            xf, cab_h, body_h = L / 2, _u(rng, 2.9, 3.1), _u(rng, 2.8, 3.1)
            parts, cab_x0 = _truck_cab(xf, W, _u(rng, 2.7, 3.1), cab_h, _RED)
            parts += [
                _chassis(-L / 2 + 0.3, cab_x0 - 0.1),
                _part("equipment_body", _box((-L / 2, -W / 2, 0.9), (cab_x0 - 0.1, W / 2, body_h)), "Truck", "paint",
                      color=_RED),
            ]  # fmt: skip
            # a ladder lying on top, reaching over the cab; rungs between (not touching) the rails
            zl, x0, x1 = max(body_h, cab_h) + 0.25, -L / 2 + 0.2, xf - 0.6
            rails = _union(_box((x0, 0.30, zl), (x1, 0.36, zl + 0.15)), _box((x0, -0.36, zl), (x1, -0.30, zl + 0.15)))
            n = int((x1 - x0) // 0.9)
            rung_x = [x0 + 0.45 + 0.9 * k for k in range(n)]
            rungs = _union(*[_box((x - 0.03, -0.29, zl + 0.05), (x + 0.03, 0.29, zl + 0.09)) for x in rung_x])
            turntable = _cylinder(0.6, (-L / 2 + 1.3, 0.0, body_h), (-L / 2 + 1.3, 0.0, zl - 0.01), 16)
            light = _box((xf - 1.3, -0.6, cab_h), (xf - 1.0, 0.6, cab_h + 0.12))
            parts += [
                _part("ladder_rails", rails, "Truck", "metal"),
                _part("ladder_rungs", rungs, "Truck", "metal"),
                _part("turntable", turntable, "Truck", "metal"),
                _part("light_bar", light, "Truck", "lens", color=_RED),
            ]
            axles = [xf - 1.5, -L / 2 + 2.2]
        elif subclass == "semi_truck":
            L, W = _u(rng, 15.0, 16.5), _u(rng, 2.45, 2.55)
            xf = L / 2
            parts, cab_x0 = _truck_cab(xf, W, _u(rng, 2.3, 2.6), _u(rng, 3.6, 3.9), paint, belt=1.75, glass_top=2.75)
            trailer_x1 = cab_x0 - 0.7
            xg = trailer_x1 - 4.5  # landing gear, clear of the tractor's rear wheels
            tanks = _union(*[_cylinder(0.30, (cab_x0 - 1.6, sy * 0.9, 0.75), (cab_x0 - 0.4, sy * 0.9, 0.75), 12)
                             for sy in (-1.0, 1.0)])  # fmt: skip
            parts += [
                _chassis(xf - 6.4, cab_x0 - 0.05, 0.6, 1.05, 0.5),
                _part("fifth_wheel", _box((xf - 5.8, -0.5, 1.06), (xf - 4.6, 0.5, 1.15)), "Truck", "metal"),
                _part("fuel_tanks", tanks, "Truck", "metal", color=(200, 200, 205, 255)),
                _part("trailer", _box((-L / 2, -W / 2, 1.25), (trailer_x1, W / 2, _u(rng, 3.9, 4.05))), "Truck",
                      "paint", color=_pick(rng, _BODY_COLOURS)),
                _part("landing_gear", _union(*[_box((xg, sy * 0.9 - 0.06, 0.3), (xg + 0.12, sy * 0.9 + 0.06, 1.24))
                                                for sy in (-1.0, 1.0)]), "Truck", "metal"),
            ]  # fmt: skip
            axles = [xf - 1.3, xf - 4.9, xf - 6.2, -L / 2 + 1.3, -L / 2 + 2.6, -L / 2 + 3.9]
        elif subclass == "garbage_truck":
            L, W, H = _u(rng, 8.0, 10.0), _u(rng, 2.45, 2.55), _u(rng, 3.4, 3.7)
            xf = L / 2
            colour = _pick(rng, (_WHITE, (60, 130, 60, 255), _ORANGE, (150, 155, 160, 255)))
            parts, cab_x0 = _truck_cab(xf, W, _u(rng, 2.2, 2.5), _u(rng, 2.7, 2.9), colour)
            xh = -L / 2 + 1.4  # the rear hopper, tapered, behind the compactor body
            hopper = _extrude([(xh - 0.01, 0.9), (xh - 0.01, H - 0.05), (-L / 2 + 0.5, H - 0.35), (-L / 2, 1.9),
                               (-L / 2 + 0.3, 0.9)], -W / 2 + 0.05, W / 2 - 0.05)  # fmt: skip
            parts += [
                _chassis(-L / 2 + 0.5, cab_x0 - 0.15),
                _part("compactor_body", _box((xh, -W / 2, 1.0), (cab_x0 - 0.15, W / 2, H)), "Truck", "paint",
                      color=colour),
                _part("hopper", hopper, "Truck", "paint", color=colour),
            ]  # fmt: skip
            axles = [xf - 1.3, -L / 2 + 2.4, -L / 2 + 3.7]
        elif subclass == "tow_truck":
            L, W = _u(rng, 6.5, 8.0), _u(rng, 2.30, 2.45)
            xf, cab_h = L / 2, _u(rng, 2.6, 2.8)
            parts, cab_x0 = _truck_cab(xf, W, _u(rng, 2.1, 2.3), cab_h, paint)
            xd = cab_x0 - 0.3
            parts += [
                _chassis(-L / 2 + 0.4, cab_x0 - 0.1),
                _part("deck", _box((-L / 2, -W / 2, 1.01), (xd, W / 2, 1.16)), "Truck", "metal"),
                _part("headboard", _box((xd + 0.01, -W / 2 + 0.1, 1.01), (xd + 0.14, W / 2 - 0.1, 2.3)), "Truck",
                      "metal"),
                _part("light_bar", _box((xf - 1.2, -0.6, cab_h), (xf - 0.9, 0.6, cab_h + 0.12)), "Truck", "lens",
                      color=_ORANGE),
            ]  # fmt: skip
            axles = [xf - 1.2, -L / 2 + 1.8]
        elif subclass == "cement_mixer":
            L, W = _u(rng, 8.0, 9.5), _u(rng, 2.45, 2.50)
            xf = L / 2
            parts, cab_x0 = _truck_cab(xf, W, _u(rng, 2.2, 2.4), _u(rng, 2.7, 2.9), paint)
            R = _u(rng, 1.05, 1.15)
            pf, pr = np.array([cab_x0 - 1.0, 0.0, 2.05]), np.array([-L / 2 + 1.3, 0.0, 2.55])
            d = (pr - pf) / np.linalg.norm(pr - pf)
            colour = _pick(rng, (_WHITE, _ORANGE, _BLUE, (200, 200, 195, 255)))
            parts += [
                _chassis(-L / 2 + 0.3, cab_x0 - 0.15),
                _part("drum", _cylinder(R, pf, pr, 16), "Truck", "paint", color=colour),
                _part("drum_front", _cone_between(R, pf, pf - 0.8 * d, 16), "Truck", "paint", color=colour),
                _part("drum_rear", _cone_between(R, pr, pr + 1.0 * d, 16), "Truck", "paint", color=colour),
            ]
            axles = [xf - 1.3, -L / 2 + 1.6, -L / 2 + 2.95]
        elif subclass == "dump_truck":
            L, W = _u(rng, 7.0, 8.8), _u(rng, 2.45, 2.55)
            xf, cab_h, Ht = L / 2, _u(rng, 2.8, 3.0), _u(rng, 2.5, 2.9)
            parts, cab_x0 = _truck_cab(xf, W, _u(rng, 2.1, 2.4), cab_h, paint)
            profile = [(-W / 2 + 0.15, 1.1), (W / 2 - 0.15, 1.1), (W / 2, Ht), (-W / 2, Ht)]  # flared sides
            tipper = _extrude(profile, -L / 2, cab_x0 - 0.2, "x")
            zg = max(Ht, cab_h) + 0.02
            guard = _box((cab_x0 - 0.19, -W / 2 + 0.1, zg), (cab_x0 + 0.9, W / 2 - 0.1, zg + 0.1))
            colour = _pick(rng, (_YELLOW, _ORANGE, (150, 155, 160, 255), _RED))
            parts += [
                _chassis(-L / 2 + 0.3, cab_x0 - 0.15),
                _part("tipper", tipper, "Truck", "metal", color=colour),
                _part("cab_guard", guard, "Truck", "metal", color=colour),
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


def _bus(subclass: str) -> Builder:
    """City bus (10.5-12.5 m), minibus (6.5-7.8 m) or coach (12-13.8 m, high window band, tandem
    rear axle): a full-length window band over the body."""
    spec = _BUS_SPECS[subclass]

    def build(rng: np.random.Generator) -> list[MeshPart]:
        L, W, H = _u(rng, *spec["L"]), _u(rng, *spec["W"]), _u(rng, *spec["H"])
        paint = _pick(rng, _PAINTS)
        axles = [L / 2 - spec["front"]] + [-L / 2 + d for d in spec["rear"]]
        return _greenhouse_vehicle(
            L, W, H, semantic="Bus", clearance=spec["clear"], belt=spec["belt"],
            gh_rear=-L / 2 + 0.05, gh_front=L / 2 - 0.05, top_rear=0.05, top_front=spec["top_front"],
            top_side=0.03, hood=(0.05, 0.02), wheel_r=spec["r"], wheel_w=0.30, axles=axles, paint=paint,
        )  # fmt: skip

    return build


def _school_bus(rng: np.random.Generator) -> list[MeshPart]:
    """Conventional (bonneted) school bus, 9.5-12 m, yellow: an engine bonnet in front of the
    passenger box, a window band and roof."""
    L, W, H = _u(rng, 9.5, 12.0), _u(rng, 2.40, 2.50), _u(rng, 3.0, 3.2)
    bonnet_len = _u(rng, 1.4, 1.7)
    xb = L / 2 - bonnet_len  # the front of the passenger box
    gy, belt, glass_top = W / 2 - 0.04, 1.55, H - 0.3
    bonnet = _chamfer_front_top(_box((xb + 0.01, -W / 2 + 0.25, 0.45), (L / 2, W / 2 - 0.25, 1.55)), 0.25, 0.12)
    body = _box((-L / 2, -W / 2, 0.35), (xb, W / 2, belt))
    glass = _frustum((-L / 2 + 0.05, -gy, belt), (xb - 0.02, gy, glass_top), (-L / 2 + 0.05, -gy + 0.03),
                     (xb - 0.25, gy - 0.03))  # fmt: skip
    roof = _box((-L / 2, -W / 2, glass_top), (xb - 0.2, W / 2, H))
    return [
        _part("bonnet", bonnet, "Bus", "paint", color=_YELLOW),
        _part("body", body, "Bus", "paint", color=_YELLOW),
        _glass("windows", glass, "Bus"),
        _part("roof", roof, "Bus", "paint", color=_YELLOW),
    ] + _wheels([L / 2 - bonnet_len + 0.3, -L / 2 + 3.0], W / 2 - 0.18, 0.48, 0.30, "Bus")


def _double_decker(rng: np.random.Generator) -> list[MeshPart]:
    """Double-decker bus, 10-11.5 m long and 4.2-4.4 m tall: two window bands separated by a
    body band."""
    L, W, H = _u(rng, 10.0, 11.5), _u(rng, 2.50, 2.55), _u(rng, 4.2, 4.4)
    paint = _pick(rng, (_RED, _RED, _PAINTS[0], _BLUE, _GREEN))
    gy = W / 2 - 0.03
    lower = _box((-L / 2, -W / 2, 0.30), (L / 2, W / 2, 1.0))
    mid = _box((-L / 2, -W / 2, 2.05), (L / 2, W / 2, 2.45))
    roof = _box((-L / 2 + 0.05, -W / 2 + 0.03, H - 0.22), (L / 2 - 0.05, W / 2 - 0.03, H))
    glass = _union(
        _box((-L / 2 + 0.05, -gy, 1.01), (L / 2 - 0.05, gy, 2.04)),
        _box((-L / 2 + 0.05, -gy, 2.46), (L / 2 - 0.05, gy, H - 0.23)),
    )
    return [
        _part("body", _union(lower, mid), "Bus", "paint", color=paint),
        _glass("windows", glass, "Bus"),
        _part("roof", roof, "Bus", "paint", color=paint),
    ] + _wheels([L / 2 - 2.4, -L / 2 + 2.8], W / 2 - 0.18, 0.50, 0.30, "Bus")


def _rail_wheels(centres, spacing: float, per_bogie: int, radius: float) -> list[MeshPart]:
    """Rail wheels (standard gauge) of ``per_bogie`` axles ``spacing`` apart on each bogie."""
    xs = [c + (k - (per_bogie - 1) / 2) * spacing for c in centres for k in range(per_bogie)]
    return _wheels(xs, 0.72, radius, 0.14, "Train", 12)


def _doors(xs, half_w: float, y: float, z0: float, z1: float, colour: RGBA) -> MeshPart:
    """Door leaves on both sides of a rail car: thin boxes straddling the side walls at ``y``."""
    leaves = [_box((x - half_w, sy * y - 0.03, z0), (x + half_w, sy * y + 0.03, z1)) for x in xs for sy in (-1.0, 1.0)]
    return _part("doors", _union(*leaves), "Train", "metal", color=colour)


def _tram(rng: np.random.Generator) -> list[MeshPart]:
    """Low-floor articulated tram, 20-32 m: a window band with raked windscreens at both ends,
    side doors, skirted bogies and a roof pantograph."""
    L, W, H = _u(rng, 20.0, 32.0), _u(rng, 2.30, 2.65), _u(rng, 3.3, 3.5)
    paint = _pick(rng, (_WHITE, _RED, _YELLOW, (30, 120, 160, 255), _GREEN))
    floor, belt, glass_top = 0.35, 1.0, _u(rng, 2.45, 2.6)
    gy = W / 2 - 0.04
    body = _box((-L / 2, -W / 2, floor), (L / 2, W / 2, belt))
    glass = _frustum((-L / 2 + 0.05, -gy, belt), (L / 2 - 0.05, gy, glass_top), (-L / 2 + 0.5, -gy + 0.03),
                     (L / 2 - 0.5, gy - 0.03))  # fmt: skip
    roof = _box((-L / 2 + 0.5, -gy + 0.03, glass_top), (L / 2 - 0.5, gy - 0.03, H))
    n_bogie = 2 + int(L > 26.0)
    centres = [(-L / 2 + 2.6) + k * (L - 5.2) / (n_bogie - 1) for k in range(n_bogie)]
    bogies = _union(*[_box((c - 1.2, -W / 2 + 0.12, 0.0), (c + 1.2, W / 2 - 0.12, floor - 0.01)) for c in centres])
    n_doors = int(L // 6.5)
    doors = [(-L / 2 + 2.0) + (k + 0.5) * (L - 4.0) / n_doors for k in range(n_doors)]
    xp = float(centres[0] + centres[-1]) / 2 + 2.0
    return [
        _part("body", body, "Train", "paint", color=paint),
        _glass("windows", glass, "Train"),
        _part("roof", roof, "Train", "paint", color=paint),
        _part("bogies", bogies, "Train", "metal", color=_DARK),
        _doors(doors, 0.65, W / 2, floor + 0.05, glass_top - 0.1, _DARK),
        _part("pantograph_base", _box((xp - 0.6, -0.4, H), (xp + 0.6, 0.4, H + 0.12)), "Train", "metal"),
        _part("pantograph_arm", _beam((xp - 0.5, 0.0, H + 0.1), (xp + 0.2, 0.0, H + 0.57), 0.06, 0.06), "Train",
              "metal"),
        _part("pantograph_bow", _box((xp + 0.15, -0.75, H + 0.55), (xp + 0.25, 0.75, H + 0.6)), "Train", "metal"),
    ]


def _metro(rng: np.random.Generator) -> list[MeshPart]:
    """Metro / subway car, 18-20.5 m: flat ends with windscreens, a window band, three doors a
    side, two bogies of two axles."""
    L, W, H = _u(rng, 18.0, 20.5), _u(rng, 2.80, 3.05), _u(rng, 3.5, 3.8)
    paint = _pick(rng, (_PAINTS[2], _WHITE, _BLUE, (200, 200, 195, 255)))
    gy = W / 2 - 0.04
    body = _box((-L / 2, -W / 2, 0.95), (L / 2, W / 2, 1.9))
    glass = _frustum(
        (-L / 2 + 0.03, -gy, 1.9), (L / 2 - 0.03, gy, 2.9), (-L / 2 + 0.15, -gy + 0.02), (L / 2 - 0.15, gy - 0.02)
    )
    roof = _box((-L / 2 + 0.15, -gy + 0.02, 2.9), (L / 2 - 0.15, gy - 0.02, H))
    centres = [-L / 2 + 2.6, L / 2 - 2.6]
    bogies = _union(*[_box((c - 1.3, -W / 2 + 0.35, 0.35), (c + 1.3, W / 2 - 0.35, 0.94)) for c in centres])
    return [
        _part("body", body, "Train", "paint", color=paint),
        _glass("windows", glass, "Train"),
        _part("roof", roof, "Train", "paint", color=paint),
        _part("bogies", bogies, "Train", "metal", color=_DARK),
        _doors([-L / 4, 0.0, L / 4], 0.7, W / 2, 1.0, 2.8, _pick(rng, (_RED, _YELLOW, _DARK))),
    ] + _rail_wheels(centres, 1.8, 2, 0.43)


def _locomotive(rng: np.random.Generator) -> list[MeshPart]:
    """Diesel locomotive (taxonomy sub-class ``train``), 16.5-21 m: a frame, a narrow hood, a
    full-width cab with windows near the front, a short nose, two three-axle bogies, a fuel tank."""
    L, W, H = _u(rng, 16.5, 21.0), _u(rng, 2.90, 3.10), _u(rng, 4.0, 4.3)
    paint = _pick(rng, (_RED, _BLUE, _YELLOW, _GREEN, _ORANGE, _DARK))
    gy = W / 2 - 0.05
    xc0, xc1 = L / 2 - 3.4, L / 2 - 0.6  # the cab
    frame = _box((-L / 2, -W / 2, 1.05), (L / 2, W / 2, 1.45))
    hood = _box((-L / 2 + 0.4, -W / 2 + 0.35, 1.46), (xc0 - 0.01, W / 2 - 0.35, H - 0.35))
    cab = _box((xc0, -W / 2, 1.46), (xc1, W / 2, 2.6))
    glass = _frustum((xc0, -gy, 2.6), (xc1, gy, H - 0.2), (xc0, -gy + 0.05), (xc1 - 0.25, gy - 0.05))
    roof = _box((xc0, -gy + 0.05, H - 0.2), (xc1 - 0.25, gy - 0.05, H))
    nose = _chamfer_front_top(_box((xc1 + 0.01, -W / 2 + 0.3, 1.46), (L / 2, W / 2 - 0.3, 2.5)), 0.2, 0.2)
    centres = [-(L / 2 - 3.8), L / 2 - 3.8]
    bogies = _union(*[_box((c - 1.9, -W / 2 + 0.4, 0.45), (c + 1.9, W / 2 - 0.4, 1.04)) for c in centres])
    tank = _box((-(L / 2 - 6.0), -W / 2 + 0.5, 0.5), (L / 2 - 6.0, W / 2 - 0.5, 1.04))
    return [
        _part("frame", frame, "Train", "metal", color=_DARK),
        _part("hood", _union(hood, nose), "Train", "paint", color=paint),
        _part("cab", cab, "Train", "paint", color=paint),
        _glass("cab_windows", glass, "Train"),
        _part("cab_roof", roof, "Train", "paint", color=paint),
        _part("bogies", bogies, "Train", "metal", color=_DARK),
        _part("fuel_tank", tank, "Train", "metal", color=_DARK),
    ] + _rail_wheels(centres, 1.4, 3, 0.52)
