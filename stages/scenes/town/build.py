"""Procedural towns in three styles (``downtown``, ``suburb``, ``arterial``) on the town contract of
:mod:`carlaocc.stages.scenes.network`.

World frame: metres, right-handed, Z up, the road surface at z = 0. Every style is a road grid: ``nx
+ 1`` straight north-south *columns* at ``x = cx[i]`` and ``ny + 1`` east-west *rows* at ``y =
ry[j]``; in the arterial style the middle row is the arterial, shifted sideways between junctions by
smooth S-curves (sampled at <= 1 m, straight for 6 m beyond each junction zone), so every junction
is axis-aligned. Each road has a cross-section
(:class:`~carlaocc.stages.scenes.town.layout.CrossSection`): ``lanes`` lanes of 3.5 m each way
(right-hand traffic), an optional raised median (grass, kerbed, with a guard rail) and an optional
parking strip along each kerb. ``block_size`` is the kerb-to-kerb distance between neighbouring
roads.

Junction zones: the square ``|x - cx| <= Hc + Z``, ``|y - cy| <= Hr + Z`` around a junction centre
(``Hc``/``Hr`` the column/row half-widths, ``Z`` the zone depth). It holds the crosswalk (zebra) of
every approach and the stop line at its edge; road lanes end at the zone edge and connector lanes
(straight, left and right turns, cubic curves sampled <= 1 m, carrying the junction id) cross it.
The zone's corner squares (``Z`` by ``Z``) are sidewalk. Blocks are bounded by sidewalks of width
``S`` along every road; their interior is grass (Terrain) at kerb height holding the lots. Around
the outermost roads runs a sidewalk ring of width ``max(S, Z)`` and a terrain margin of 20 m.

Stuff meshes (world frame, identity pose, keys ``"<town>/<name>"``) are **thin closed slabs**
(``SURFACE`` = 1 cm thick) standing for surfaces, tessellated into pieces of at most ``STUFF_TILE``
= 8 m (:mod:`~carlaocc.stages.scenes.placing`): straight pieces are axis-aligned tiled slabs, curved
pieces are extruded ribbons (grids along a polyline and across offsets from it). The road is
``[-SURFACE, 0]``; sidewalk, terrain and median tops are ``[curb - SURFACE, curb]``; the sidewalk
mesh also holds the kerb faces (thin walls ``[-SURFACE, curb - SURFACE]`` under every kerb edge);
road markings are ``[0, 0.01]`` on the road; fences, walls and guard rails stand on the grass.
Pieces touch at faces or edges only, every piece is closed on its own, so every stuff mesh is
watertight.

Things and props are placed on their support (kerb height) and never overlap one another: every
placement registers an oriented footprint (pole-like assets a small square at the pole axis, found
through the asset-frame conventions of :mod:`carlaocc.stages.ingest.procedural` with
``POLE_RADIUS``; trees their crown in lots and their trunk on sidewalks). Buildings fill lots along
every block side, street-facing, choosing the asset whose footprint fits the lot best. Nothing but
connector and road lanes lies on the carriageway except parked cars, which stay inside the parking
strips.

The town is built by concern, in this order (the order of the random draws and placements): junction
control (:mod:`~carlaocc.stages.scenes.town.furniture`), then per segment its road
(:mod:`~carlaocc.stages.scenes.town.roads`) and sidewalks
(:mod:`~carlaocc.stages.scenes.town.walkways`), per junction its road and sidewalk corners, the
block grounds and the outer ring, the lane graph and walk graph, the buildings
(:mod:`~carlaocc.stages.scenes.town.buildings`) and the furniture; the plan they share is
:mod:`~carlaocc.stages.scenes.town.layout`."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from carlaocc.schemas import taxonomy
from carlaocc.schemas.configs import ScenesConfig, TownSpec
from carlaocc.schemas.records import AssetRecord
from carlaocc.stages.geometry import concatenate
from carlaocc.stages.scenes.network import RoadNetwork, Town
from carlaocc.stages.scenes.placing import AssetPools, Placer, stuff_geometry
from carlaocc.stages.scenes.town.buildings import place_buildings
from carlaocc.stages.scenes.town.furniture import place_furniture, signalised
from carlaocc.stages.scenes.town.layout import STYLE_RULES, STYLES, TOWN_MARGIN, Layout, TownDraft
from carlaocc.stages.scenes.town.roads import junction_surfaces, lane_graph, road_length, road_surfaces
from carlaocc.stages.scenes.town.walkways import (
    block_ground,
    junction_corners,
    outer_ground,
    sidewalks_along,
    walk_graph,
)

__all__ = ["build_procedural_town", "town_name"]

# semantic class and material of each stuff mesh
STUFF_CLASSES = {"road": ("Road", "asphalt"), "sidewalk": ("Sidewalk", "paving"), "terrain": ("Terrain", "grass"),
                 "roadline": ("RoadLine", "paint"), "guardrail": ("GuardRail", "metal"), "fence": ("Fence", "wood"),
                 "wall": ("Wall", "concrete")}  # fmt: skip


def town_name(index: int) -> str:
    """``0 -> "town00"``."""
    return f"town{index:02d}"


def build_procedural_town(spec: TownSpec, scenes: ScenesConfig, index: int, assets: Sequence[AssetRecord]) -> Town:
    """Build procedural town ``index`` in ``spec.style`` from the ADMesh ``assets``.

    Deterministic from ``(scenes.seed, index, spec.style)`` and the set of assets (whatever their
    order). ``spec.blocks / block_size / road_width / sidewalk_width`` override the style's
    defaults. Needs at least one Building asset; other categories are placed when present (Car
    only as parked cars in the suburb). Raises ``ValueError`` for other styles or layouts without
    room for sidewalks and lanes.
    """
    if spec.style not in STYLE_RULES:
        raise ValueError(f"build_procedural_town builds the styles {list(STYLES)}, not {spec.style!r}")
    pools = AssetPools(assets)
    if not pools.get("Building"):
        raise ValueError(f"a procedural town needs at least one asset of category Building; got {sorted(pools.by_cat)}")
    rules = STYLE_RULES[spec.style]
    code = STYLES.index(spec.style)
    rng = np.random.default_rng(np.random.SeedSequence([scenes.seed, index, code, 0x70776E]))
    lay = Layout(spec.style, rules, spec, rng)
    draft = TownDraft(spec.style, rules, lay, pools, scenes.curb_height, rng)
    for i in range(lay.nx + 1):
        for j in range(lay.ny + 1):
            draft.signal[(i, j)] = signalised(draft, i, j)
    # stuff: roads and sidewalks, block grounds, the outer ring
    for seg in lay.segments:
        road_surfaces(draft, seg)
        sidewalks_along(draft, seg)
    for j in range(lay.ny + 1):
        for i in range(lay.nx + 1):
            junction_surfaces(draft, i, j)
            junction_corners(draft, i, j)
    for bj in range(lay.ny):
        for bi in range(lay.nx):
            block_ground(draft, bi, bj)
    outer_ground(draft)
    network = RoadNetwork(lanes=lane_graph(lay), walkways=walk_graph(draft), road_length=road_length(lay))
    # things, before the stuff meshes: lot frontages add fences and walls
    place_buildings(draft)
    place_furniture(draft)
    return _town(town_name(index), index, draft, network, frozenset(taxonomy.thing_ids(scenes.taxonomy)))


def _town(name: str, index: int, draft: TownDraft, network: RoadNetwork, things: frozenset[int]) -> Town:
    """The finished town: one stuff mesh per non-empty kind placed first (identity poses), then
    the deferred asset placements at kerb height; ``things`` get instance ids."""
    lay = draft.lay
    stuff = {}
    placer = Placer(name, things)
    for key, parts in draft.pieces.items():
        if not parts:
            continue
        k = f"{name}/{key}"
        stuff[k] = stuff_geometry(k, concatenate(parts), *STUFF_CLASSES[key])
        placer.add_stuff(stuff[k])
    for kind, asset, xy, yaw, anchor in draft.placements:
        placer.add_asset(kind, asset, xy, draft.curb, yaw, anchor)
    g = TOWN_MARGIN + lay.ring
    bounds = (lay.X0 - g, lay.Y0 - g, lay.X1 + g, lay.Y1 + g)
    return Town(
        name=name, index=index, style=draft.style, source="", placements=placer.records, stuff=stuff,
        network=network, bounds=tuple(float(b) for b in bounds), max_instance_id=placer.next_instance - 1,
        curb_height=draft.curb,
    )  # fmt: skip
