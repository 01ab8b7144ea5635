"""Any directory of mesh files, classified by a category map.

Layout accepted
    ``root`` and every sub-directory (hidden ones skipped), files ending (any case) in ``.obj``
    (with its ``.mtl``), ``.ply``, ``.stl``, ``.off``, ``.glb``, ``.gltf`` or ``.dae``. One item
    per file; its key is the path relative to ``root`` with ``/`` separators.

Category map (``category_map=``, a CSV path; relative paths are taken from ``root``)
    A header row is required. Columns, by header name:

    ========= ======== ===============================================================
    glob      required fnmatch pattern on the path relative to root (``/`` separators,
                       case-sensitive; ``*`` also crosses directories)
    category  required taxonomy class name (any case/separators, CARLA spellings); empty:
                       the matched files are explicitly excluded ("no category")
    subclass  required a sub-class of that class; empty: the class's first sub-class
    length_m  optional real length in metres -> ``target_length`` (empty: unknown)
    up        optional declared up axis (``+x``...``-z``), overriding the format default
    forward   optional declared forward axis, overriding the format default
    units     optional declared units (m, cm, mm, in, unknown); default unknown
    ========= ======== ===============================================================

    Rows are tried in file order; the first match wins. A file no row matches is listed, and
    reading it raises ``SourceError("no category")``: categories are never guessed. A malformed
    map (missing column, unknown column, unknown class or sub-class, bad length or axis) makes
    :meth:`FolderAdapter.list_items` raise ``SourceError("bad category map")`` naming the line.

Declarations
    units ``"unknown"`` unless the map says otherwise, for every format, glTF included: the glTF
    spec says metres, but game kits (Kenney's are ~1 unit per road tile) use arbitrary units, so
    sizes are inferred from the sub-class size range downstream. Axes default by format
    (:func:`carlaocc.catalog.sources._common.default_axes`): glTF +y up / +z forward (the spec), COLLADA
    from its ``<up_axis>``, others +z / +x.

Licence
    The ``License:`` line (else the first line) of the nearest ``LICENSE*.txt`` / ``LICENCE*.txt``
    in the file's directory or a parent up to ``root``; ``""`` if none. Not required.
"""

from __future__ import annotations

import csv
import fnmatch
import math
import os
import stat

from carlaocc.catalog.sources._common import (
    UNITS,
    check_axes,
    check_subclass,
    default_axes,
    default_subclass,
    find_licence_file,
    is_excluded,
    is_mesh_file,
    licence_text,
    load_parts,
    missing_file_notes,
    semantic_class,
    sidecar_files,
)
from carlaocc.catalog.sources.base import SourceError, SourceItem
from carlaocc.schemas.meshes import SourceAsset

_REQUIRED = ("glob", "category", "subclass")
_OPTIONAL = ("length_m", "up", "forward", "units")


def _bad(path: str, line: int | None, why: str) -> SourceError:
    where = f"{path}, line {line}" if line is not None else path
    return SourceError("bad category map", f"{where}: {why}")


def read_category_map(path: str) -> list[dict]:
    """Parse and validate a category map; rows as dicts (``line`` = 1-based file line)."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            rows = list(csv.reader(f))
    except FileNotFoundError:
        raise _bad(path, None, "file not found") from None
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise _bad(path, None, f"cannot read: {e}") from None
    if not rows:
        raise _bad(path, 1, f"empty; the header row must name {', '.join(_REQUIRED)}")
    header = [h.strip().lower() for h in rows[0]]
    missing = [c for c in _REQUIRED if c not in header]
    if missing:
        raise _bad(path, 1, f"header {rows[0]} lacks column(s) {', '.join(missing)} "
                            f"(columns: {', '.join(_REQUIRED)}[, {', '.join(_OPTIONAL)}])")  # fmt: skip
    unknown = [h for h in header if h not in _REQUIRED + _OPTIONAL]
    if unknown:
        raise _bad(path, 1, f"unknown column(s) {', '.join(unknown)}; "
                            f"allowed: {', '.join(_REQUIRED + _OPTIONAL)}")  # fmt: skip
    if len(set(header)) != len(header):
        raise _bad(path, 1, "a column is named twice")
    out = []
    for no, raw in enumerate(rows[1:], start=2):
        if not any(c.strip() for c in raw) or raw[0].lstrip().startswith("#"):
            continue  # blank lines and comments
        if len(raw) != len(header):
            raise _bad(path, no, f"{len(raw)} fields, header has {len(header)}")
        row = {h: v.strip() for h, v in zip(header, raw)}
        if not row["glob"]:
            raise _bad(path, no, "empty glob")
        entry: dict = {"line": no, "glob": row["glob"], "category": None, "subclass": "",
                       "length_m": None, "up": None, "forward": None, "units": "unknown"}  # fmt: skip
        if row["category"]:
            try:
                cls = semantic_class(row["category"])
            except KeyError as e:
                raise _bad(path, no, str(e.args[0])) from None
            sub = row["subclass"] or default_subclass(cls)
            why = check_subclass(cls, sub)
            if why:
                raise _bad(path, no, why)
            entry["category"], entry["subclass"] = cls.name, sub
        if row.get("length_m"):
            try:
                length = float(row["length_m"])
            except ValueError:
                length = float("nan")
            if not (math.isfinite(length) and length > 0):
                raise _bad(path, no, f"length_m {row['length_m']!r} is not a positive number")
            entry["length_m"] = length
        up, fwd = row.get("up") or None, row.get("forward") or None
        if up or fwd:
            if not (up and fwd):
                raise _bad(path, no, "give both up and forward, or neither")
            why = check_axes(up, fwd)
            if why:
                raise _bad(path, no, why)
            entry["up"], entry["forward"] = up, fwd
        if row.get("units"):
            if row["units"] not in UNITS:
                raise _bad(path, no, f"units {row['units']!r} not one of {', '.join(UNITS)}")
            entry["units"] = row["units"]
        out.append(entry)
    return out


def match_row(rel: str, rows: list[dict]) -> dict | None:
    """The first row whose glob matches ``rel`` (fnmatchcase, ``/`` paths)."""
    for row in rows:
        if fnmatch.fnmatchcase(rel, row["glob"]):
            return row
    return None


class FolderAdapter:
    """A directory tree of mesh files + a CSV category map (see the module docstring)."""

    kind = "folder"

    def __init__(self, category_map: str | None = None):
        self.category_map = category_map

    def _map_path(self, root: str) -> str | None:
        if not self.category_map:
            return None
        return os.path.abspath(os.path.join(root, self.category_map))

    def _rows(self, root: str) -> list[dict]:
        path = self._map_path(root)
        return read_category_map(path) if path else []

    def list_items(self, root: str, exclude: tuple[str, ...] = ()) -> list[SourceItem]:
        root = os.path.abspath(root)
        if not os.path.isdir(root):
            raise SourceError("missing mesh", f"{root} is not a directory")
        rows = self._rows(root)
        map_path = self._map_path(root)
        items = []
        for d, dirs, files in os.walk(root):
            dirs[:] = sorted(x for x in dirs if not x.startswith(".")
                             and not is_excluded(os.path.join(d, x), exclude))
            if exclude and is_excluded(d, exclude):  # the root itself is excluded
                dirs[:] = []
                continue
            for name in sorted(files):
                path = os.path.join(d, name)
                if name.startswith(".") or not is_mesh_file(name):
                    continue
                # a FIFO, socket or device named like a mesh is never opened; a dangling link or
                # a link loop (stat fails) is listed, and reported when read
                try:
                    regular = stat.S_ISREG(os.stat(path).st_mode)
                except OSError:
                    regular = True
                if not regular:
                    continue
                rel = os.path.relpath(path, root).replace(os.sep, "/")
                row = match_row(rel, rows)
                files_ = [path, *sidecar_files(path)]
                lic = find_licence_file(path, root)
                if lic:
                    files_.append(lic)
                meta = {"category_map": map_path, "row": row}
                items.append(SourceItem(key=rel, files=tuple(files_), meta=meta))
        items.sort(key=lambda it: it.key)
        return items

    def read(self, root: str, item: SourceItem) -> SourceAsset:
        root = os.path.abspath(root)
        path = os.path.join(root, item.key)
        row = item.meta["row"] if "row" in item.meta else match_row(item.key, self._rows(root))
        if row is None or row.get("category") is None:
            where = self._map_path(root) or "no category map given (category_map=...)"
            if row is None:
                hint = (f"add a row to the category map matching {item.key!r} "
                        f"(columns glob,category,subclass[,length_m]); map: {where}")  # fmt: skip
            else:
                hint = f"excluded by the row {row['glob']!r} of {where} (empty category)"
            raise SourceError("no category", hint)
        parts = load_parts(path)
        up, forward = default_axes(path)
        if row.get("up"):
            up, forward = row["up"], row["forward"]
        lic = find_licence_file(path, root)
        return SourceAsset(
            source=self.kind,
            source_path=path,
            licence=licence_text(lic) if lic else "",
            category=row["category"],
            subclass=row["subclass"],
            parts=tuple(parts),
            up=up,
            forward=forward,
            units=row.get("units", "unknown"),
            normalized=False,
            target_length=row.get("length_m"),
            licence_required=False,
            notes=tuple(missing_file_notes(path, parts)),
        )
