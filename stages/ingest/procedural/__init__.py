"""The built-in procedural ADMesh source: parametric road-scene assets made from closed primitives.

The catalogue (:data:`CATALOGUE`) covers every *thing* class of the taxonomy (Pedestrian, Rider,
Car, Truck, Bus, Train, Motorcycle, Bicycle, Building) and the street-scene stuff props (poles,
street lights, traffic lights, signs, trees and other plants, benches, bins and other furniture,
a few movable props), with several sub-classes each: 87 sub-classes, so the default
``variants_per_subclass`` (3) gives 261 distinct assets. Every sub-class name is one of its
class's taxonomy sub-classes.

Modules, by asset family:

* ``primitives``   — class ids, materials and palettes, closed mesh primitives, parts, random draws.
* ``vehicles``     — cars, trucks, buses, trains.
* ``two_wheelers`` — bicycles and motorcycles (parked, or ridden).
* ``people``       — pedestrians and riders.
* ``buildings``    — houses to towers, halls, garages, gas stations, religious and public buildings.
* ``vegetation``   — trees, conifers, bushes, palms, hedges.
* ``poles``        — street lights, utility poles, flagpoles, traffic lights, traffic signs.
* ``furniture``    — street furniture (Static) and movable props (Dynamic).
* ``catalogue``    — :data:`CATALOGUE` and the driver :func:`ingest_procedural` (seeded draws,
  asset frame, content ids, records).

Every asset is a list of parts (:class:`~carlaocc.schemas.meshes.MeshPart`) in the **asset
frame**: metres, +X forward, +Y left, Z up, origin at the bottom centre of the asset's
axis-aligned bounding box. Each part is built from ``trimesh.creation`` primitives (box, cylinder,
icosphere, capsule, cone) or convex extruded prisms (``primitives._extrude``) and is closed and
consistently wound (outward) on its own; a part made of several primitives uses *disjoint* pieces
only (touching at most), so a closed part stays a valid solid for interior fill. Pieces of one
asset that overlap (a wheel inside a wheel arch, a window half sunk into a wall, a column under a
canopy) are separate parts.

Transparent parts (vehicle windows and windscreens, building glazing, bus-shelter and phone-booth
panes, vending-machine fronts) are parts of their own with ``transparent=True``, material
``"glass"`` and the asset's class as semantic id.

Conventions the scene builder relies on (documented here, derived from the asset extent):

* Vehicles (Car, Truck, Bus, Train, Motorcycle, Bicycle, Rider) drive along +X; wheels touch z = 0.
* Buildings: the entrance facade faces +X; ``extent[0]`` is the depth, ``extent[1]`` the frontage.
* ``Pole/street_light``: the pole stands at the -X end (``x = -extent[0]/2 + r``, ``y = 0``);
  the arm and lamp reach forward along +X (over the road when +X points at it).
* ``Pole/utility_pole`` and ``Pole/flagpole``: the pole is at ``x = -extent[0]/2 + r``, ``y = 0``
  (a transformer or the flag, when present, is on its +X side).
* ``TrafficLight/vehicle_signal`` and ``TrafficLight/pedestrian_signal``: the pole is at
  ``x = -extent[0]/2 + r``, ``y = 0``; the lenses face +X (towards the traffic they control).
* ``TrafficLight/overhead_signal``: the pole is at ``x = -extent[0]/2 + r``,
  ``y = +extent[1]/2 - r``; the mast arm reaches along -Y and the head's lenses face +X.
* ``TrafficSign/*``: the pole is at ``x = -extent[0]/2 + r``, ``y = 0``; the plate faces +X.
* ``Static/bench``, ``Static/bus_stop``, ``Static/kiosk``, ``Static/vending_machine``,
  ``Static/phone_booth``, ``Static/billboard``, ``Static/mailbox``: the usable side (seat, open
  side, service window, front panel, door, board face, slot) faces +X.

``r`` is the pole radius (0.04-0.14 m, within 5 cm of the town's assumed 0.09 m). Sizes are seeded
uniform draws inside realistic ranges (a sub-class's variants also draw styles and colours), so the
``variants_per_subclass`` variants of one sub-class differ in size and proportions; the same seed
gives byte-identical vertex arrays and records. Colours (``MeshPart.color``) are cosmetic: they go
into GLB files and previews, never into ids or hashes.
"""

from carlaocc.stages.ingest.procedural.catalogue import (
    CATALOGUE, LICENCE, SOURCE, IngestResult, asset_id_for, ingest_procedural,
)

__all__ = ["IngestResult", "ingest_procedural", "asset_id_for", "SOURCE", "LICENCE", "CATALOGUE"]
