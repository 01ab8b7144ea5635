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
    _BLUE, _DARK, _GREEN, _PAINTS, _RED, RGBA, _WHITE, _YELLOW, Builder, Mesh, _box, _cylinder, _ellipsoid,
    _extrude, _part, _pick, _plate_x, _shift, _u, _union,
)


def _street_light(rng: np.random.Generator) -> list[MeshPart]:
    """Street light: 7-9 m pole, an arm of 1.5-2.5 m along +X, a lamp head at its end."""
    h, arm, r = _u(rng, 7.0, 9.0), _u(rng, 1.5, 2.5), _u(rng, 0.08, 0.11)
    pole = _cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, h), 12)
    arm_mesh = _box((r, -0.04, h - 0.20), (arm, 0.04, h - 0.10))
    lamp = _box((arm, -0.15, h - 0.30), (arm + 0.6, 0.15, h - 0.08))
    return [
        _part("pole", pole, "Pole", "metal"),
        _part("arm", arm_mesh, "Pole", "metal"),
        _part("lamp", lamp, "Pole", "lamp"),
    ]


def _utility_pole(rng: np.random.Generator) -> list[MeshPart]:
    """Wooden utility pole, 9-12 m: a cross-arm near the top with four insulators, and on half of
    them a pole-mounted transformer on the +X side."""
    h, r, a = _u(rng, 9.0, 12.0), _u(rng, 0.11, 0.14), _u(rng, 0.9, 1.2)
    ys = (-a + 0.1, -a / 2, a / 2, a - 0.1)
    insulators = _union(*[_cylinder(0.05, (0.0, y, h - 0.48), (0.0, y, h - 0.28), 8) for y in ys])
    parts = [
        _part("pole", _cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, h), 10), "Pole", "wood"),
        _part("crossarm", _box((-0.05, -a, h - 0.6), (0.05, a, h - 0.48)), "Pole", "wood"),
        _part("insulators", insulators, "Pole", "plastic", color=(150, 170, 160, 255)),
    ]
    if rng.uniform() < 0.5:
        tr = _cylinder(0.3, (r + 0.32, 0.0, h - 3.5), (r + 0.32, 0.0, h - 2.5), 12)
        parts.append(_part("transformer", tr, "Pole", "metal"))
    return parts


def _flagpole(rng: np.random.Generator) -> list[MeshPart]:
    """Flagpole, 6-10 m, with a finial no wider than the pole and a flag (class Static) flying
    along +X."""
    h, r = _u(rng, 6.0, 10.0), _u(rng, 0.04, 0.06)
    fw, fh = _u(rng, 1.2, 2.0), _u(rng, 0.8, 1.3)
    flag = _box((r + 0.01, -0.01, h - 0.1 - fh), (r + 0.01 + fw, 0.01, h - 0.1))
    return [
        _part("pole", _cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, h), 10), "Pole", "metal"),
        _part("finial", _ellipsoid((0.0, 0.0, h + 0.04), (r, r, 0.08), 1), "Pole", "metal"),
        _part("flag", flag, "Static", "cloth", color=_pick(rng, _PAINTS)),
    ]


def _signal_head(x_back: float, y: float, z_top: float, lenses: int = 3) -> tuple[Mesh, Mesh]:
    """A signal head of ``lenses`` lenses with its back at ``x_back``, centred on ``y``, top at
    ``z_top``; returns (housing, lenses) with the lenses facing +X."""
    depth, width, height = 0.25, 0.35, 0.30 * lenses + 0.05
    housing = _box((x_back, y - width / 2, z_top - height), (x_back + depth, y + width / 2, z_top))
    lens_mesh = _union(*[
        _plate_x(0.10, 0.04, (x_back + depth + 0.02, y, z_top - 0.17 - 0.30 * k), 12, 0.0) for k in range(lenses)
    ])  # fmt: skip
    return housing, lens_mesh


def _vehicle_signal(rng: np.random.Generator) -> list[MeshPart]:
    """Post-mounted vehicle signal: a 3.0-3.6 m pole with a signal head on its front (+X)."""
    h, r = _u(rng, 3.0, 3.6), _u(rng, 0.07, 0.09)
    housing, lenses = _signal_head(r, 0.0, h)
    return [
        _part("pole", _cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, h), 12), "Pole", "metal"),
        _part("head", housing, "TrafficLight", "metal", color=_DARK),
        _part("lenses", lenses, "TrafficLight", "lens"),
    ]


def _pedestrian_signal(rng: np.random.Generator) -> list[MeshPart]:
    """Pedestrian signal: a 2.3-2.8 m pole, a two-lens head on its front (+X) and a push-button
    box below it."""
    h, r = _u(rng, 2.3, 2.8), _u(rng, 0.06, 0.08)
    housing, lenses = _signal_head(r, 0.0, h, lenses=2)
    return [
        _part("pole", _cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, h), 12), "Pole", "metal"),
        _part("head", housing, "TrafficLight", "metal", color=_DARK),
        _part("lenses", lenses, "TrafficLight", "lens", color=(230, 235, 230, 255)),
        _part("button", _box((r + 0.005, -0.05, 1.0), (r + 0.10, 0.05, 1.2)), "TrafficLight", "plastic",
              color=_YELLOW),
    ]  # fmt: skip


def _overhead_signal(rng: np.random.Generator) -> list[MeshPart]:
    """Mast-arm signal: a 5.8-6.8 m pole, an arm of 3.5-6 m reaching along -Y, a signal head
    hanging in front of the arm's end (its bottom at least 4.4 m above ground)."""
    h, arm, r = _u(rng, 5.8, 6.8), _u(rng, 3.5, 6.0), _u(rng, 0.10, 0.11)
    pole = _cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, h), 12)
    arm_mesh = _box((-0.06, -arm, h - 0.45), (0.06, -r, h - 0.30))
    housing, lenses = _signal_head(0.06, -arm + 0.5, h - 0.45)
    return [
        _part("pole", pole, "Pole", "metal"),
        _part("arm", arm_mesh, "Pole", "metal"),
        _part("head", housing, "TrafficLight", "metal", color=_DARK),
        _part("lenses", lenses, "TrafficLight", "lens"),
    ]


def _sign(subclass: str) -> Builder:
    """Traffic sign on a thin pole; the plate faces +X: stop (red octagon), speed_limit (white
    disc in a red ring), no_entry (red disc, white bar), yield (triangle, point down), warning
    (triangle, point up), one_way (blue oblong, white arrow), pedestrian_crossing and parking (blue
    squares with a white symbol), direction (green or blue rectangle). Symbols and rings are parts
    of class TrafficSign just in front of (or behind) the plate."""

    def build(rng: np.random.Generator) -> list[MeshPart]:
        r = 0.045
        zc = _u(rng, 2.3, 2.7)  # plate centre height
        x = r + 0.015 + 0.01  # plate centre: just in front of the pole
        xs = x + 0.02  # symbol centre: on the plate's face
        extra: list[tuple[str, Mesh, RGBA]] = []
        if subclass == "stop":
            plate, colour = _plate_x(_u(rng, 0.36, 0.40), 0.03, (x, 0.0, zc), 8, np.pi / 8), _RED
            extra.append(("symbol", _box((xs - 0.005, -0.22, zc - 0.05), (xs + 0.005, 0.22, zc + 0.05)), _WHITE))
        elif subclass == "speed_limit":
            R = _u(rng, 0.28, 0.32)
            plate, colour = _plate_x(0.8 * R, 0.03, (xs - 0.005, 0.0, zc), 20, 0.0), _WHITE
            extra.append(("ring", _plate_x(R, 0.03, (x, 0.0, zc), 20, 0.0), _RED))
        elif subclass == "no_entry":
            R = _u(rng, 0.28, 0.32)
            plate, colour = _plate_x(R, 0.03, (x, 0.0, zc), 20, 0.0), _RED
            bar = _box((xs - 0.005, -0.65 * R, zc - 0.1 * R), (xs + 0.005, 0.65 * R, zc + 0.1 * R))
            extra.append(("symbol", bar, _WHITE))
        elif subclass in ("yield", "warning"):
            # the primitive's corner at spin 0 ends at -Z after the turn: point down for yield
            spin = 0.0 if subclass == "yield" else np.pi
            plate = _plate_x(_u(rng, 0.42, 0.48), 0.03, (x, 0.0, zc), 3, spin)
            colour = _WHITE if subclass == "yield" else _YELLOW
        elif subclass == "one_way":
            w, hgt = _u(rng, 0.8, 1.0), _u(rng, 0.25, 0.32)
            plate = _box((x - 0.015, -w / 2, zc - hgt / 2), (x + 0.015, w / 2, zc + hgt / 2))
            colour = _BLUE
            side = _pick(rng, (-1.0, 1.0))  # the arrow points left (+Y) or right (-Y)
            y_tail, y_base, y_tip = -0.3 * w * side, (0.4 * w - 0.12) * side, 0.4 * w * side
            shaft = _box((xs - 0.005, min(y_tail, y_base - 0.005 * side), zc - 0.03),
                         (xs + 0.005, max(y_tail, y_base - 0.005 * side), zc + 0.03))  # fmt: skip
            head = _extrude([(y_base, -0.1), (y_tip, 0.0), (y_base, 0.1)], xs - 0.005, xs + 0.005, "x")
            extra.append(("symbol", _union(shaft, _shift(head, (0.0, 0.0, zc))), _WHITE))
        elif subclass in ("pedestrian_crossing", "parking"):
            a = _u(rng, 0.55, 0.65)
            plate, colour = _box((x - 0.015, -a / 2, zc - a / 2), (x + 0.015, a / 2, zc + a / 2)), _BLUE
            if subclass == "pedestrian_crossing":
                triangle = [(-0.3 * a, -0.25 * a), (0.3 * a, -0.25 * a), (0.0, 0.3 * a)]
                sym = _extrude(triangle, xs - 0.005, xs + 0.005, "x")
                sym = _shift(sym, (0.0, 0.0, zc))
            else:  # a blocky "P": stem and bowl
                sym = _union(
                    _box((xs - 0.005, -0.18 * a, zc - 0.3 * a), (xs + 0.005, -0.08 * a, zc + 0.3 * a)),
                    _box((xs - 0.005, -0.07 * a, zc + 0.02 * a), (xs + 0.005, 0.18 * a, zc + 0.3 * a)),
                )
            extra.append(("symbol", sym, _WHITE))
        else:  # direction
            w, hgt = _u(rng, 0.6, 1.0), _u(rng, 0.4, 0.7)
            plate = _box((x - 0.015, -w / 2, zc - hgt / 2), (x + 0.015, w / 2, zc + hgt / 2))
            colour = _pick(rng, (_GREEN, _BLUE))
        top = max([float(plate[0][:, 2].max())] + [float(m[0][:, 2].max()) for _, m, _ in extra])
        pole = _cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, top - 0.05), 8)
        parts = [_part("pole", pole, "Pole", "metal"), _part("plate", plate, "TrafficSign", "sign_face", color=colour)]
        return parts + [_part(name, mesh, "TrafficSign", "sign_face", color=c) for name, mesh, c in extra]

    return build
