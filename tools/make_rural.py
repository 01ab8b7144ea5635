"""Generator of a small hilly rural OpenDRIVE map for tests (original work of carlaocc, CC0-1.0):
the lane features CARLA's own towns use where our roads went wrong (issue 38).

One open road of three geometries (a line, a left arc, a line; 300 m) over two lane sections:

* elevation: a climb at 15 % (cubic ramps in and out of it), a crest, then a descent;
* superelevation: the arc is banked (ramped in and out);
* ``laneOffset``: the centre lane drifts 1 m to the left and back (cubic records);
* per side: a driving lane whose width has several records with ``sOffset`` and non-zero
  cubic terms (3.25 m -> 3.75 m -> 3.4 m), a shoulder lane with two width records, a border lane,
  and on the right a ``none`` lane of 1 m beyond the border (no surface);
* the second lane section adds a second driving lane on the right that opens from 0 m (cubic).

Usage: ``python tools/make_rural.py OUT.xodr`` or :func:`rural_xodr` (deterministic).
"""

from __future__ import annotations

import math
import os
import sys

# the number and cubic-record writers of the other test map's generator (tools/ is not a package)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from make_hills import num, polys  # noqa: E402

LINE1, ARC, LINE2 = 110.0, 90.0, 100.0  # m: planView pieces
RADIUS = 70.0  # m: the arc's radius (left turn)
GRADE = 0.15  # the climb's steepest grade
BANK = -0.08  # rad: superelevation on the arc (outside, right of +s, higher)
SECTION2 = 150.0  # m: start of the second lane section


def ramp(s0: float, length: float, v0: float, v1: float) -> tuple[float, float, float, float, float]:
    """Cubic record (s, a, b, c, d) going from ``v0`` to ``v1`` over ``length`` with zero slope at both ends."""
    dv = v1 - v0
    return (s0, v0, 0.0, 3 * dv / length**2, -2 * dv / length**3)


def elevation_records() -> list[tuple[float, float, float, float, float]]:
    """A 15 % climb: grade eased 0 -> 15 % over 20 m (z'' constant), 15 % for 60 m, eased back to 0
    over 20 m, flat for 40 m, then down at -10 % (eased) to the end."""
    g, e = GRADE, 20.0
    c = g / (2 * e)  # z = c u^2 on the easing: slope 2 c u reaches g at u = e
    recs = [(0.0, 0.0, 0.0, 0.0, 0.0), (20.0, 0.0, 0.0, c, 0.0)]
    z = c * e * e
    recs.append((40.0, z, g, 0.0, 0.0))
    z += g * 60.0
    recs.append((100.0, z, g, -c, 0.0))
    z += g * e - c * e * e
    recs.append((120.0, z, 0.0, 0.0, 0.0))
    g2 = -0.10
    c2 = g2 / (2 * e)
    recs.append((160.0, z, 0.0, c2, 0.0))
    z += c2 * e * e
    recs.append((180.0, z, g2, 0.0, 0.0))
    return recs


def lane(lid: int, kind: str, widths, mark: str = "none") -> str:
    rm = (f'<roadMark sOffset="0.0" type="{mark}" weight="standard" color="standard" width="0.12" '
          f'laneChange="{"both" if mark == "broken" else "none"}"/>')  # fmt: skip
    return f'<lane id="{lid}" type="{kind}" level="false">{polys("width", widths, "sOffset")}{rm}</lane>'


def driving_widths() -> list:
    """Several records with sOffset, each with non-zero cubic terms (within a lane section)."""
    return [ramp(0.0, 40.0, 3.25, 3.75), (40.0, 3.75, 0.0, 0.0, 0.0), ramp(80.0, 50.0, 3.75, 3.4), (130.0, 3.4, 0.0, 0.0, 0.0)]


def rural_xodr() -> str:
    h1 = LINE1
    arc_end_h = ARC / RADIUS
    cx, cy = LINE1, RADIUS  # arc centre
    x2, y2 = cx + RADIUS * math.sin(arc_end_h), cy - RADIUS * math.cos(arc_end_h)
    total = LINE1 + ARC + LINE2
    geoms = (f'<geometry s="0.0" x="0.0" y="0.0" hdg="0.0" length="{num(LINE1)}"><line/></geometry>'
             f'<geometry s="{num(h1)}" x="{num(LINE1)}" y="0.0" hdg="0.0" length="{num(ARC)}">'
             f'<arc curvature="{num(1 / RADIUS)}"/></geometry>'
             f'<geometry s="{num(LINE1 + ARC)}" x="{num(x2)}" y="{num(y2)}" hdg="{num(arc_end_h)}" '
             f'length="{num(LINE2)}"><line/></geometry>')  # fmt: skip
    sup = [(0.0, 0.0, 0.0, 0.0, 0.0), ramp(LINE1 - 10, 30.0, 0.0, BANK), (LINE1 + 20, BANK, 0.0, 0.0, 0.0),
           ramp(LINE1 + ARC - 20, 30.0, BANK, 0.0), (LINE1 + ARC + 10, 0.0, 0.0, 0.0, 0.0)]  # fmt: skip
    offsets = [(0.0, 0.0, 0.0, 0.0, 0.0), ramp(30.0, 60.0, 0.0, 1.0), (90.0, 1.0, 0.0, 0.0, 0.0),
               ramp(200.0, 60.0, 1.0, 0.0), (260.0, 0.0, 0.0, 0.0, 0.0)]  # fmt: skip
    shoulder = [(0.0, 0.5, 0.0, 0.0, 0.0), ramp(60.0, 50.0, 0.5, 1.2)]
    centre = '<lane id="0" type="none" level="false"><roadMark sOffset="0.0" type="solid" weight="standard" color="yellow" width="0.12"/></lane>'  # noqa: E501
    sec1 = (f'<laneSection s="0.0"><left>{lane(3, "border", [(0.0, 0.4, 0.0, 0.0, 0.0)])}'
            f'{lane(2, "shoulder", shoulder)}{lane(1, "driving", driving_widths(), "solid")}</left>'
            f"<center>{centre}</center>"
            f'<right>{lane(-1, "driving", driving_widths(), "solid")}{lane(-2, "shoulder", shoulder)}'
            f'{lane(-3, "border", [(0.0, 0.4, 0.0, 0.0, 0.0)])}{lane(-4, "none", [(0.0, 1.0, 0.0, 0.0, 0.0)])}'
            "</right></laneSection>")  # fmt: skip
    n2 = total - SECTION2
    sec2 = (f'<laneSection s="{num(SECTION2)}"><left>{lane(3, "border", [(0.0, 0.4, 0.0, 0.0, 0.0)])}'
            f'{lane(2, "shoulder", [(0.0, 1.2, 0.0, 0.0, 0.0), ramp(40.0, 60.0, 1.2, 0.6)])}'
            f'{lane(1, "driving", [(0.0, 3.4, 0.0, 0.0, 0.0), ramp(70.0, 60.0, 3.4, 3.6)], "solid")}</left>'
            f"<center>{centre}</center>"
            f'<right>{lane(-1, "driving", [(0.0, 3.4, 0.0, 0.0, 0.0)], "broken")}'
            f'{lane(-2, "driving", [ramp(0.0, 40.0, 0.0, 3.3), (40.0, 3.3, 0.0, 0.0, 0.0)], "solid")}'
            f'{lane(-3, "shoulder", [(0.0, 1.2, 0.0, 0.0, 0.0)])}'
            f'{lane(-4, "border", [(0.0, 0.4, 0.0, 0.0, 0.0), ramp(n2 - 50, 50.0, 0.4, 1.0)])}'
            "</right></laneSection>")  # fmt: skip
    lines = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        "<!-- rural.xodr: carlaocc test map (CC0-1.0), made by tools/make_rural.py: a 15 % climb, a banked "
        "arc, laneOffset, width records with sOffset and cubic terms, shoulder, border and none lanes. -->",
        "<OpenDRIVE>",
        '  <header revMajor="1" revMinor="4" name="rural" version="1.0" date="2025-01-01" vendor="carlaocc"/>',
        f'  <road name="Rural" length="{num(total)}" id="1" junction="-1">',
        '    <type s="0.0" type="rural"><speed max="70" unit="km/h"/></type>',
        f"    <planView>{geoms}</planView>",
        f"    <elevationProfile>{polys('elevation', elevation_records())}</elevationProfile>",
        f"    <lateralProfile>{polys('superelevation', sup)}</lateralProfile>",
        f"    <lanes>{polys('laneOffset', offsets)}{sec1}{sec2}</lanes>",
        "  </road>",
        "</OpenDRIVE>",
    ]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python tools/make_rural.py OUT.xodr")
    with open(sys.argv[1], "w", encoding="utf-8") as fh:
        fh.write(rural_xodr())
    print(f"wrote {sys.argv[1]}")
