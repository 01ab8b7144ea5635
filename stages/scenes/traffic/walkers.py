"""Walkers of a traffic sequence (:mod:`carlaocc.stages.scenes.traffic.simulation`): pedestrians on the walk
graph (sidewalks, and crosswalks when their junction is reserved for them in
:mod:`~carlaocc.stages.scenes.traffic.junctions`), keeping right, yielding to the walker ahead and
stepping aside for oncoming ones; the gait phase advances by walked distance.

World frame of the town: metres, Z up; time in seconds, speeds in m/s. A walker walks along
walkway ``way`` at arc length ``s`` (m); its actual position is steered towards that path point.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from carlaocc.schemas.records import AssetRecord
from carlaocc.stages.scenes.network import Walkway
from carlaocc.stages.scenes.traffic.junctions import JunctionReservations

__all__ = ["GAIT_STEP", "STAND_SPEED", "Walker", "WalkerTraffic"]

WALKER_CLEAR = 0.15  # m, walkers keep this much space between their boxes
WALKER_STEER = 1.5  # walkers move towards their path point at most this many times their speed
ASIDE_RATE = 0.4  # m/s: how fast a yielding walker steps aside (and back)
GAIT_STEP = 0.415  # step length / body height
STAND_SPEED = 0.1  # m/s: slower walkers stand (no gait phase)


@dataclass
class Walker:
    """A walker on the walk graph: on walkway ``way`` at arc length ``s``, walking towards its end
    (``sign`` +1) or its start (-1); ``pos`` its actual position (steered towards the path)."""

    asset: AssetRecord
    way: int
    s: float
    sign: int
    v0: float
    pos: np.ndarray
    yaw: float
    v: float = 0.0
    phase: float = 0.0
    plan: tuple[int, int] | None = None  # the walkway (and direction) taken at the next node
    walked: float = 0.0
    aside: float = 0.0  # m stepped aside (to the right) to let an oncoming walker pass

    @property
    def radius(self) -> float:
        return 0.5 * math.hypot(float(self.asset.extent[0]), float(self.asset.extent[1]))

class WalkerTraffic:
    """The walkers of one sequence on the walk graph of ``ways``: path points, plans at the
    nodes (drawn from ``rng``), crosswalk reservations and the stepping."""

    def __init__(self, ways: Sequence[Walkway], rng: np.random.Generator, junctions: JunctionReservations) -> None:
        self.ways = ways
        self.rng = rng
        self.junctions = junctions
        self.walkers: list[Walker] = []
        # walk graph: node -> [(walkway, sign of travel when leaving the node along it)]
        self.node_ways: dict[int, list[tuple[int, int]]] = {}
        for w in self.ways:
            self.node_ways.setdefault(w.start_node, []).append((w.walkway_id, 1))
            self.node_ways.setdefault(w.end_node, []).append((w.walkway_id, -1))

    def path_point(self, w: Walker) -> tuple[np.ndarray, float]:
        """Path point (3,) and heading of a walker: its walkway point, kept right of the centre."""
        way = self.ways[w.way]
        p, yaw = way.at(w.s)
        yaw = float(yaw) if w.sign > 0 else float(yaw) + math.pi
        offset = min(0.45, way.width / 4) + w.aside
        return p + np.array([math.sin(yaw), -math.cos(yaw), 0.0]) * offset, yaw

    def remaining(self, w: Walker) -> float:
        """Metres left on the walker's walkway in its walking direction."""
        return self.ways[w.way].length - w.s if w.sign > 0 else w.s

    def ensure_plan(self, w: Walker) -> tuple[int, int]:
        """The walkway (and direction) a walker takes at its next node, drawn once: any other
        walkway at the node, or back along its own at a dead end."""
        if w.plan is None:
            way = self.ways[w.way]
            node = way.end_node if w.sign > 0 else way.start_node
            options = [(k, sg) for k, sg in self.node_ways.get(node, []) if k != w.way] or [(w.way, -w.sign)]
            w.plan = options[int(self.rng.integers(len(options)))]
        return w.plan

    def crossing_ahead(self, w: Walker, index: int) -> tuple[int, float] | None:
        """(junction, metres to it) of a crosswalk the walker is about to step on without holding
        its junction, when within 3 m of it; else None."""
        r = self.remaining(w)
        if r > 3.0:
            return None
        nxt = self.ways[self.ensure_plan(w)[0]]
        if nxt.crosswalk and nxt.junction >= 0 and not self.junctions.holds(nxt.junction, "walker", index):
            return nxt.junction, r
        return None

    def step(self, dt: float, step_no: int) -> None:
        """Advance every walker by ``dt`` s at integration step ``step_no``: yield to walkers ahead,
        wait for the junction of a crosswalk, walk along the graph, steer towards the path point."""
        W, J = self.walkers, self.junctions
        if not W:
            return
        pos = np.array([w.pos[:2] for w in W])
        heading = np.array([[math.cos(w.yaw), math.sin(w.yaw)] for w in W])
        radius = np.array([w.radius for w in W])
        rel = pos[None, :, :] - pos[:, None, :]  # [i, j] = pos_j - pos_i
        along = np.einsum("ijk,ik->ij", rel, heading)
        lateral = np.abs(rel[:, :, 0] * heading[:, None, 1] - rel[:, :, 1] * heading[:, None, 0])
        reach = radius[:, None] + radius[None, :] + WALKER_CLEAR
        ahead = (along > -0.5 * reach) & (lateral < reach)
        np.fill_diagonal(ahead, False)
        # two walkers blocking each other: the higher index steps aside (to its right) until the
        # other can pass; both keep their distance meanwhile
        idx = np.arange(len(W))
        yields = (ahead & ahead.T & (idx[:, None] > idx[None, :])).any(axis=1)
        gap = np.where(ahead, np.hypot(along, lateral) - reach, np.inf).min(axis=1)
        for i, w in enumerate(W):
            room = max(0.0, self.ways[w.way].width / 2 - min(0.45, self.ways[w.way].width / 4) - 0.3)
            w.aside = min(room, w.aside + ASIDE_RATE * dt) if yields[i] else max(0.0, w.aside - ASIDE_RATE * dt)
        crossing = [self.crossing_ahead(w, i) for i, w in enumerate(W)]
        for i, c in enumerate(crossing):
            if c is not None and c[1] < 2.0:
                J.request(c[0], "walker", i, step_no)
        J.grant()
        where = np.array([w.pos[:2] for w in W])  # current positions, updated as walkers move
        for i, w in enumerate(W):
            w.v = w.v0 if gap[i] > 0.6 else (0.5 * w.v0 if gap[i] > 0.2 else 0.0)
            before = (w.way, w.s, w.sign, w.plan, w.pos, w.walked)
            step = w.v * dt
            c = crossing[i]
            if c is not None and not J.holds(c[0], "walker", i):
                step = min(step, max(0.0, c[1] - 0.4))  # wait at the kerb
                w.v = step / dt
            w.walked += step
            while step > 0:
                r = self.remaining(w)
                if step <= r:
                    w.s += w.sign * step
                    break
                step -= r
                w.way, w.sign = self.ensure_plan(w)
                w.plan = None
                w.s = 0.0 if w.sign > 0 else self.ways[w.way].length
            target, yaw = self.path_point(w)
            # steer: move towards the path point at a bounded speed (no jumps at corners)
            d = target - w.pos
            dist = float(np.linalg.norm(d[:2]))
            cap = max(w.v, 0.3) * WALKER_STEER * dt
            if dist > cap:
                d = d * (cap / dist)
            w.pos = w.pos + d
            # hard rule: a move that would bring the walker's disc into another's is not made
            near = np.hypot(*(where - w.pos[:2]).T) < radius + radius[i]
            near[i] = False
            if near.any():
                w.way, w.s, w.sign, w.plan, w.pos, w.walked = before
                w.v = 0.0
                continue
            where[i] = w.pos[:2]
            if w.v > 0:
                w.yaw = math.atan2(d[1], d[0]) if dist > 0.05 * dt else yaw
            w.phase = (w.phase + w.v * dt / (2.0 * GAIT_STEP * float(w.asset.extent[2]))) % 1.0
            # hold a junction only while on one of its crosswalks
            way = self.ways[w.way]
            keep = {way.junction} if way.crosswalk and way.junction >= 0 else set()
            J.release_all_but(keep | ({c[0]} if c is not None else set()), "walker", i)
