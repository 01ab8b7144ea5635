"""ShapeNetCore v2.

Layout accepted
    ``<root>/taxonomy.json`` (required: the list of ``{"synsetId", "name", "children": [...]}``
    ShapeNet ships) and ``<root>/<synset>/<model>/models/model_normalized.obj`` (+ its
    ``model_normalized.mtl``; textures under ``<model>/images/``). One item per model, key
    ``"<synset>/<model>"``. Optional ``<root>/all.csv`` (ShapeNet's split file: ``id, synsetId,
    subSynsetId, modelId, split``) gives each model's sub-synset, used for the sub-class.
    ShapeNetCore v1 (``model.obj``, a different alignment) is not read.

Categories
    The synset directory, or the model's sub-synset when ``all.csv`` names one, is resolved
    through ``taxonomy.json``'s parent links to the most specific synset of :data:`SYNSETS`
    (WordNet 3.0 offsets). Vehicles map to the taxonomy; every other synset (airplane, chair,
    watercraft...) raises ``SourceError("no category")``: it is quarantined, not guessed.

    ====================== ==========================================================
    02958343 car            Car; sub-class from the most specific known sub-synset
                            (:data:`CAR_SUBSYNSETS`, e.g. 04285965 SUV -> suv), else a
                            word of its taxonomy name that is a Car sub-class, else sedan
    04490091 truck          Truck (fire engine, garbage truck, tow truck, trailer truck,
                            moving van: their sub-classes); pickup 03930630 -> Car/pickup
    02924116 bus            Bus (minibus 03769881 -> minibus; trolleybus -> city_bus)
    04468005 train          Train (streetcar 04335435 -> tram)
    03790512 motorcycle     Motorcycle (moped, motor scooter -> their sub-classes)
    02834778 bicycle        Bicycle/city_bike; 03792782 mountain bike -> mountain_bike
    ====================== ==========================================================

    Of these, ShapeNetCore's 55 synsets hold car, bus, train and motorbike; the truck and
    bicycle rows serve taxonomies (ShapeNetSem-style, or sub-synsets named in ``all.csv``) that
    have them.

Declarations
    ``normalized=True`` (ShapeNet scales every model to a unit bounding-box diagonal, so the
    size is rescaled from the sub-class size range), units ``"unknown"``. Axes: the ShapeNetCore
    v2 release notes state the OBJ files are pre-aligned with **+Y up and the front facing -Z**
    (fixing v1's mirroring), so up ``"+y"``, forward ``"-z"``. Licence ``"ShapeNet terms of
    use"`` (non-commercial research terms accepted at download), ``licence_required=False``.
"""

from __future__ import annotations

import csv
import json
import os
import re

from carlaocc.catalog.sources._common import (drop_excluded, load_parts, missing_file_notes, semantic_class,
                                              texture_files)
from carlaocc.catalog.sources.obj import mtl_files
from carlaocc.catalog.sources.base import SourceError, SourceItem
from carlaocc.schemas.meshes import SourceAsset

LICENCE = "ShapeNet terms of use"
MODEL_FILE = os.path.join("models", "model_normalized.obj")

# synset -> (class, sub-class): the most specific synset on a model's hypernym path wins.
SYNSETS: dict[str, tuple[str, str]] = {
    "02958343": ("Car", "sedan"),  # car, auto, automobile
    "03930630": ("Car", "pickup"),  # pickup, pickup truck (a truck hyponym in WordNet)
    "04490091": ("Truck", "box_truck"),  # truck, motortruck
    "03345487": ("Truck", "fire_truck"),  # fire engine, fire truck
    "03417042": ("Truck", "garbage_truck"),  # garbage truck, dustcart
    "04461696": ("Truck", "tow_truck"),  # tow truck, wrecker
    "04467665": ("Truck", "semi_truck"),  # trailer truck, tractor trailer, semi
    "03796401": ("Truck", "box_truck"),  # moving van
    "02924116": ("Bus", "city_bus"),  # bus, autobus, coach
    "03769881": ("Bus", "minibus"),  # minibus
    "04487081": ("Bus", "city_bus"),  # trolleybus
    "04468005": ("Train", "train"),  # train, railroad train
    "04335435": ("Train", "tram"),  # streetcar, tram
    "03790512": ("Motorcycle", "sport"),  # motorcycle, bike
    "03785016": ("Motorcycle", "moped"),  # moped
    "03791053": ("Motorcycle", "scooter"),  # motor scooter
    "02834778": ("Bicycle", "city_bike"),  # bicycle, bike, wheel, cycle
    "03792782": ("Bicycle", "mountain_bike"),  # mountain bike, all-terrain bike
}

# Car sub-synsets of ShapeNet's taxonomy (WordNet 3.0) -> Car sub-class.
CAR_SUBSYNSETS: dict[str, str] = {
    "02701002": "van",  # ambulance
    "02814533": "wagon",  # beach wagon, station wagon, estate car
    "02930766": "taxi",  # cab, hack, taxi
    "03100240": "convertible",
    "03119396": "coupe",
    "03141065": "police",  # cruiser, police cruiser, patrol car
    "03881534": "police",  # panda car
    "03498781": "hatchback",
    "03543394": "coupe",  # hot rod
    "03594945": "suv",  # jeep, landrover
    "03670208": "sedan",  # limousine
    "03770679": "minivan",
    "03870105": "coupe",  # pace car
    "04037443": "coupe",  # racer, race car
    "04322801": "coupe",  # stock car
    "04097373": "convertible",  # roadster, two-seater
    "04166281": "sedan",  # sedan, saloon
    "04285008": "coupe",  # sports car
    "04285965": "suv",  # sport utility vehicle
    "04459122": "convertible",  # touring car, phaeton
    "03930630": "pickup",
}


def _load_taxonomy(root: str) -> dict[str, dict]:
    path = os.path.join(root, "taxonomy.json")
    try:
        with open(path, encoding="utf-8") as f:
            doc = json.load(f)
    except FileNotFoundError:
        raise SourceError("bad metadata", f"{path} not found: a ShapeNetCore root holds "
                                          "taxonomy.json and <synset>/<model>/models/") from None  # fmt: skip
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise SourceError("bad metadata", f"{path}: {e}") from None
    if not isinstance(doc, list) or not all(isinstance(e, dict) and "synsetId" in e for e in doc):
        raise SourceError("bad metadata", f"{path}: expected a list of {{synsetId, name, children}}")
    out: dict[str, dict] = {}
    for e in doc:
        sid = str(e["synsetId"])
        out[sid] = {"name": str(e.get("name", "")), "children": [str(c) for c in e.get("children", []) or []]}
    return out


def _parents(tax: dict[str, dict]) -> dict[str, str]:
    parents: dict[str, str] = {}
    for sid, e in tax.items():
        for c in e["children"]:
            parents.setdefault(c, sid)
    return parents


def _load_subsynsets(root: str) -> dict[tuple[str, str], str]:
    """(synset, model) -> subSynsetId from ``all.csv`` when present."""
    path = os.path.join(root, "all.csv")
    if not os.path.isfile(path):
        return {}
    out: dict[tuple[str, str], str] = {}
    try:
        with open(path, newline="", encoding="utf-8") as f:
            for row in csv.DictReader(f):
                s, m, sub = row.get("synsetId"), row.get("modelId"), row.get("subSynsetId")
                if s and m and sub:
                    out[(s.strip().zfill(8), m.strip())] = sub.strip().zfill(8)
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise SourceError("bad metadata", f"{path}: {e}") from None
    return out


def _chain(sid: str, parents: dict[str, str]) -> list[str]:
    """sid and its hypernyms up the taxonomy, most specific first."""
    out, seen = [], set()
    while sid and sid not in seen:
        out.append(sid)
        seen.add(sid)
        sid = parents.get(sid, "")
    return out


def classify(synset: str, sub: str | None, tax: dict[str, dict]) -> tuple[str, str] | None:
    """(class, sub-class) for a model of directory ``synset`` and optional sub-synset, or None."""
    parents = _parents(tax)
    chain = _chain(sub, parents) if sub else []
    if synset not in chain:
        chain += _chain(synset, parents)
    hit = next((s for s in chain if s in SYNSETS), None)
    if hit is None:
        return None
    cls_name, subclass = SYNSETS[hit]
    if cls_name == "Car":
        vocab = semantic_class("Car").subclasses
        for s in chain:
            if s == hit:
                break
            if s in CAR_SUBSYNSETS:
                return cls_name, CAR_SUBSYNSETS[s]
            words = re.split(r"[^a-z]+", tax.get(s, {}).get("name", "").lower())
            match = next((w for w in words if w in vocab), None)
            if match:
                return cls_name, match
    return cls_name, subclass


class ShapeNetAdapter:
    """ShapeNetCore v2 (see the module docstring)."""

    kind = "shapenet"

    def __init__(self):
        self._cache: dict[str, tuple[tuple, dict, dict]] = {}

    def _metadata(self, root: str) -> tuple[dict[str, dict], dict[tuple[str, str], str]]:
        """taxonomy.json and all.csv of a root, re-read only when either file changes."""
        stamp = []
        for name in ("taxonomy.json", "all.csv"):
            try:
                st = os.stat(os.path.join(root, name))
                stamp.append((st.st_mtime_ns, st.st_size))
            except OSError:
                stamp.append(None)
        cached = self._cache.get(root)
        if cached is None or cached[0] != tuple(stamp):
            cached = (tuple(stamp), _load_taxonomy(root), _load_subsynsets(root))
            self._cache[root] = cached
        return cached[1], cached[2]

    def list_items(self, root: str, exclude: tuple[str, ...] = ()) -> list[SourceItem]:
        root = os.path.abspath(root)
        if not os.path.isdir(root):
            raise SourceError("bad metadata", f"{root} is not a directory")
        self._metadata(root)  # the root must be a ShapeNet root (taxonomy.json)
        items = []
        for synset in sorted(os.listdir(root)):
            sdir = os.path.join(root, synset)
            if not (re.fullmatch(r"\d{8}", synset) and os.path.isdir(sdir)):
                continue
            for model in sorted(os.listdir(sdir)):
                obj = os.path.join(sdir, model, MODEL_FILE)
                if not os.path.isdir(os.path.join(sdir, model)):
                    continue
                files = (obj, *mtl_files(obj), *texture_files(obj)) if os.path.isfile(obj) else (obj,)
                items.append(SourceItem(key=f"{synset}/{model}", files=files,
                                        meta={"synset": synset, "model": model}))  # fmt: skip
        return drop_excluded(items, exclude)

    def read(self, root: str, item: SourceItem) -> SourceAsset:
        root = os.path.abspath(root)
        synset, _, model = item.key.partition("/")
        tax, subs = self._metadata(root)
        sub = subs.get((synset, model))
        found = classify(synset, sub, tax)
        if found is None:
            name = tax.get(sub or synset, tax.get(synset, {})).get("name", "not in taxonomy.json")
            raise SourceError("no category", f"ShapeNet synset {sub or synset} ({name}) is not "
                                             "a road-scene class; add it to "
                                             "catalog.sources.shapenet.SYNSETS if it should be")  # fmt: skip
        path = os.path.join(root, synset, model, MODEL_FILE)
        if not os.path.isfile(path):
            raise SourceError("missing mesh", f"{path} does not exist (ShapeNetCore v2 layout "
                                              "<synset>/<model>/models/model_normalized.obj)")  # fmt: skip
        parts = load_parts(path)
        cls_name, subclass = found
        return SourceAsset(
            source=self.kind,
            source_path=path,
            licence=LICENCE,
            category=cls_name,
            subclass=subclass,
            parts=tuple(parts),
            up="+y",
            forward="-z",
            units="unknown",
            normalized=True,
            target_length=None,
            licence_required=False,
            notes=tuple(missing_file_notes(path, parts)),
        )
