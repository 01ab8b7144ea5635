"""Generator of catalog/towns/hills.xodr, the builtin OpenDRIVE town with slopes and banks (original
work of carlaocc, CC0-1.0).

A closed circuit of four roads linked road to road (no junction), each with two 3.5 m driving
lanes per direction and a 3 m sidewalk per side:

* road 1 "Hill": 160 m straight over a crest ``HILL`` m high (smoothstep up, then down: grades up
  to 1.5 * HILL / 80, 15 % for 8 m);
* road 2 "East Bank": a 180-degree left arc of radius ``RADIUS`` m, banked by ``BANK`` rad (the
  outside, on the right of +s, is higher: negative superelevation), ramped in and out over
  ``RAMP`` m;
* road 3 "Valley": 160 m straight back west through a sag ``DIP`` m deep;
* road 4 "West Bank": the second banked half circle, closing the loop at the origin.

Usage: ``python tools/make_hills.py catalog/towns/hills.xodr``. Deterministic: the same file
every run (the shipped one is this script's output).
"""

from __future__ import annotations

import math
import sys

W, SW = 3.5, 3.0  # m: driving lane, sidewalk width
LANES = 2  # driving lanes per direction
STRAIGHT = 160.0  # m
RADIUS = 45.0  # m, centre line of the banked half circles
HILL, DIP = 8.0, -3.0  # m: crest of road 1, sag of road 3
BANK, RAMP = -0.12, 30.0  # rad of superelevation on the curves (about 6.9 degrees), m to reach it


def num(v: float) -> str:
    return repr(float(v))


def smooth_bump(length: float, height: float) -> list[tuple[float, float, float, float, float]]:
    """Elevation records (s, a, b, c, d) rising by ``height`` over the first half (a cubic with
    zero slope at both ends) and falling back over the second."""
    m = length / 2
    c, d = 3 * height / m**2, -2 * height / m**3
    return [(0.0, 0.0, 0.0, c, d), (m, height, 0.0, -c, -d)]


def bank_profile(length: float, bank: float, ramp: float) -> list[tuple[float, float, float, float, float]]:
    """Superelevation records (s, a, b, c, d): 0 -> ``bank`` over ``ramp`` m (cubic, zero slope at
    both ends), constant, then back to 0 over the last ``ramp`` m."""
    c, d = 3 * bank / ramp**2, -2 * bank / ramp**3
    return [(0.0, 0.0, 0.0, c, d), (ramp, bank, 0.0, 0.0, 0.0), (length - ramp, bank, 0.0, -c, -d)]


def polys(tag: str, records, s_name: str = "s") -> str:
    """OpenDRIVE cubic records ``<tag s=.. a=.. b=.. c=.. d=..>`` (``s_name``: ``sOffset`` for
    lane widths) from (s, a, b, c, d) tuples."""
    return "".join(f'<{tag} {s_name}="{num(s)}" a="{num(a)}" b="{num(b)}" c="{num(c)}" d="{num(d)}"/>'
                   for s, a, b, c, d in records)  # fmt: skip


def lane(lid: int, kind: str, width: float, mark: str) -> str:
    """A lane continuing into the same lane id of the neighbouring roads of the loop."""
    rm = ('<roadMark sOffset="0.0" type="none" weight="standard" color="standard" width="0.0"/>' if mark == "none"
          else f'<roadMark sOffset="0.0" type="{mark}" weight="standard" color="standard" width="0.15" '
               f'laneChange="{"both" if mark == "broken" else "none"}"/>')  # fmt: skip
    return (f'            <lane id="{lid}" type="{kind}" level="false"><link><predecessor id="{lid}"/>'
            f'<successor id="{lid}"/></link><width sOffset="0.0" a="{num(width)}" b="0.0" c="0.0" d="0.0"/>'
            f"{rm}</lane>")


def side(sign: int) -> list[str]:
    out = [lane(sign * k, "driving", W, "broken" if k < LANES else "solid") for k in range(1, LANES + 1)]
    return out + [lane(sign * (LANES + 1), "sidewalk", SW, "none")]


def road(rid: int, name: str, length: float, geometry: str, elevation, superelevation, pred: int, succ: int) -> list[str]:
    centre = ('            <lane id="0" type="none" level="false"><roadMark sOffset="0.0" type="solid solid" '
              'weight="standard" color="yellow" width="0.15" laneChange="none"/></lane>')
    return [
        f'  <road name="{name}" length="{num(length)}" id="{rid}" junction="-1">',
        f'      <link><predecessor elementType="road" elementId="{pred}" contactPoint="end"/>'
        f'<successor elementType="road" elementId="{succ}" contactPoint="start"/></link>',
        '      <type s="0.0" type="town"><speed max="50" unit="km/h"/></type>',
        f"      <planView>\n        {geometry}\n      </planView>",
        f"      <elevationProfile>{polys('elevation', elevation)}</elevationProfile>",
        f"      <lateralProfile>{polys('superelevation', superelevation)}</lateralProfile>",
        '      <lanes>\n        <laneSection s="0.0">',
        "          <left>\n" + "\n".join(side(+1)[::-1]) + "\n          </left>",
        f"          <center>\n{centre}\n          </center>",
        "          <right>\n" + "\n".join(side(-1)) + "\n          </right>",
        "        </laneSection>\n      </lanes>",
        "  </road>",
    ]


def hills_xodr() -> str:
    arc = math.pi * RADIUS
    flat = [(0.0, 0.0, 0.0, 0.0, 0.0)]
    bank = bank_profile(arc, BANK, RAMP)
    line = lambda x, y, h: (f'<geometry s="0.0" x="{num(x)}" y="{num(y)}" hdg="{num(h)}" length="{num(STRAIGHT)}">'
                            "<line/></geometry>")  # fmt: skip
    curve = lambda x, y, h: (f'<geometry s="0.0" x="{num(x)}" y="{num(y)}" hdg="{num(h)}" length="{num(arc)}">'
                             f'<arc curvature="{num(1 / RADIUS)}"/></geometry>')  # fmt: skip
    d = 2 * RADIUS
    lines = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        "<!-- hills.xodr: a small original town of the carlaocc project (CC0-1.0), made by tools/make_hills.py. "
        f"A closed loop: a {HILL:g} m crest, a banked half circle of radius {RADIUS:g} m ({BANK:g} rad), "
        f"a {-DIP:g} m sag, a second banked half circle; two 3.5 m lanes each way, 3 m sidewalks. -->",
        "<OpenDRIVE>",
        f'  <header revMajor="1" revMinor="4" name="hills" version="1.0" date="2025-01-01" north="{num(d + 60)}" '
        f'south="-60.0" east="{num(STRAIGHT + RADIUS + 60)}" west="{num(-RADIUS - 60)}" vendor="carlaocc"/>',
        *road(1, "Hill", STRAIGHT, line(0.0, 0.0, 0.0), smooth_bump(STRAIGHT, HILL), flat, 4, 2),
        *road(2, "East Bank", arc, curve(STRAIGHT, 0.0, 0.0), flat, bank, 1, 3),
        *road(3, "Valley", STRAIGHT, line(STRAIGHT, d, math.pi), smooth_bump(STRAIGHT, DIP), flat, 2, 4),
        *road(4, "West Bank", arc, curve(0.0, d, math.pi), flat, bank, 3, 1),
        "</OpenDRIVE>",
    ]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python tools/make_hills.py OUT.xodr")
    with open(sys.argv[1], "w", encoding="utf-8") as fh:
        fh.write(hills_xodr())
    print(f"wrote {sys.argv[1]}")
