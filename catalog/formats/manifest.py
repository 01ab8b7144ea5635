"""What every export writes beside its files: ``grid.json`` (the grid or grids its files index
and how an index becomes metres) and ``splits/{train,val,test}.txt``. The one writer of both."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path

from carlaocc.catalog.formats import atomic_write

INDEX_TO_METRE = "centre = origin + (index + 0.5) * voxel_size"


def grid_manifest(fmt: str, frame: str, grids: Sequence[Mapping], labels: Sequence[str], free_label: int,
                  label_table: str | None, encoding: str | None = None, notes: Mapping | None = None) -> dict:
    """The ``grid.json`` document of an export.

    ``frame``: the frame the indices are in (``"lidar"``, ``"ego"``), axes x forward, y left, z up;
    ``grids``: one or more ``{"origin": [x, y, z] m, "voxel_size": m, "shape": [nx, ny, nz]}``
    (several, each with its ``"folder"``, when the export writes a grid per folder); ``labels``
    the class names by label id, ``free_label`` the id of free space; ``label_table`` the
    dataset's label table the labels were mapped from; ``encoding`` how instance ids are packed
    into labels (CarlaOcc layouts); ``notes`` extra keys (units of flow...)."""
    doc: dict = {"format": fmt, "frame": f"{frame} (x forward, y left, z up)"}
    if len(grids) == 1 and "folder" not in grids[0]:
        g = grids[0]
        doc |= {"origin": list(g["origin"]), "voxel_size": g["voxel_size"], "shape": list(g["shape"])}
    doc |= {"axis_order": ["x", "y", "z"], "index_to_metre": INDEX_TO_METRE, "labels": list(labels),
            "free_label": free_label}
    if encoding is not None:
        doc["label_encoding"] = encoding
    if label_table is not None:
        doc["built_from_label_table"] = label_table
    if len(grids) > 1 or "folder" in grids[0]:
        doc["grids"] = [{"folder": g["folder"], "voxel_size": g["voxel_size"], "origin": list(g["origin"]),
                         "shape": list(g["shape"])} for g in grids]
    return doc | dict(notes or {})


def save_grid_manifest(out: Path, manifest: Mapping) -> int:
    """Write ``out/grid.json``; returns the files written (1)."""
    atomic_write(Path(out) / "grid.json", lambda fh: fh.write(json.dumps(manifest, indent=1).encode()))
    return 1


def save_split_lists(out: Path, lines: Mapping[str, Sequence[str]]) -> int:
    """Write ``out/splits/<split>.txt`` for every split of ``lines``, one line each (a sequence
    id, or a frame in the release's layout); returns the files written."""
    for split, rows in lines.items():
        atomic_write(Path(out) / "splits" / f"{split}.txt", lambda fh, b="".join(f"{r}\n" for r in rows).encode(): fh.write(b))
    return len(lines)


def find_grid_manifest(file: Path) -> tuple[dict, Path] | None:
    """The ``grid.json`` nearest above ``file`` (its own folder first, then each parent: a file
    deep in an export's tree finds the export's) and the folder holding it, or None;
    ``ValueError`` naming a grid.json that is not a JSON object."""
    file = Path(file).resolve()
    for folder in [file.parent, *file.parent.parents]:
        path = folder / "grid.json"
        if path.is_file():
            try:
                doc = json.loads(path.read_text())
            except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
                raise ValueError(f"{path}: unreadable ({exc})") from None
            if not isinstance(doc, dict):
                raise ValueError(f"{path}: not a grid.json (a JSON object)")
            return doc, folder
    return None


def grid_of(manifest: Mapping, relative: Path) -> dict:
    """``{"origin", "voxel_size", "shape", "frame"}`` of the grid a file at ``relative`` (to the
    grid.json's folder) indexes: the manifest's one grid, or the grid whose ``folder`` is one of
    the path's folders (an export writing a grid per folder); ``frame`` is ``"ego"`` or
    ``"lidar"``. ``ValueError`` when no grid fits or a key is missing."""
    grids = manifest.get("grids")
    if grids:
        parts = set(Path(relative).parts[:-1])
        hit = [g for g in grids if g.get("folder") in parts]
        if len(hit) != 1:
            raise ValueError(f"no grid of grid.json's {[g.get('folder') for g in grids]} is a folder of {relative}")
        g = hit[0]
    else:
        g = manifest
    try:
        frame = str(manifest["frame"]).split()[0]
        return {"origin": tuple(float(v) for v in g["origin"]), "voxel_size": float(g["voxel_size"]),
                "shape": tuple(int(v) for v in g["shape"]), "frame": frame}
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"grid.json: no usable grid for {relative} ({type(exc).__name__}: {exc})") from None
