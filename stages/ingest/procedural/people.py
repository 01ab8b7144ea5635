"""Procedural people: pedestrians (standing or walking adults and children) and riders seated on a
bicycle or a motorcycle (classes Pedestrian, Rider).

Asset frame: metres, +X forward (the way the person faces or rides), +Y left, Z up; feet or
wheels touch z = 0.
"""

from __future__ import annotations

import numpy as np

from carlaocc.schemas.meshes import MeshPart
from carlaocc.stages.ingest.procedural.primitives import (
    CLOTHES, HAIR, PAINTS, SKINS, Builder, box, capsule, cone, ellipsoid, part, pick, uniform,
)
from carlaocc.stages.ingest.procedural.two_wheelers import two_wheeler


def rider(family: str) -> Builder:
    """A rider (class Rider) on a bicycle (city, road or mountain bike) or a motorcycle (sport,
    cruiser or scooter) of that vehicle's class; motorcyclists always wear a helmet, cyclists
    half of the time."""

    def build(rng: np.random.Generator) -> list[MeshPart]:
        kinds = ("city_bike", "road_bike", "mountain_bike") if family == "bicycle" else ("sport", "cruiser", "scooter")
        kind = pick(rng, kinds)
        parts, a = two_wheeler(rng, kind)
        H = uniform(rng, 1.60, 1.90)  # standing height of the rider
        cloth, skin = pick(rng, CLOTHES), pick(rng, SKINS)
        helmet = family == "motorcycle" or rng.uniform() < 0.5
        leans = {"road_bike": (0.42, 0.26), "cruiser": (0.12, 0.32), "scooter": (0.12, 0.32)}  # forward, up (x H)
        lean_x, lean_z = leans.get(kind, (0.30, 0.30))
        hip = a["seat"] + (0.0, 0.0, 0.10)
        shoulder = hip + (lean_x, 0.0, lean_z * H)
        tr, ar, lr = 0.085 * H * 0.9, 0.028 * H, 0.045 * H
        head_r = 0.065 * H * (1.15 if helmet else 1.0)
        head = ellipsoid(shoulder + (0.10, 0.0, 0.06 + 1.6 * 0.065 * H), (head_r,) * 3)
        parts += [
            part("rider_torso", capsule(tr, hip + (0.02, 0, tr * 0.6), shoulder - (0.03, 0, 0.05)), "Rider", "cloth",
                  color=cloth),
            part("rider_head", head, "Rider", "plastic" if helmet else "skin",
                  color=pick(rng, PAINTS) if helmet else skin),
        ]  # fmt: skip
        hands_y = 0.20
        for side, sy in (("left", 1.0), ("right", -1.0)):
            sh = shoulder + (0.0, sy * (tr + ar), -0.05)
            hand = a["bar"] + (0.0, sy * hands_y, 0.03)
            foot = a["pedal"] + (0.05, sy * 0.16, 0.0)
            knee = (hip + foot) / 2 + (0.22, sy * 0.10, 0.12)
            parts += [
                part(f"rider_arm_{side}", capsule(ar, sh, hand), "Rider", "cloth", color=cloth),
                part(f"rider_thigh_{side}", capsule(lr, hip + (0.0, sy * 0.09, 0.0), knee), "Rider", "cloth",
                      color=cloth),
                part(f"rider_shin_{side}", capsule(lr * 0.85, knee + (0.0, 0.0, -0.02), foot), "Rider", "cloth",
                      color=cloth),
            ]  # fmt: skip
        return parts

    return build


def pedestrian(subclass: str) -> Builder:
    """Standing or walking person (adult 1.55-1.95 m, child 1.0-1.4 m): head, optional hair,
    torso, two arms, two legs; varied girth, stride, arm swing, clothes and skin colours, and a
    style (trousers, skirt, backpack or hand bag)."""
    h_range, head_frac = {"adult": ((1.55, 1.95), 0.065), "child": ((1.00, 1.40), 0.080)}[subclass]

    def build(rng: np.random.Generator) -> list[MeshPart]:
        H = uniform(rng, *h_range)
        girth = uniform(rng, 0.9, 1.15)
        skin, top, bottom = pick(rng, SKINS), pick(rng, CLOTHES), pick(rng, CLOTHES)
        style = pick(rng, ("trousers", "trousers", "skirt", "backpack", "bag"))
        stride, swing = uniform(rng, 0.0, 0.12) * H, uniform(rng, -0.35, 0.35)
        sleeves = rng.uniform() < 0.5
        head_r = head_frac * H
        leg_r, arm_r, torso_r = 0.042 * H * girth, 0.028 * H, 0.085 * H * girth
        hip_z = 0.50 * H
        torso_top = H - 2 * head_r - torso_r * 0.6
        parts = [
            part("head", ellipsoid((0.0, 0.0, H - head_r), (head_r, head_r * 0.9, head_r)), "Pedestrian", "skin",
                  color=skin),
        ]  # fmt: skip
        if rng.uniform() < 0.7:
            hair = ellipsoid((-0.1 * head_r, 0.0, H - 0.85 * head_r), (head_r * 1.02, head_r * 0.94, head_r * 0.8))
            parts.append(part("hair", hair, "Pedestrian", "cloth", color=pick(rng, HAIR)))
        torso = capsule(torso_r, (0.0, 0.0, hip_z + 0.2 * torso_r), (0.0, 0.0, torso_top))
        torso = (torso[0] * (0.8, 1.15, 1.0), torso[1])  # flatter front-to-back than side-to-side
        parts.append(part("torso", torso, "Pedestrian", "cloth", color=top))
        arm_len = torso_top - 0.02 * H - 0.46 * H
        hands = {}
        for side, sy in (("left", 1.0), ("right", -1.0)):
            y_leg = sy * 0.055 * H
            y_arm = sy * (torso_r * 1.15 + arm_r + 0.01)
            foot_x = sy * stride / 2  # the left foot forward, the right back (or the reverse)
            sw = -sy * swing  # each arm swings against its leg
            sh = np.array([0.0, y_arm, torso_top - 0.02 * H])
            hands[side] = sh + arm_len * np.array([np.sin(sw), 0.0, -np.cos(sw)])
            parts += [
                part(f"leg_{side}", capsule(leg_r, (0.0, y_leg, hip_z), (foot_x, y_leg, leg_r)), "Pedestrian",
                      "cloth", color=bottom),
                part(f"arm_{side}", capsule(arm_r, sh, hands[side]), "Pedestrian", "cloth" if sleeves else "skin",
                      color=top if sleeves else skin),
            ]  # fmt: skip
        if style == "skirt":
            skirt = cone(0.115 * H * girth, 0.30 * H, (0.0, 0.0, 0.30 * H), 12)
            parts.append(part("skirt", skirt, "Pedestrian", "cloth", color=bottom))
        elif style == "backpack":
            zb = hip_z + 0.15 * H
            pack = box((-0.8 * torso_r - 0.17, -0.14, zb), (-0.8 * torso_r - 0.01, 0.14, min(zb + 0.4, torso_top)))
            parts.append(part("backpack", pack, "Pedestrian", "cloth", color=pick(rng, CLOTHES)))
        elif style == "bag":
            h = hands["right"]
            bag = box((h[0] - 0.06, h[1] - 0.16, h[2] - 0.30), (h[0] + 0.06, h[1] + 0.10, h[2] - 0.04))
            parts.append(part("bag", bag, "Pedestrian", "leather"))
        return parts

    return build
