"""Lay an OpenDRIVE map over hills, for tests (original work of carlaocc, CC0-1.0).

Every road's elevation profile is replaced by cubic Hermite records every :data:`STEP` m that
follow a smooth height field under its reference line,

    z(x, y) = A sin(2 pi x / L) cos(2 pi y / L)     (metres; steepest grade 2 pi A / L),

so linked roads meet at the same height wherever their reference lines meet. With ``bank`` the
cross section is also rolled to the field's cross slope (``<superelevation>`` = atan of the
slope to the left of +s), so the lanes lie on the field to second order in their offset;
without it the cross sections stay level, as in CARLA's own towns, and a junction connector
whose reference line starts beside the incoming road's meets its lanes a little higher or lower.

Usage: ``python tools/make_hilly.py IN.xodr OUT.xodr [A L [bank]]`` or :func:`hilly_xodr`.
"""

from __future__ import annotations

import math
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from carlaocc.catalog.opendrive import parse_opendrive  # noqa: E402
from carlaocc.stages.scenes.opendrive.geometry import reference_pose  # noqa: E402

STEP = 5.0  # m: elevation record length


def field(x, y, amplitude: float, wavelength: float):
    """Height (m) of the field at world (x, y) m."""
    k = 2 * np.pi / wavelength
    return amplitude * np.sin(k * np.asarray(x)) * np.cos(k * np.asarray(y))


def field_gradient(x, y, amplitude: float, wavelength: float):
    """(dz/dx, dz/dy) of :func:`field`."""
    k = 2 * np.pi / wavelength
    x, y = np.asarray(x), np.asarray(y)
    return amplitude * k * np.cos(k * x) * np.cos(k * y), -amplitude * k * np.sin(k * x) * np.sin(k * y)


def _records(tag: str, s: np.ndarray, v: np.ndarray, dv: np.ndarray | None) -> list[ET.Element]:
    """Cubic Hermite records through values ``v`` (and slopes ``dv``; linear when None) at ``s``."""
    out = []
    for i in range(len(s) - 1):
        h = s[i + 1] - s[i]
        if dv is None:
            a, b, c, d = v[i], (v[i + 1] - v[i]) / h, 0.0, 0.0
        else:
            a, b = v[i], dv[i]
            c = (3 * (v[i + 1] - v[i]) / h - 2 * dv[i] - dv[i + 1]) / h
            d = (dv[i] + dv[i + 1] - 2 * (v[i + 1] - v[i]) / h) / h**2
        out.append(ET.Element(tag, {"s": repr(float(s[i])), "a": repr(float(a)), "b": repr(float(b)),
                                    "c": repr(float(c)), "d": repr(float(d))}))  # fmt: skip
    return out


def hilly_xodr(text: str, amplitude: float, wavelength: float, bank: bool = False) -> str:
    """``text`` (an OpenDRIVE file) with every road's elevation (and with ``bank`` its
    superelevation) replaced by the height field's."""
    odr = parse_opendrive(text)
    root = ET.fromstring(text)
    for elem in root.findall("road"):
        road = odr.road(elem.get("id"))
        n = max(1, math.ceil(road.length / STEP))
        s = np.linspace(0.0, road.length, n + 1)
        x, y, h = reference_pose(road, s)
        gx, gy = field_gradient(x, y, amplitude, wavelength)
        along = gx * np.cos(h) + gy * np.sin(h)  # dz/ds on the reference line
        for old in elem.findall("elevationProfile") + elem.findall("lateralProfile"):
            elem.remove(old)
        elev = ET.Element("elevationProfile")
        elev.extend(_records("elevation", s, field(x, y, amplitude, wavelength), along))
        lateral = ET.Element("lateralProfile")
        if bank:
            left = -gx * np.sin(h) + gy * np.cos(h)  # the field's slope to the left of +s
            lateral.extend(_records("superelevation", s, np.arctan(left), None))
        pos = list(elem).index(elem.find("planView")) + 1
        elem.insert(pos, elev)
        elem.insert(pos + 1, lateral)
    return ET.tostring(root, encoding="unicode")


if __name__ == "__main__":
    if len(sys.argv) not in (3, 5, 6):
        sys.exit("usage: python tools/make_hilly.py IN.xodr OUT.xodr [AMPLITUDE WAVELENGTH [bank]]")
    a, wl = (float(sys.argv[3]), float(sys.argv[4])) if len(sys.argv) >= 5 else (8.0, 300.0)
    out = hilly_xodr(Path(sys.argv[1]).read_text(encoding="utf-8"), a, wl, bank=len(sys.argv) == 6)
    Path(sys.argv[2]).write_text(out, encoding="utf-8")
    print(f"wrote {sys.argv[2]}")
