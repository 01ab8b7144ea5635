"""Built-in OpenDRIVE towns shipped with carlaocc, and the resolver for ``TownSpec.opendrive``.

``builtin:<name>`` names a file of this package (e.g. ``builtin:crossroads.xodr``, an original
4-way + two T-junction town of the project); any other reference is a filesystem path.
"""

from __future__ import annotations

import pathlib

__all__ = ["BUILTIN_PREFIX", "builtin_names", "resolve_opendrive"]

BUILTIN_PREFIX = "builtin:"
_HERE = pathlib.Path(__file__).resolve().parent


def builtin_names() -> list[str]:
    """File names of the shipped OpenDRIVE towns, sorted (e.g. ``["crossroads.xodr"]``)."""
    return sorted(p.name for p in _HERE.glob("*.xodr") if p.is_file())


def resolve_opendrive(ref: str) -> pathlib.Path:
    """``"builtin:<name>"`` -> the shipped file; anything else -> ``Path(ref)``.

    Raises ``ValueError`` for an empty reference or a built-in name that is not a plain file
    name, ``FileNotFoundError`` naming the reference when the file does not exist."""
    if not isinstance(ref, str) or not ref.strip():
        raise ValueError(f"OpenDRIVE reference {ref!r} is empty; give a .xodr path or builtin:<name>")
    if ref.startswith(BUILTIN_PREFIX):
        name = ref[len(BUILTIN_PREFIX):].strip()
        if not name or pathlib.PurePath(name).name != name or name in (".", ".."):
            raise ValueError(f"OpenDRIVE reference {ref!r}: builtin:<name> needs a plain file name; "
                             f"available: {builtin_names()}")  # fmt: skip
        path = _HERE / name
        if not path.is_file():
            raise FileNotFoundError(f"OpenDRIVE reference {ref!r}: no built-in town {name!r}; available: {builtin_names()}")
        return path
    path = pathlib.Path(ref).expanduser()
    if not path.is_file():
        what = "is a directory, not a .xodr file" if path.is_dir() else "does not exist"
        raise FileNotFoundError(f"OpenDRIVE reference {ref!r}: {path} {what}")
    return path
