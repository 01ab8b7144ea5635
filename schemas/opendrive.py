"""OpenDRIVE road-network records: the parsed ``.xodr`` network as plain frozen dataclasses.

:func:`carlaocc.catalog.opendrive.read_opendrive` returns an :class:`OpenDriveNetwork`; the scene
stage takes these records as they are (:mod:`carlaocc.stages.scenes.opendrive.geometry` for the geometry,
:mod:`carlaocc.stages.scenes.opendrive.town` for the town).

Only the parts the scene stage needs are kept: the header, roads (links, road types, planView
geometries, elevation and superelevation profiles, lane offsets, lane sections with their lanes,
widths, borders and road marks, signals, objects) and junctions (connections with lane links).

Units are those of the file (metres, radians). Coordinates are OpenDRIVE's inertial frame:
right-handed, x east, y north, z up, which is also this project's world frame. Road coordinates:
``s`` along the road's reference line (metres from the road start), ``t`` to its left.
"""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = [
    "GEOMETRY_KINDS",
    "Header",
    "Poly3Record",
    "Geometry",
    "RoadLink",
    "RoadTypeRecord",
    "RoadMarkLine",
    "RoadMark",
    "LaneRecord",
    "LaneSection",
    "Signal",
    "RoadObject",
    "Road",
    "LaneLink",
    "Connection",
    "Junction",
    "OpenDriveNetwork",
]

GEOMETRY_KINDS = ("line", "arc", "spiral", "poly3", "paramPoly3")


@dataclass(frozen=True)
class Header:
    """The ``<header>``: format revision, name, and the bounding box (metres) when the file gives one."""

    rev_major: int | None = None
    rev_minor: int | None = None
    name: str = ""
    version: str = ""
    date: str = ""
    north: float | None = None
    south: float | None = None
    east: float | None = None
    west: float | None = None
    vendor: str = ""
    geo_reference: str = ""


@dataclass(frozen=True)
class Poly3Record:
    """``a + b ds + c ds^2 + d ds^3`` valid from ``s`` on (``s`` is ``sOffset`` for lane
    widths/borders, relative to the lane section start; road-absolute elsewhere)."""

    s: float
    a: float
    b: float = 0.0
    c: float = 0.0
    d: float = 0.0


@dataclass(frozen=True)
class Geometry:
    """One planView record. ``kind`` is one of :data:`GEOMETRY_KINDS`; the fields that do not
    apply to the kind are left at their defaults.

    arc: ``curvature``. spiral: ``curv_start``, ``curv_end``. poly3: ``a, b, c, d`` (v(u)).
    paramPoly3: ``au..du, av..dv`` and ``p_range`` in {"arcLength", "normalized"}.
    """

    s: float
    x: float
    y: float
    hdg: float
    length: float
    kind: str
    curvature: float = 0.0
    curv_start: float = 0.0
    curv_end: float = 0.0
    a: float = 0.0
    b: float = 0.0
    c: float = 0.0
    d: float = 0.0
    au: float = 0.0
    bu: float = 0.0
    cu: float = 0.0
    du: float = 0.0
    av: float = 0.0
    bv: float = 0.0
    cv: float = 0.0
    dv: float = 0.0
    p_range: str = "normalized"
    line: int | None = None


@dataclass(frozen=True)
class RoadLink:
    """A road's ``<predecessor>`` / ``<successor>``: another road (with the contact point) or a junction."""

    element_type: str  # "road" or "junction"
    element_id: str
    contact_point: str | None = None  # "start" / "end" (roads only)


@dataclass(frozen=True)
class RoadTypeRecord:
    """A road ``<type>`` from ``s`` on, with its speed limit (``speed_max`` in ``speed_unit``, None if none)."""

    s: float
    type: str
    speed_max: float | None = None
    speed_unit: str | None = None


@dataclass(frozen=True)
class RoadMarkLine:
    """An explicit line of a ``<roadMark><type>`` definition."""

    length: float
    space: float
    t_offset: float = 0.0
    s_offset: float = 0.0
    width: float | None = None
    rule: str = "none"


@dataclass(frozen=True)
class RoadMark:
    """A lane's ``<roadMark>`` from ``s_offset`` (metres from the lane-section start) on; ``width`` in
    metres (None: the default), ``lines`` the explicit line pattern if the file gives one."""

    s_offset: float
    type: str  # solid, broken, "solid solid", "broken broken", "solid broken", curb, none, ...
    weight: str = "standard"
    color: str = "standard"
    material: str = "standard"
    width: float | None = None
    lane_change: str = "both"
    height: float = 0.0
    lines: tuple[RoadMarkLine, ...] = ()


@dataclass(frozen=True)
class LaneRecord:
    """One lane of a lane section: id (positive left of the centre lane, negative right, 0 the centre
    lane), OpenDRIVE lane type, width / border polynomials and road marks (sorted by offset), and
    the ids of the linked lanes of the neighbouring sections / roads."""

    id: int
    type: str
    level: bool = False
    widths: tuple[Poly3Record, ...] = ()
    borders: tuple[Poly3Record, ...] = ()
    road_marks: tuple[RoadMark, ...] = ()
    predecessor: int | None = None
    successor: int | None = None


@dataclass(frozen=True)
class LaneSection:
    """A ``<laneSection>`` starting at road-absolute ``s``: its left, centre and right lanes."""

    s: float
    single_side: bool = False
    left: tuple[LaneRecord, ...] = ()  # ids 1, 2, 3, ... (sorted inner to outer)
    center: tuple[LaneRecord, ...] = ()  # id 0
    right: tuple[LaneRecord, ...] = ()  # ids -1, -2, -3, ... (sorted inner to outer)


@dataclass(frozen=True)
class Signal:
    """A road ``<signal>`` at road coordinates (``s``, ``t``), metres; ``h_offset``, ``pitch``, ``roll``
    in radians; ``orientation`` "+" (valid along +s), "-" (against s) or "none"."""

    id: str
    name: str
    s: float
    t: float
    z_offset: float = 0.0
    h_offset: float = 0.0
    orientation: str = "none"
    dynamic: bool = False
    country: str = ""
    type: str = ""
    subtype: str = ""
    value: float | None = None
    text: str = ""
    height: float | None = None
    width: float | None = None
    pitch: float = 0.0
    roll: float = 0.0


@dataclass(frozen=True)
class RoadObject:
    """A road ``<object>`` at road coordinates (``s``, ``t``), metres; angles in radians; sizes in
    metres (None when the file gives none)."""

    id: str
    name: str
    type: str
    s: float
    t: float
    z_offset: float = 0.0
    hdg: float = 0.0
    pitch: float = 0.0
    roll: float = 0.0
    orientation: str = "none"
    length: float | None = None
    width: float | None = None
    height: float | None = None
    radius: float | None = None


@dataclass(frozen=True)
class Road:
    """One ``<road>``: its reference line (planView geometries sorted by ``s``), profiles and lane
    offsets (sorted by ``s``), lane sections (sorted by ``s``), links, types, signals and objects.
    ``length`` in metres; ``line`` is the source line of the element."""

    id: str
    name: str
    length: float
    junction: str  # "-1" when not in a junction
    geometries: tuple[Geometry, ...]
    elevations: tuple[Poly3Record, ...] = ()
    superelevations: tuple[Poly3Record, ...] = ()
    lane_offsets: tuple[Poly3Record, ...] = ()
    lane_sections: tuple[LaneSection, ...] = ()
    predecessor: RoadLink | None = None
    successor: RoadLink | None = None
    types: tuple[RoadTypeRecord, ...] = ()
    signals: tuple[Signal, ...] = ()
    objects: tuple[RoadObject, ...] = ()
    line: int | None = None


@dataclass(frozen=True)
class LaneLink:
    """A junction connection's ``<laneLink>``: lane ``from_lane`` of the incoming road continues into
    lane ``to_lane`` of the connecting road."""

    from_lane: int
    to_lane: int


@dataclass(frozen=True)
class Connection:
    """A junction ``<connection>``: the incoming road enters the connecting road at its
    ``contact_point`` ("start" / "end")."""

    id: str
    incoming_road: str
    connecting_road: str
    contact_point: str | None = None
    lane_links: tuple[LaneLink, ...] = ()


@dataclass(frozen=True)
class Junction:
    """A ``<junction>`` and its connections."""

    id: str
    name: str
    connections: tuple[Connection, ...] = ()


@dataclass(frozen=True)
class OpenDriveNetwork:
    """A parsed ``.xodr`` file: header, roads (file order), junctions; ``source`` names the file."""

    header: Header
    roads: tuple[Road, ...]
    junctions: tuple[Junction, ...] = ()
    source: str = ""
    _road_index: dict = field(default_factory=dict, repr=False, compare=False)

    def road(self, road_id: str | int) -> Road:
        """The road with this id (``KeyError`` if absent)."""
        if not self._road_index:
            self._road_index.update({r.id: r for r in self.roads})
        return self._road_index[str(road_id)]

    @property
    def signals(self) -> tuple[Signal, ...]:
        return tuple(sig for r in self.roads for sig in r.signals)

    @property
    def objects(self) -> tuple[RoadObject, ...]:
        return tuple(obj for r in self.roads for obj in r.objects)
