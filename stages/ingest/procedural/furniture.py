"""Procedural street furniture (class Static: benches, bins, hydrants, bus stops, mailboxes,
kiosks, bollards, planters, barriers, cones, billboards, vending machines, phone booths) and
movable props (class Dynamic: wheeled bins, boxes, luggage).

Asset frame: metres, Z up; the usable side (seat, open side, service window, front panel, door,
board face, slot) faces +X.
"""

from __future__ import annotations

import numpy as np

from carlaocc.schemas.meshes import MeshPart
from carlaocc.stages.ingest.procedural.primitives import (
    BLACK, BLUE, DARK, GREEN, ORANGE, PAINTS, RED, WHITE, YELLOW, box, cone, cylinder,
    ellipsoid, extrude, frustum, glass_part, part, pick, uniform, union,
)


def bench(rng: np.random.Generator) -> list[MeshPart]:
    """Park bench, 1.5-1.8 m long: seat, backrest at -X, two leg frames."""
    L = uniform(rng, 1.5, 1.8)
    seat = box((-0.22, -L / 2, 0.42), (0.22, L / 2, 0.47))
    back = box((-0.30, -L / 2, 0.50), (-0.25, L / 2, 0.85))
    legs = union(
        box((-0.25, -L / 2 + 0.10, 0.0), (0.20, -L / 2 + 0.16, 0.42)),
        box((-0.25, L / 2 - 0.16, 0.0), (0.20, L / 2 - 0.10, 0.42)),
    )
    supports = union(
        box((-0.30, -L / 2 + 0.10, 0.42), (-0.25, -L / 2 + 0.16, 0.50)),
        box((-0.30, L / 2 - 0.16, 0.42), (-0.25, L / 2 - 0.10, 0.50)),
    )
    return [
        part("seat", seat, "Static", "wood"),
        part("backrest", back, "Static", "wood"),
        part("legs", legs, "Static", "metal"),
        part("back_supports", supports, "Static", "metal"),
    ]


def litter_bin(rng: np.random.Generator) -> list[MeshPart]:
    """Litter bin: a 0.8-1.0 m cylinder with a lid."""
    r, h = uniform(rng, 0.22, 0.30), uniform(rng, 0.8, 1.0)
    colour = pick(rng, (DARK, GREEN, (60, 60, 60, 255), (150, 155, 160, 255)))
    body = cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, h), 16)
    lid = cylinder(r + 0.02, (0.0, 0.0, h), (0.0, 0.0, h + 0.05), 16)
    return [
        part("body", body, "Static", "plastic", color=colour),
        part("lid", lid, "Static", "plastic", color=colour),
    ]


def hydrant(rng: np.random.Generator) -> list[MeshPart]:
    """Fire hydrant, 0.6-0.8 m: a base flange, a barrel, a domed cap and side outlets."""
    h, r = uniform(rng, 0.5, 0.65), uniform(rng, 0.10, 0.13)
    colour = pick(rng, (RED, YELLOW, (200, 200, 195, 255)))
    zo = 0.06 + 0.7 * h  # outlet height
    return [
        part("base", cylinder(r + 0.04, (0.0, 0.0, 0.0), (0.0, 0.0, 0.06), 12), "Static", "metal", color=colour),
        part("barrel", cylinder(r, (0.0, 0.0, 0.06), (0.0, 0.0, 0.06 + h), 12), "Static", "metal", color=colour),
        part("cap", ellipsoid((0.0, 0.0, 0.06 + h), (r + 0.01, r + 0.01, 0.09), 1), "Static", "metal", color=colour),
        part("outlets", cylinder(0.045, (0.0, -r - 0.08, zo), (0.0, r + 0.08, zo), 10), "Static", "metal",
              color=colour),
    ]  # fmt: skip


def bus_stop(rng: np.random.Generator) -> list[MeshPart]:
    """Bus shelter, 3.5-6 m long: a roof on four posts, a glass back wall at -X and a glass side
    panel, a bench; the open side faces +X."""
    L, H = uniform(rng, 3.5, 6.0), uniform(rng, 2.5, 2.8)
    corners = [(sx * 0.65, sy * (L / 2 - 0.1)) for sx in (-1.0, 1.0) for sy in (-1.0, 1.0)]
    posts = union(*[cylinder(0.04, (x, y, 0.0), (x, y, H - 0.11), 10) for x, y in corners])
    glass = union(
        box((-0.72, -L / 2 + 0.15, 0.10), (-0.68, L / 2 - 0.15, H - 0.2)),
        box((-0.60, L / 2 - 0.12, 0.10), (0.40, L / 2 - 0.08, H - 0.2)),
    )
    return [
        part("roof", box((-0.8, -L / 2, H - 0.1), (0.8, L / 2, H)), "Static", "metal"),
        part("posts", posts, "Static", "metal"),
        glass_part("panels", glass, "Static"),
        part("bench", box((-0.62, -L / 3, 0.42), (-0.25, L / 3, 0.47)), "Static", "wood"),
        part("bench_legs", union(*[box((-0.5, y - 0.03, 0.0), (-0.4, y + 0.03, 0.41)) for y in (-L / 4, L / 4)]),
              "Static", "metal"),
    ]  # fmt: skip


def mailbox(rng: np.random.Generator) -> list[MeshPart]:
    """Post box: a round pillar box with a domed cap, or a box on a post; the slot faces +X."""
    colour = pick(rng, (RED, YELLOW, BLUE, GREEN))
    if rng.uniform() < 0.5:
        r, h = uniform(rng, 0.22, 0.28), uniform(rng, 1.1, 1.4)
        return [
            part("body", cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, h), 16), "Static", "metal", color=colour),
            part("cap", ellipsoid((0.0, 0.0, h), (r + 0.02, r + 0.02, 0.12), 1), "Static", "metal", color=colour),
            part("slot", box((r - 0.02, -0.1, h - 0.25), (r + 0.01, 0.1, h - 0.21)), "Static", "plastic",
                  color=BLACK),
        ]  # fmt: skip
    w, hb = uniform(rng, 0.35, 0.45), uniform(rng, 0.45, 0.6)
    return [
        part("post", box((-0.04, -0.04, 0.0), (0.04, 0.04, 0.8)), "Static", "metal"),
        part("body", box((-0.15, -w / 2, 0.81), (0.15, w / 2, 0.81 + hb)), "Static", "metal", color=colour),
        part("slot", box((0.14, -0.1, 0.81 + hb - 0.12), (0.16, 0.1, 0.81 + hb - 0.09)), "Static", "plastic",
              color=BLACK),
    ]  # fmt: skip


def kiosk(rng: np.random.Generator) -> list[MeshPart]:
    """Street kiosk, 2.2-3 m deep: a hut with an overhanging roof, a glazed service window and a
    counter on the +X side."""
    D, F, H = uniform(rng, 2.2, 3.0), uniform(rng, 2.5, 4.0), uniform(rng, 2.6, 3.0)
    return [
        part("body", box((-D / 2, -F / 2, 0.0), (D / 2, F / 2, H - 0.16)), "Static", "wood",
              color=pick(rng, (GREEN, (110, 75, 45, 255), BLUE, (200, 200, 195, 255)))),
        part("roof", box((-D / 2 - 0.3, -F / 2 - 0.3, H - 0.15), (D / 2 + 0.4, F / 2 + 0.3, H)), "Static", "metal"),
        glass_part("window", box((D / 2 - 0.05, -F / 3, 1.0), (D / 2 + 0.05, F / 3, 2.1)), "Static"),
        part("counter", box((D / 2 + 0.06, -F / 3, 0.95), (D / 2 + 0.35, F / 3, 1.0)), "Static", "wood"),
    ]  # fmt: skip


def bollard(rng: np.random.Generator) -> list[MeshPart]:
    """Bollard, 0.8-1.0 m: a post with a reflective band near its top."""
    r, h = uniform(rng, 0.08, 0.12), uniform(rng, 0.8, 1.0)
    return [
        part("post", cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, h), 12), "Static", "metal",
              color=pick(rng, (DARK, (150, 155, 160, 255), RED))),
        part("band", cylinder(r + 0.005, (0.0, 0.0, h - 0.15), (0.0, 0.0, h - 0.08), 12), "Static", "plastic",
              color=WHITE),
    ]  # fmt: skip


def planter(rng: np.random.Generator) -> list[MeshPart]:
    """Concrete planter box with a shrub (class Vegetation) growing out of it."""
    L, w, h = uniform(rng, 1.0, 2.0), uniform(rng, 0.6, 1.0), uniform(rng, 0.5, 0.8)
    shrub = ellipsoid((0.0, 0.0, h), (0.4 * L, 0.4 * w, uniform(rng, 0.3, 0.6)), 1)
    return [
        part("box", box((-L / 2, -w / 2, 0.0), (L / 2, w / 2, h)), "Static", "concrete"),
        part("shrub", shrub, "Vegetation", "foliage"),
    ]


def barrier(rng: np.random.Generator) -> list[MeshPart]:
    """Jersey barrier, 2-4 m long and 0.81 m high, in concrete or red/white plastic."""
    L = uniform(rng, 2.0, 4.0)
    profile = [(-0.3, 0.0), (0.3, 0.0), (0.3, 0.08), (0.1, 0.81), (-0.1, 0.81), (-0.3, 0.08)]
    if rng.uniform() < 0.6:
        return [part("barrier", extrude(profile, -L / 2, L / 2, "x"), "Static", "concrete")]
    colour = pick(rng, (RED, WHITE))
    return [part("barrier", extrude(profile, -L / 2, L / 2, "x"), "Static", "plastic", color=colour)]


def traffic_cone(rng: np.random.Generator) -> list[MeshPart]:
    """Traffic cone, 0.5-0.75 m, on a square base."""
    h, r = uniform(rng, 0.45, 0.70), uniform(rng, 0.13, 0.16)
    return [
        part("base", box((-0.19, -0.19, 0.0), (0.19, 0.19, 0.03)), "Static", "rubber"),
        part("cone", cone(r, h, (0.0, 0.0, 0.03), 12), "Static", "plastic", color=ORANGE),
    ]


def billboard(rng: np.random.Generator) -> list[MeshPart]:
    """Billboard: a 3-6 m by 2-3 m board 2.5-4.5 m up on one or two posts behind it; the face
    looks +X."""
    W, Hb, Hh = uniform(rng, 3.0, 6.0), uniform(rng, 2.5, 4.5), uniform(rng, 2.0, 3.0)
    ys = (0.0,) if W < 4.0 else (-W / 4, W / 4)
    posts = union(*[cylinder(0.15, (-0.2, y, 0.0), (-0.2, y, Hb + Hh - 0.3), 12) for y in ys])
    return [
        part("posts", posts, "Static", "metal"),
        part("board", box((-0.04, -W / 2, Hb), (0.2, W / 2, Hb + Hh)), "Static", "sign_face",
              color=pick(rng, PAINTS)),
    ]


def vending_machine(rng: np.random.Generator) -> list[MeshPart]:
    """Vending machine, 1.8-1.95 m: a cabinet with a glazed display on its +X front and a
    delivery slot."""
    W, H = uniform(rng, 0.9, 1.2), uniform(rng, 1.8, 1.95)
    return [
        part("cabinet", box((-0.4, -W / 2, 0.0), (0.4, W / 2, H)), "Static", "metal", color=pick(rng, PAINTS)),
        glass_part("display", box((0.38, -W / 2 + 0.08, 0.7), (0.42, W / 4, H - 0.15)), "Static"),
        part("slot", box((0.38, -W / 2 + 0.1, 0.15), (0.42, W / 4, 0.35)), "Static", "plastic", color=BLACK),
    ]


def phone_booth(rng: np.random.Generator) -> list[MeshPart]:
    """Phone booth, about 1 m square and 2.4-2.6 m tall: a base, four corner posts, glass panes on
    every side (the door at +X) and a roof."""
    a, H = uniform(rng, 0.9, 1.05), uniform(rng, 2.4, 2.6)
    colour = pick(rng, (RED, (150, 155, 160, 255), BLUE))
    h = a / 2
    posts = union(*[box((sx * h - 0.04 * (sx > 0), sy * h - 0.04 * (sy > 0), 0.11),
                          (sx * h + 0.04 * (sx < 0), sy * h + 0.04 * (sy < 0), H - 0.21))
                     for sx in (-1.0, 1.0) for sy in (-1.0, 1.0)])  # fmt: skip
    panes = union(
        box((h - 0.03, -h + 0.05, 0.2), (h - 0.01, h - 0.05, H - 0.3)),
        box((-h + 0.01, -h + 0.05, 0.2), (-h + 0.03, h - 0.05, H - 0.3)),
        box((-h + 0.05, h - 0.03, 0.2), (h - 0.05, h - 0.01, H - 0.3)),
        box((-h + 0.05, -h + 0.01, 0.2), (h - 0.05, -h + 0.03, H - 0.3)),
    )
    return [
        part("base", box((-h, -h, 0.0), (h, h, 0.1)), "Static", "metal", color=colour),
        part("posts", posts, "Static", "metal", color=colour),
        glass_part("panes", panes, "Static"),
        part("roof", box((-h - 0.03, -h - 0.03, H - 0.2), (h + 0.03, h + 0.03, H)), "Static", "metal", color=colour),
    ]


def movable_bin(rng: np.random.Generator) -> list[MeshPart]:
    """Wheelie bin, 1.0-1.1 m: a tapered body, a lid, two wheels and a handle at -X."""
    h = uniform(rng, 0.95, 1.05)
    colour = pick(rng, (GREEN, DARK, BLUE, (110, 80, 50, 255), (150, 155, 160, 255)))
    body = frustum((-0.28, -0.25, 0.05), (0.28, 0.25, h), (-0.31, -0.29), (0.31, 0.29))
    wheels = union(*[cylinder(0.1, (-0.24, sy * 0.26 - 0.025, 0.1), (-0.24, sy * 0.26 + 0.025, 0.1), 12)
                      for sy in (-1.0, 1.0)])  # fmt: skip
    return [
        part("body", body, "Dynamic", "plastic", color=colour),
        part("lid", box((-0.33, -0.31, h + 0.001), (0.33, 0.31, h + 0.05)), "Dynamic", "plastic", color=colour),
        part("wheels", wheels, "Dynamic", "rubber"),
        part("handle", box((-0.37, -0.2, h - 0.12), (-0.335, 0.2, h - 0.08)), "Dynamic", "plastic", color=colour),
    ]


def boxes(rng: np.random.Generator) -> list[MeshPart]:
    """A stack of 1-3 cardboard boxes (0.3-0.8 m), each a part of its own."""
    parts, z = [], 0.0
    for k in range(int(rng.integers(1, 4))):
        a, b, c = uniform(rng, 0.3, 0.8), uniform(rng, 0.3, 0.8), uniform(rng, 0.25, 0.6)
        dx, dy = uniform(rng, -0.05, 0.05), uniform(rng, -0.05, 0.05)
        parts.append(part(f"box_{k}", box((dx - a / 2, dy - b / 2, z), (dx + a / 2, dy + b / 2, z + c)), "Dynamic",
                           "cardboard"))  # fmt: skip
        z += c
    return parts


def luggage(rng: np.random.Generator) -> list[MeshPart]:
    """Upright suitcase, 0.55-0.75 m, with an extended telescopic handle and two wheels."""
    d, w, h = uniform(rng, 0.22, 0.30), uniform(rng, 0.38, 0.50), uniform(rng, 0.55, 0.75)
    hh = uniform(rng, 0.3, 0.45)
    rods = union(*[box((-d / 2 + 0.02, y - 0.01, h + 0.05), (-d / 2 + 0.04, y + 0.01, h + 0.05 + hh))
                    for y in (-0.12, 0.12)])  # fmt: skip
    yw = w / 2 - 0.05  # wheel centres at +-yw
    xw = -d / 2 + 0.04
    wheels = union(*[cylinder(0.03, (xw, y - 0.015, 0.03), (xw, y + 0.015, 0.03), 10) for y in (-yw, yw)])
    return [
        part("case", box((-d / 2, -w / 2, 0.05), (d / 2, w / 2, h + 0.05)), "Dynamic", "plastic",
              color=pick(rng, PAINTS)),
        part("handle_rods", rods, "Dynamic", "metal"),
        part("grip", box((-d / 2 + 0.01, -0.14, h + 0.06 + hh), (-d / 2 + 0.05, 0.14, h + 0.09 + hh)), "Dynamic",
              "plastic", color=BLACK),
        part("wheels", wheels, "Dynamic", "rubber"),
    ]  # fmt: skip
