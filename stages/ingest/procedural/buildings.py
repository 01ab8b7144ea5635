"""Procedural buildings (class Building): houses, residential and apartment blocks, offices and
towers, commercial and industrial halls, warehouses, garages, gas stations, religious and public
buildings.

Asset frame: metres, Z up; the entrance facade faces +X, ``extent[0]`` is the depth and
``extent[1]`` the frontage. Glazing is transparent glass parts half sunk into the walls.
"""

from __future__ import annotations

import numpy as np

from carlaocc.schemas.meshes import MeshPart
from carlaocc.stages.ingest.procedural.primitives import (
    BLUE, COLOURS, DARK, FACADES, GREEN, PAINTS, RED, WHITE, YELLOW, Mesh, box, cone, cylinder,
    ellipsoid, extrude, frustum, glass_part, part, pick, prism_gable, pyramid, shift, uniform, union,
)


def _windows_on_facades(
    D: float, F: float, rows: list[tuple[float, float]], spans: dict[str, list[tuple[float, float]]]
) -> Mesh:
    """Glass panes straddling the walls of a ``D`` (x) by ``F`` (y) block: for every ``(z0, z1)``
    row and every facade (``"front"`` +X, ``"back"`` -X, ``"left"`` +Y, ``"right"`` -Y), one pane
    per ``(a, b)`` span along that facade (y spans on front/back, x spans on the sides).
    Panes are 0.10 m thick, half inside the wall, and never touch each other."""
    t = 0.05
    panes: list[Mesh] = []
    for z0, z1 in rows:
        for facade, facade_spans in spans.items():
            for a, b in facade_spans:
                if facade in ("front", "back"):
                    x = D / 2 if facade == "front" else -D / 2
                    panes.append(box((x - t, a, z0), (x + t, b, z1)))
                else:
                    y = F / 2 if facade == "left" else -F / 2
                    panes.append(box((a, y - t, z0), (b, y + t, z1)))
    return union(*panes)


def _bays(lo: float, hi: float, n: int, width: float) -> list[tuple[float, float]]:
    """``n`` spans of ``width`` centred in ``n`` equal bays between ``lo`` and ``hi``."""
    step = (hi - lo) / n
    return [(lo + (k + 0.5) * step - width / 2, lo + (k + 0.5) * step + width / 2) for k in range(n)]


_ROOF_COLOURS = ((120, 50, 40, 255), (70, 72, 80, 255), (150, 95, 60, 255), (95, 45, 35, 255))


def house(rng: np.random.Generator) -> list[MeshPart]:
    """Detached house, 1-2 storeys, gable or hip roof, door on the +X facade, 4-9 m wide windows."""
    D, F = uniform(rng, 8.0, 12.0), uniform(rng, 9.0, 14.0)
    storeys = int(rng.integers(1, 3))
    wall_h = 2.9 * storeys + 0.3
    roof_h = uniform(rng, 1.8, 3.5)
    eave = 0.35
    walls = box((-D / 2, -F / 2, 0.0), (D / 2, F / 2, wall_h))
    roof_lo, roof_hi = (-D / 2 - eave, -F / 2 - eave, wall_h), (D / 2 + eave, F / 2 + eave, wall_h + roof_h)
    if rng.uniform() < 0.5:
        roof = prism_gable(roof_lo, roof_hi)
    else:
        ridge = 0.15 + 0.25 * F  # hip roof: the top face shrinks to a short ridge along Y
        roof = frustum(roof_lo, roof_hi, (-0.08, -ridge / 2), (0.08, ridge / 2))
    rows = [(0.9 + 2.9 * k, 2.2 + 2.9 * k) for k in range(storeys)]
    ys = [(-F / 4 - 0.6, -F / 4 + 0.6), (F / 4 - 0.6, F / 4 + 0.6)]
    xs = [(-0.6, 0.6)]
    glazing = _windows_on_facades(D, F, rows, {"front": ys, "back": ys, "left": xs, "right": xs})
    door = box((D / 2 - 0.06, -0.45, 0.0), (D / 2 + 0.06, 0.45, 2.1))
    return [
        part("walls", walls, "Building", "plaster", color=pick(rng, FACADES["plaster"])),
        part("roof", roof, "Building", "roof_tile", color=pick(rng, _ROOF_COLOURS)),
        glass_part("glazing", glazing, "Building"),
        part("door", door, "Building", "wood"),
    ]


def residential(rng: np.random.Generator) -> list[MeshPart]:
    """Apartment block, 3-8 floors of 3 m, ribbon windows on every facade and floor, an entrance
    on the +X facade and a plant room on the flat roof."""
    D, F = uniform(rng, 10.0, 16.0), uniform(rng, 16.0, 30.0)
    floors = int(rng.integers(3, 9))
    H = 3.0 * floors + 0.4
    walls = box((-D / 2, -F / 2, 0.0), (D / 2, F / 2, H))
    rows = [(3.0 * k + 0.9, 3.0 * k + 2.3) for k in range(1, floors)]
    along_y = [(-F / 2 + 0.6, F / 2 - 0.6)]
    along_x = [(-D / 2 + 0.6, D / 2 - 0.6)]
    glazing = _windows_on_facades(D, F, rows, {"front": along_y, "back": along_y, "left": along_x, "right": along_x})
    # ground floor: shop windows beside the entrance at the front, ribbons on the other facades
    ground = _windows_on_facades(
        D, F, [(0.5, 2.5)],
        {"front": [(-F / 2 + 0.6, -1.2), (1.2, F / 2 - 0.6)], "back": along_y, "left": along_x, "right": along_x},
    )  # fmt: skip
    door = box((D / 2 - 0.06, -0.9, 0.0), (D / 2 + 0.06, 0.9, 2.4))
    plant = box((-D / 4, -F / 6, H), (D / 4, F / 6, H + uniform(rng, 1.5, 2.5)))
    return [
        part("walls", walls, "Building", "brick", color=pick(rng, FACADES["brick"])),
        glass_part("glazing", union(glazing, ground), "Building"),
        glass_part("entrance", door, "Building"),
        part("roof_plant", plant, "Building", "concrete"),
    ]


def apartment(rng: np.random.Generator) -> list[MeshPart]:
    """Apartment slab, 4-10 floors of 2.9 m: vertical window strips in 4 m bays on every facade,
    balconies with glass railings on every upper floor of the +X facade, a glazed entrance and a
    ground floor of windows on the front."""
    D, F = uniform(rng, 12.0, 18.0), uniform(rng, 18.0, 36.0)
    floors, fh = int(rng.integers(4, 11)), 2.9
    H = fh * floors + 0.6
    nb, ns = max(2, int(F // 4.0)), max(1, int(D // 4.0))
    ys, xs = _bays(-F / 2, F / 2, nb, 1.4), _bays(-D / 2, D / 2, ns, 1.4)
    strips = _windows_on_facades(D, F, [(fh + 0.8, H - 1.2)], {"front": ys, "back": ys, "left": xs, "right": xs})
    ground = _windows_on_facades(D, F, [(0.8, 2.2)], {"front": [s for s in ys if min(abs(s[0]), abs(s[1])) > 1.4]})
    slabs, rails = [], []
    for k in range(1, floors):
        z = fh * k
        slabs.append(box((D / 2 + 0.06, -F / 2 + 1.0, z - 0.15), (D / 2 + 1.3, F / 2 - 1.0, z)))
        rails.append(box((D / 2 + 1.24, -F / 2 + 1.0, z + 0.01), (D / 2 + 1.30, F / 2 - 1.0, z + 1.0)))
    door = box((D / 2 - 0.06, -1.0, 0.0), (D / 2 + 0.06, 1.0, 2.4))
    plant = box((-D / 4, -F / 8, H), (D / 4, F / 8, H + uniform(rng, 1.5, 2.5)))
    return [
        part("walls", box((-D / 2, -F / 2, 0.0), (D / 2, F / 2, H)), "Building", "plaster",
              color=pick(rng, FACADES["plaster"])),
        glass_part("glazing", union(strips, ground), "Building"),
        glass_part("entrance", door, "Building"),
        part("balconies", union(*slabs), "Building", "concrete"),
        glass_part("balcony_railings", union(*rails), "Building"),
        part("roof_plant", plant, "Building", "concrete"),
    ]  # fmt: skip


def _curtain_block(D: float, F: float, z0: float, z1: float, t: float = 0.15) -> tuple[Mesh, Mesh]:
    """A glass-clad block: a core inset by ``t`` and four ``t`` thick curtain walls around it (the
    front/back walls span the full frontage, the sides fit between them), from ``z0`` to ``z1``."""
    core = box((-D / 2 + t, -F / 2 + t, z0), (D / 2 - t, F / 2 - t, z1))
    curtain = union(
        box((D / 2 - t, -F / 2, z0), (D / 2, F / 2, z1)),
        box((-D / 2, -F / 2, z0), (-D / 2 + t, F / 2, z1)),
        box((-D / 2 + t, F / 2 - t, z0), (D / 2 - t, F / 2, z1)),
        box((-D / 2 + t, -F / 2, z0), (D / 2 - t, -F / 2 + t, z1)),
    )
    return core, curtain


def office(rng: np.random.Generator) -> list[MeshPart]:
    """Office tower, 8-13 floors of 3.6 m over a 4.5 m lobby: a concrete core, a glass curtain
    wall on every facade, floor-slab edges projecting 0.15 m at every floor, a roof plant room."""
    D, F = uniform(rng, 18.0, 28.0), uniform(rng, 18.0, 30.0)
    floors = int(rng.integers(8, 14))
    lobby = 4.5
    H = lobby + 3.6 * floors
    core, _ = _curtain_block(D, F, 0.0, H)
    _, curtain = _curtain_block(D, F, 0.0, H - 0.6)
    slabs = union(*[
        box((-D / 2 - 0.15, -F / 2 - 0.15, z - 0.3), (D / 2 + 0.15, F / 2 + 0.15, z))
        for z in [lobby + 3.6 * k for k in range(floors)]
    ] + [box((-D / 2 - 0.15, -F / 2 - 0.15, H - 0.6), (D / 2 + 0.15, F / 2 + 0.15, H))])  # fmt: skip
    plant = box((-D / 5, -F / 5, H), (D / 5, F / 5, H + uniform(rng, 2.5, 4.0)))
    return [
        part("core", core, "Building", "concrete"),
        glass_part("curtain_wall", curtain, "Building"),
        part("floor_slabs", slabs, "Building", "concrete"),
        part("roof_plant", plant, "Building", "concrete"),
    ]


def tower(rng: np.random.Generator) -> list[MeshPart]:
    """High-rise, 18-31 floors of 3.7 m over a 5 m lobby (75-125 m): a glass-clad shaft, a narrower
    glass-clad top of 3-6 floors set back above it, slab bands every third floor, a crown and,
    on half of them, an antenna mast."""
    D, F = uniform(rng, 22.0, 34.0), uniform(rng, 22.0, 34.0)
    floors, n_up, fh, lobby = int(rng.integers(18, 32)), int(rng.integers(3, 7)), 3.7, 5.0
    s = uniform(rng, 0.6, 0.8)
    H_mid, H1 = lobby + fh * (floors - n_up), lobby + fh * floors
    d, f = D * s, F * s
    core_lo, curtain_lo = _curtain_block(D, F, 0.0, H_mid)
    core_up, curtain_up = _curtain_block(d, f, H_mid + 0.01, H1)
    bands = [box((-D / 2 - 0.15, -F / 2 - 0.15, z - 0.3), (D / 2 + 0.15, F / 2 + 0.15, z))
             for z in np.arange(lobby, H_mid - 0.5, 3 * fh)]  # fmt: skip
    bands.append(box((-D / 2 - 0.15, -F / 2 - 0.15, H_mid - 0.3), (D / 2 + 0.15, F / 2 + 0.15, H_mid)))
    bands.append(box((-d / 2 - 0.15, -f / 2 - 0.15, H1 - 0.3), (d / 2 + 0.15, f / 2 + 0.15, H1)))
    crown_top = H1 + uniform(rng, 3.0, 6.0)
    parts = [
        part("core", union(core_lo, core_up), "Building", "concrete"),
        glass_part("curtain_wall", union(curtain_lo, curtain_up), "Building"),
        part("floor_bands", union(*bands), "Building", "concrete"),
        part("crown", box((-d * 0.35, -f * 0.35, H1), (d * 0.35, f * 0.35, crown_top)), "Building", "concrete"),
    ]
    if rng.uniform() < 0.5:
        mast = cylinder(0.3, (0.0, 0.0, crown_top), (0.0, 0.0, crown_top + uniform(rng, 6.0, 15.0)), 8)
        parts.append(part("antenna", mast, "Building", "metal"))
    return parts


def commercial(rng: np.random.Generator) -> list[MeshPart]:
    """Retail building, 1-2 storeys: shop windows either side of a glazed entrance on the +X
    facade, a canopy and a sign band above them, ribbon windows upstairs, roof-top units."""
    D, F = uniform(rng, 14.0, 24.0), uniform(rng, 20.0, 40.0)
    storeys = int(rng.integers(1, 3))
    H = 4.6 + 3.8 * (storeys - 1) + 0.6
    material = pick(rng, ("plaster", "brick", "concrete"))
    shop = _windows_on_facades(D, F, [(0.3, 3.4)], {"front": [(-F / 2 + 0.8, -1.9), (1.9, F / 2 - 0.8)]})
    glazing = [shop]
    if storeys == 2:
        glazing.append(_windows_on_facades(D, F, [(5.4, 7.2)], {
            "front": [(-F / 2 + 0.8, F / 2 - 0.8)], "back": [(-F / 2 + 0.8, F / 2 - 0.8)],
            "left": [(-D / 2 + 0.8, D / 2 - 0.8)], "right": [(-D / 2 + 0.8, D / 2 - 0.8)],
        }))  # fmt: skip
    n = int(rng.integers(1, 4))
    centres = [-F / 2 + (k + 1) * F / (n + 1) for k in range(n)]
    units = [box((-2.0, yc - 1.2, H), (1.0, yc + 1.2, H + 1.5)) for yc in centres]
    return [
        part("walls", box((-D / 2, -F / 2, 0.0), (D / 2, F / 2, H)), "Building", material,
              color=pick(rng, FACADES[material])),
        glass_part("glazing", union(*glazing), "Building"),
        glass_part("entrance", box((D / 2 - 0.06, -1.6, 0.0), (D / 2 + 0.06, 1.6, 3.0)), "Building"),
        part("canopy", box((D / 2 + 0.06, -F / 2 + 0.5, 3.55), (D / 2 + 1.8, F / 2 - 0.5, 3.75)), "Building", "metal",
              color=pick(rng, PAINTS)),
        part("sign_band", box((D / 2 - 0.02, -F * 0.3, 3.85), (D / 2 + 0.2, F * 0.3, 4.45)), "Building", "sign_face",
              color=pick(rng, PAINTS)),
        part("roof_units", union(*units), "Building", "metal"),
    ]  # fmt: skip


def industrial(rng: np.random.Generator) -> list[MeshPart]:
    """Factory hall with a north-light sawtooth roof (glazed vertical faces), high ribbon
    windows, 1-3 loading doors on the +X facade and a brick chimney."""
    D, F, wall_h = uniform(rng, 25.0, 45.0), uniform(rng, 20.0, 40.0), uniform(rng, 6.5, 9.5)
    material = pick(rng, ("concrete", "metal"))
    n = max(3, int(D // 8.0))
    d, th = D / n, uniform(rng, 2.5, 3.5)
    x0s = [-D / 2 + k * d for k in range(n)]
    teeth = union(*[extrude([(x0, wall_h), (x0 + d - 0.01, wall_h), (x0, wall_h + th)], -F / 2, F / 2) for x0 in x0s])
    roof_glass = union(*[box((x0 - 0.05, -F / 2 + 0.5, wall_h + 0.3), (x0 + 0.05, F / 2 - 0.5, wall_h + th - 0.3))
                          for x0 in x0s])  # fmt: skip
    ribbons = _windows_on_facades(D, F, [(wall_h - 2.6, wall_h - 1.2)], {
        "front": [(-F / 2 + 1.0, -F / 4), (F / 4, F / 2 - 1.0)],
        "left": [(-D / 2 + 1.0, D / 2 - 1.0)], "right": [(-D / 2 + 1.0, D / 2 - 1.0)],
    })  # fmt: skip
    nd = int(rng.integers(1, 4))
    w = min(4.0, F / 2 / nd - 0.4)
    doors = union(*[box((D / 2 - 0.05, a, 0.0), (D / 2 + 0.08, b, 4.5)) for a, b in _bays(-F / 4, F / 4, nd, w)])
    chimney_r, chimney_h = uniform(rng, 0.6, 1.0), uniform(rng, 14.0, 22.0)
    chimney = cylinder(chimney_r, (-D / 2 + 3.0, F / 2 - 3.0, 0.0), (-D / 2 + 3.0, F / 2 - 3.0, chimney_h))
    return [
        part("walls", box((-D / 2, -F / 2, 0.0), (D / 2, F / 2, wall_h)), "Building", material,
              color=pick(rng, FACADES[material])),
        part("sawtooth_roof", teeth, "Building", "metal", color=(110, 115, 120, 255)),
        glass_part("glazing", union(roof_glass, ribbons), "Building"),
        glass_part("entrance", box((D / 2 - 0.06, F / 2 - 4.0, 0.0), (D / 2 + 0.06, F / 2 - 2.5, 2.4)), "Building"),
        part("loading_doors", doors, "Building", "metal", color=DARK),
        part("chimney", chimney, "Building", "brick"),
    ]  # fmt: skip


def warehouse(rng: np.random.Generator) -> list[MeshPart]:
    """Logistics warehouse: a long clad box under a low-pitched roof, a loading dock along the +X
    facade with 2-5 roller doors, high ribbon windows on the other facades."""
    D, F, wall_h = uniform(rng, 30.0, 60.0), uniform(rng, 20.0, 40.0), uniform(rng, 7.0, 11.0)
    pitch = np.tan(np.radians(uniform(rng, 4.0, 8.0)))
    roof = extrude([(-F / 2 - 0.3, wall_h), (F / 2 + 0.3, wall_h), (0.0, wall_h + (F / 2 + 0.3) * pitch)],
                    -D / 2 - 0.3, D / 2 + 0.3, "x")  # fmt: skip
    nd = int(rng.integers(2, 6))
    spacing = (F - 4.0) / nd
    doors = union(*[box((D / 2 - 0.04, a, 1.21), (D / 2 + 0.06, b, 5.2))
                     for a, b in _bays(-F / 2 + 2.0, F / 2 - 2.0, nd, min(3.5, spacing - 0.8))])  # fmt: skip
    along_y, along_x = [(-F / 2 + 1.0, F / 2 - 1.0)], [(-D / 2 + 1.0, D / 2 - 1.0)]
    high = [(wall_h - 1.8, wall_h - 0.8)]
    ribbons = _windows_on_facades(D, F, high, {"back": along_y, "left": along_x, "right": along_x})
    return [
        part("walls", box((-D / 2, -F / 2, 0.0), (D / 2, F / 2, wall_h)), "Building", "metal",
              color=pick(rng, FACADES["metal"])),
        part("roof", roof, "Building", "metal", color=(95, 100, 105, 255)),
        part("dock", box((D / 2 + 0.01, -F / 2 + 1.0, 0.0), (D / 2 + 2.5, F / 2 - 1.0, 1.2)), "Building", "concrete"),
        part("roller_doors", doors, "Building", "metal", color=DARK),
        glass_part("glazing", ribbons, "Building"),
        glass_part("entrance", box((D / 2 - 4.0, F / 2 - 0.06, 0.0), (D / 2 - 2.5, F / 2 + 0.06, 2.4)), "Building"),
    ]  # fmt: skip


def garage(rng: np.random.Generator) -> list[MeshPart]:
    """Detached single or double garage under a mono-pitch roof: up-and-over doors on the +X
    facade, a small side window."""
    D = uniform(rng, 5.5, 7.0)
    bays = 2 if rng.uniform() < 0.5 else 1
    F = uniform(rng, 5.8, 6.6) if bays == 2 else uniform(rng, 3.0, 3.6)
    Hf = uniform(rng, 2.4, 2.7)
    roof = extrude([(-D / 2 - 0.2, Hf), (D / 2 + 0.3, Hf), (D / 2 + 0.3, Hf + 0.15), (-D / 2 - 0.2, Hf + 0.5)],
                    -F / 2 - 0.2, F / 2 + 0.2)  # fmt: skip
    spans = _bays(-F / 2, F / 2, bays, F / bays - 0.7)
    doors = union(*[box((D / 2 - 0.04, a, 0.0), (D / 2 + 0.05, b, 2.1)) for a, b in spans])
    material = pick(rng, ("plaster", "brick"))
    return [
        part("walls", box((-D / 2, -F / 2, 0.0), (D / 2, F / 2, Hf)), "Building", material,
              color=pick(rng, FACADES[material])),
        part("roof", roof, "Building", "roof_tile", color=pick(rng, _ROOF_COLOURS)),
        part("doors", doors, "Building", "metal", color=pick(rng, (WHITE, DARK, (120, 80, 50, 255)))),
        glass_part("glazing", box((-0.5, F / 2 - 0.05, 1.2), (0.5, F / 2 + 0.05, 1.8)), "Building"),
    ]  # fmt: skip


def gas_station(rng: np.random.Generator) -> list[MeshPart]:
    """Filling station: a shop with a glazed front at the back, a canopy on columns over 2-3 pump
    islands in front of it (+X), a price pylon at the front corner."""
    Ds, Fs, Hs = uniform(rng, 8.0, 12.0), uniform(rng, 10.0, 16.0), uniform(rng, 3.8, 4.5)
    Dc, Fc, Hc = uniform(rng, 10.0, 14.0), uniform(rng, 14.0, 22.0), uniform(rng, 4.8, 5.5)
    x0 = Ds + uniform(rng, 3.0, 5.0)  # the canopy's back edge (the shop spans x 0 .. Ds)
    colour = pick(rng, (RED, BLUE, GREEN, YELLOW))
    shop_front = {"front": [(-Fs / 2 + 0.6, -1.2), (1.2, Fs / 2 - 0.6)]}
    shop_glass = shift(_windows_on_facades(Ds, Fs, [(0.4, 2.8)], shop_front), (Ds / 2, 0.0, 0.0))
    n_isl = 3 if Fc > 18.0 else 2
    ys = [-Fc / 2 + (k + 0.5) * Fc / n_isl for k in range(n_isl)]
    islands = union(*[box((x0 + 2.0, y - 0.6, 0.0), (x0 + Dc - 2.0, y + 0.6, 0.15)) for y in ys])
    xs = (x0 + 2.4, x0 + Dc - 2.4)
    columns = union(*[cylinder(0.25, (x, y, 0.16), (x, y, Hc - 0.01), 12) for y in ys for x in xs])
    pumps = union(*[box((x0 + Dc / 2 - 0.3, y - 0.45, 0.16), (x0 + Dc / 2 + 0.3, y + 0.45, 1.9)) for y in ys])
    pylon = box((x0 + Dc + 1.0, Fc / 2 - 2.0, 0.0), (x0 + Dc + 1.4, Fc / 2, uniform(rng, 6.0, 8.0)))
    return [
        part("shop", box((0.0, -Fs / 2, 0.0), (Ds, Fs / 2, Hs)), "Building", "plaster",
              color=pick(rng, FACADES["plaster"])),
        glass_part("glazing", shop_glass, "Building"),
        glass_part("entrance", box((Ds - 0.06, -1.0, 0.0), (Ds + 0.06, 1.0, 2.5)), "Building"),
        part("canopy", box((x0, -Fc / 2, Hc), (x0 + Dc, Fc / 2, Hc + 0.9)), "Building", "metal", color=WHITE),
        part("columns", columns, "Building", "metal", color=colour),
        part("islands", islands, "Building", "concrete"),
        part("pumps", pumps, "Building", "metal", color=colour),
        part("price_sign", pylon, "Building", "sign_face", color=colour),
    ]  # fmt: skip


def religious(rng: np.random.Generator) -> list[MeshPart]:
    """Place of worship, one of two styles: a church (nave under a steep roof with tall windows, a
    west tower with a spire and the door on its +X face) or a domed hall (a drum and dome on a
    square hall, a slender tower with a conical cap beside it)."""
    stone = pick(rng, ((190, 180, 160, 255), (200, 195, 185, 255), (165, 150, 130, 255), (210, 200, 175, 255)))
    if rng.uniform() < 0.6:
        D, Fw, wall_h = uniform(rng, 20.0, 32.0), uniform(rng, 10.0, 15.0), uniform(rng, 7.0, 10.0)
        T, Ht = uniform(rng, 4.5, 6.5), uniform(rng, 18.0, 28.0)
        gable = [(-Fw / 2 - 0.4, wall_h), (Fw / 2 + 0.4, wall_h), (0.0, wall_h + 0.6 * Fw)]
        roof = extrude(gable, -D / 2 - 0.3, D / 2 + 0.3, "x")  # ridge along X
        bays = _bays(-D / 2, D / 2, int(D // 4.0), 1.2)
        nave_glass = _windows_on_facades(D, Fw, [(2.5, wall_h - 1.0)], {"left": bays, "right": bays})
        xt = D / 2 + T / 2
        belfry = union(
            box((D / 2 + T - 0.05, -0.6, Ht - 4.0), (D / 2 + T + 0.05, 0.6, Ht - 1.5)),
            *[box((xt - 0.6, sy * T / 2 - 0.05, Ht - 4.0), (xt + 0.6, sy * T / 2 + 0.05, Ht - 1.5))
              for sy in (-1.0, 1.0)],
        )  # fmt: skip
        return [
            part("nave", box((-D / 2, -Fw / 2, 0.0), (D / 2, Fw / 2, wall_h)), "Building", "stone", color=stone),
            part("roof", roof, "Building", "roof_tile", color=(70, 75, 85, 255)),
            part("tower", box((D / 2, -T / 2, 0.0), (D / 2 + T, T / 2, Ht)), "Building", "stone", color=stone),
            part("spire", pyramid(T / 2 + 0.2, uniform(rng, 8.0, 14.0), (xt, 0.0, Ht)), "Building", "roof_tile",
                  color=(70, 75, 85, 255)),
            glass_part("glazing", union(nave_glass, belfry), "Building"),
            part("door", box((D / 2 + T - 0.06, -1.0, 0.0), (D / 2 + T + 0.06, 1.0, 3.6)), "Building", "wood"),
        ]  # fmt: skip
    D = uniform(rng, 16.0, 26.0)
    F, wall_h = D * uniform(rng, 0.9, 1.1), uniform(rng, 8.0, 12.0)
    r = 0.3 * min(D, F)
    drum_top = wall_h + uniform(rng, 2.0, 4.0)
    yt, Ht = F / 2 + 2.0, uniform(rng, 20.0, 30.0)
    glass = _windows_on_facades(D, F, [(3.0, wall_h - 2.0)], {
        "front": [(-F / 3 - 0.75, -F / 3 + 0.75), (F / 3 - 0.75, F / 3 + 0.75)], "back": _bays(-F / 2, F / 2, 3, 1.5),
        "left": _bays(-D / 2, D / 2, 3, 1.5), "right": _bays(-D / 2, D / 2, 3, 1.5),
    })  # fmt: skip
    return [
        part("hall", box((-D / 2, -F / 2, 0.0), (D / 2, F / 2, wall_h)), "Building", "stone", color=stone),
        part("drum", cylinder(r, (0.0, 0.0, wall_h), (0.0, 0.0, drum_top), 16), "Building", "stone", color=stone),
        part("dome", ellipsoid((0.0, 0.0, drum_top), (r, r, r * uniform(rng, 0.8, 1.1)), 2), "Building", "metal",
              color=pick(rng, ((60, 120, 110, 255), (200, 170, 80, 255), (90, 100, 140, 255)))),
        part("tower", cylinder(1.2, (D / 2 - 2.0, yt, 0.0), (D / 2 - 2.0, yt, Ht), 12), "Building", "stone",
              color=stone),
        part("tower_cap", cone(1.5, 3.0, (D / 2 - 2.0, yt, Ht), 12), "Building", "metal"),
        glass_part("glazing", glass, "Building"),
        part("door", box((D / 2 - 0.06, -1.2, 0.0), (D / 2 + 0.06, 1.2, 4.0)), "Building", "wood"),
    ]  # fmt: skip


def public(rng: np.random.Generator) -> list[MeshPart]:
    """Civic building (town hall, school, library), 2-3 storeys of 3.8 m: ribbon windows, a
    columned portico with steps, an entablature and a pediment in front of the +X entrance."""
    D, F = uniform(rng, 14.0, 22.0), uniform(rng, 30.0, 50.0)
    floors, fh = int(rng.integers(2, 4)), 3.8
    H = fh * floors + 0.8
    n_col = int(rng.integers(4, 7))
    Wp = (n_col - 1) * 2.6
    material = pick(rng, ("stone", "plaster"))
    colour = pick(rng, FACADES["plaster"]) if material == "plaster" else COLOURS["stone"]
    rows = [(fh * k + 1.0, fh * k + 2.8) for k in range(floors)]
    glazing = _windows_on_facades(D, F, rows, {
        "front": [(-F / 2 + 1.0, -Wp / 2 - 1.7), (Wp / 2 + 1.7, F / 2 - 1.0)], "back": [(-F / 2 + 1.0, F / 2 - 1.0)],
        "left": [(-D / 2 + 1.0, D / 2 - 1.0)], "right": [(-D / 2 + 1.0, D / 2 - 1.0)],
    })  # fmt: skip
    xc = D / 2 + 2.2
    columns = union(*[cylinder(0.35, (xc, -Wp / 2 + 2.6 * k, 1.01), (xc, -Wp / 2 + 2.6 * k, H - 1.61), 12)
                       for k in range(n_col)])  # fmt: skip
    half = Wp / 2 + 1.2
    entablature = box((D / 2, -half, H - 1.6), (D / 2 + 2.8, half, H - 0.9))
    gable = [(-half, H - 0.89), (half, H - 0.89), (0.0, H - 0.89 + uniform(rng, 1.5, 2.2))]
    pediment = extrude(gable, D / 2 - 0.2, D / 2 + 2.8, "x")
    return [
        part("walls", box((-D / 2, -F / 2, 0.0), (D / 2, F / 2, H)), "Building", material, color=colour),
        glass_part("glazing", glazing, "Building"),
        glass_part("entrance", box((D / 2 - 0.06, -1.3, 1.0), (D / 2 + 0.06, 1.3, 4.2)), "Building"),
        part("steps", box((D / 2, -Wp / 2 - 1.5, 0.0), (D / 2 + 3.8, Wp / 2 + 1.5, 1.0)), "Building", "concrete"),
        part("columns", columns, "Building", "stone"),
        part("portico_roof", union(entablature, pediment), "Building", "stone", color=colour),
    ]
