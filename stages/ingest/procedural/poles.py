"""Procedural things on a pole: street lights, utility poles and flagpoles (class Pole), traffic
lights (TrafficLight) and traffic signs (TrafficSign).

Asset frame: metres, Z up. The pole stands at ``x = -extent[0]/2 + r`` (``r`` its radius,
0.04-0.14 m), ``y = 0`` (the overhead signal's at ``y = +extent[1]/2 - r``); arms, lamps, lenses
and sign plates face +X (towards the road or the traffic they control).
"""

from __future__ import annotations

import numpy as np

from carlaocc.schemas.meshes import MeshPart
from carlaocc.stages.ingest.procedural.primitives import (
    BLUE, DARK, GREEN, PAINTS, RED, RGBA, WHITE, YELLOW, Builder, Mesh, box, cylinder, ellipsoid,
    extrude, part, pick, plate_x, shift, uniform, union,
)


def street_light(rng: np.random.Generator) -> list[MeshPart]:
    """Street light: 7-9 m pole, an arm of 1.5-2.5 m along +X, a lamp head at its end."""
    h, arm, r = uniform(rng, 7.0, 9.0), uniform(rng, 1.5, 2.5), uniform(rng, 0.08, 0.11)
    pole = cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, h), 12)
    arm_mesh = box((r, -0.04, h - 0.20), (arm, 0.04, h - 0.10))
    lamp = box((arm, -0.15, h - 0.30), (arm + 0.6, 0.15, h - 0.08))
    return [
        part("pole", pole, "Pole", "metal"),
        part("arm", arm_mesh, "Pole", "metal"),
        part("lamp", lamp, "Pole", "lamp"),
    ]


def utility_pole(rng: np.random.Generator) -> list[MeshPart]:
    """Wooden utility pole, 9-12 m: a cross-arm near the top with four insulators, and on half of
    them a pole-mounted transformer on the +X side."""
    h, r, a = uniform(rng, 9.0, 12.0), uniform(rng, 0.11, 0.14), uniform(rng, 0.9, 1.2)
    ys = (-a + 0.1, -a / 2, a / 2, a - 0.1)
    insulators = union(*[cylinder(0.05, (0.0, y, h - 0.48), (0.0, y, h - 0.28), 8) for y in ys])
    parts = [
        part("pole", cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, h), 10), "Pole", "wood"),
        part("crossarm", box((-0.05, -a, h - 0.6), (0.05, a, h - 0.48)), "Pole", "wood"),
        part("insulators", insulators, "Pole", "plastic", color=(150, 170, 160, 255)),
    ]
    if rng.uniform() < 0.5:
        tr = cylinder(0.3, (r + 0.32, 0.0, h - 3.5), (r + 0.32, 0.0, h - 2.5), 12)
        parts.append(part("transformer", tr, "Pole", "metal"))
    return parts


def flagpole(rng: np.random.Generator) -> list[MeshPart]:
    """Flagpole, 6-10 m, with a finial no wider than the pole and a flag (class Static) flying
    along +X."""
    h, r = uniform(rng, 6.0, 10.0), uniform(rng, 0.04, 0.06)
    fw, fh = uniform(rng, 1.2, 2.0), uniform(rng, 0.8, 1.3)
    flag = box((r + 0.01, -0.01, h - 0.1 - fh), (r + 0.01 + fw, 0.01, h - 0.1))
    return [
        part("pole", cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, h), 10), "Pole", "metal"),
        part("finial", ellipsoid((0.0, 0.0, h + 0.04), (r, r, 0.08), 1), "Pole", "metal"),
        part("flag", flag, "Static", "cloth", color=pick(rng, PAINTS)),
    ]


def _signal_head(x_back: float, y: float, z_top: float, lenses: int = 3) -> tuple[Mesh, Mesh]:
    """A signal head of ``lenses`` lenses with its back at ``x_back``, centred on ``y``, top at
    ``z_top``; returns (housing, lenses) with the lenses facing +X."""
    depth, width, height = 0.25, 0.35, 0.30 * lenses + 0.05
    housing = box((x_back, y - width / 2, z_top - height), (x_back + depth, y + width / 2, z_top))
    lens_mesh = union(*[
        plate_x(0.10, 0.04, (x_back + depth + 0.02, y, z_top - 0.17 - 0.30 * k), 12, 0.0) for k in range(lenses)
    ])  # fmt: skip
    return housing, lens_mesh


def vehicle_signal(rng: np.random.Generator) -> list[MeshPart]:
    """Post-mounted vehicle signal: a 3.0-3.6 m pole with a signal head on its front (+X)."""
    h, r = uniform(rng, 3.0, 3.6), uniform(rng, 0.07, 0.09)
    housing, lenses = _signal_head(r, 0.0, h)
    return [
        part("pole", cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, h), 12), "Pole", "metal"),
        part("head", housing, "TrafficLight", "metal", color=DARK),
        part("lenses", lenses, "TrafficLight", "lens"),
    ]


def pedestrian_signal(rng: np.random.Generator) -> list[MeshPart]:
    """Pedestrian signal: a 2.3-2.8 m pole, a two-lens head on its front (+X) and a push-button
    box below it."""
    h, r = uniform(rng, 2.3, 2.8), uniform(rng, 0.06, 0.08)
    housing, lenses = _signal_head(r, 0.0, h, lenses=2)
    return [
        part("pole", cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, h), 12), "Pole", "metal"),
        part("head", housing, "TrafficLight", "metal", color=DARK),
        part("lenses", lenses, "TrafficLight", "lens", color=(230, 235, 230, 255)),
        part("button", box((r + 0.005, -0.05, 1.0), (r + 0.10, 0.05, 1.2)), "TrafficLight", "plastic",
              color=YELLOW),
    ]  # fmt: skip


def overhead_signal(rng: np.random.Generator) -> list[MeshPart]:
    """Mast-arm signal: a 5.8-6.8 m pole, an arm of 3.5-6 m reaching along -Y, a signal head
    hanging in front of the arm's end (its bottom at least 4.4 m above ground)."""
    h, arm, r = uniform(rng, 5.8, 6.8), uniform(rng, 3.5, 6.0), uniform(rng, 0.10, 0.11)
    pole = cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, h), 12)
    arm_mesh = box((-0.06, -arm, h - 0.45), (0.06, -r, h - 0.30))
    housing, lenses = _signal_head(0.06, -arm + 0.5, h - 0.45)
    return [
        part("pole", pole, "Pole", "metal"),
        part("arm", arm_mesh, "Pole", "metal"),
        part("head", housing, "TrafficLight", "metal", color=DARK),
        part("lenses", lenses, "TrafficLight", "lens"),
    ]


def sign(subclass: str) -> Builder:
    """Traffic sign on a thin pole; the plate faces +X: stop (red octagon), speed_limit (white
    disc in a red ring), no_entry (red disc, white bar), yield (triangle, point down), warning
    (triangle, point up), one_way (blue oblong, white arrow), pedestrian_crossing and parking (blue
    squares with a white symbol), direction (green or blue rectangle). Symbols and rings are parts
    of class TrafficSign just in front of (or behind) the plate."""

    def build(rng: np.random.Generator) -> list[MeshPart]:
        r = 0.045
        zc = uniform(rng, 2.3, 2.7)  # plate centre height
        x = r + 0.015 + 0.01  # plate centre: just in front of the pole
        xs = x + 0.02  # symbol centre: on the plate's face
        extra: list[tuple[str, Mesh, RGBA]] = []
        if subclass == "stop":
            plate, colour = plate_x(uniform(rng, 0.36, 0.40), 0.03, (x, 0.0, zc), 8, np.pi / 8), RED
            extra.append(("symbol", box((xs - 0.005, -0.22, zc - 0.05), (xs + 0.005, 0.22, zc + 0.05)), WHITE))
        elif subclass == "speed_limit":
            R = uniform(rng, 0.28, 0.32)
            plate, colour = plate_x(0.8 * R, 0.03, (xs - 0.005, 0.0, zc), 20, 0.0), WHITE
            extra.append(("ring", plate_x(R, 0.03, (x, 0.0, zc), 20, 0.0), RED))
        elif subclass == "no_entry":
            R = uniform(rng, 0.28, 0.32)
            plate, colour = plate_x(R, 0.03, (x, 0.0, zc), 20, 0.0), RED
            bar = box((xs - 0.005, -0.65 * R, zc - 0.1 * R), (xs + 0.005, 0.65 * R, zc + 0.1 * R))
            extra.append(("symbol", bar, WHITE))
        elif subclass in ("yield", "warning"):
            # the primitive's corner at spin 0 ends at -Z after the turn: point down for yield
            spin = 0.0 if subclass == "yield" else np.pi
            plate = plate_x(uniform(rng, 0.42, 0.48), 0.03, (x, 0.0, zc), 3, spin)
            colour = WHITE if subclass == "yield" else YELLOW
        elif subclass == "one_way":
            w, hgt = uniform(rng, 0.8, 1.0), uniform(rng, 0.25, 0.32)
            plate = box((x - 0.015, -w / 2, zc - hgt / 2), (x + 0.015, w / 2, zc + hgt / 2))
            colour = BLUE
            side = pick(rng, (-1.0, 1.0))  # the arrow points left (+Y) or right (-Y)
            y_tail, y_base, y_tip = -0.3 * w * side, (0.4 * w - 0.12) * side, 0.4 * w * side
            shaft = box((xs - 0.005, min(y_tail, y_base - 0.005 * side), zc - 0.03),
                         (xs + 0.005, max(y_tail, y_base - 0.005 * side), zc + 0.03))  # fmt: skip
            head = extrude([(y_base, -0.1), (y_tip, 0.0), (y_base, 0.1)], xs - 0.005, xs + 0.005, "x")
            extra.append(("symbol", union(shaft, shift(head, (0.0, 0.0, zc))), WHITE))
        elif subclass in ("pedestrian_crossing", "parking"):
            a = uniform(rng, 0.55, 0.65)
            plate, colour = box((x - 0.015, -a / 2, zc - a / 2), (x + 0.015, a / 2, zc + a / 2)), BLUE
            if subclass == "pedestrian_crossing":
                triangle = [(-0.3 * a, -0.25 * a), (0.3 * a, -0.25 * a), (0.0, 0.3 * a)]
                sym = extrude(triangle, xs - 0.005, xs + 0.005, "x")
                sym = shift(sym, (0.0, 0.0, zc))
            else:  # a blocky "P": stem and bowl
                sym = union(
                    box((xs - 0.005, -0.18 * a, zc - 0.3 * a), (xs + 0.005, -0.08 * a, zc + 0.3 * a)),
                    box((xs - 0.005, -0.07 * a, zc + 0.02 * a), (xs + 0.005, 0.18 * a, zc + 0.3 * a)),
                )
            extra.append(("symbol", sym, WHITE))
        else:  # direction
            w, hgt = uniform(rng, 0.6, 1.0), uniform(rng, 0.4, 0.7)
            plate = box((x - 0.015, -w / 2, zc - hgt / 2), (x + 0.015, w / 2, zc + hgt / 2))
            colour = pick(rng, (GREEN, BLUE))
        top = max([float(plate[0][:, 2].max())] + [float(m[0][:, 2].max()) for _, m, _ in extra])
        pole = cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, top - 0.05), 8)
        parts = [part("pole", pole, "Pole", "metal"), part("plate", plate, "TrafficSign", "sign_face", color=colour)]
        return parts + [part(name, mesh, "TrafficSign", "sign_face", color=c) for name, mesh, c in extra]

    return build
