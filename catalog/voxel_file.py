"""The standalone voxelizer's output files (``carlaocc voxelize --out``): the one place that writes
and reads them (:func:`save_voxels` / :func:`load_voxels`).

Three layouts:

* **Sparse npz** (the default for ``OUT.npz``; ``format_version`` 1): the occupied voxels only, so
  the file and the work to write it grow with the occupied voxels, not with the grid. Arrays:

  ================  ==============  ===========================================================
  ``format``        str             ``"carlaocc.voxels"``
  ``format_version`` int64          1
  ``layout``        str             ``"sparse"``
  ``voxel_size``    float64         voxel edge, metres
  ``voxel_origin``  float64 (3,)    minimum corner of voxel (0, 0, 0), metres
  ``shape``         int64 (3,)      X, Y, Z
  ``voxel_index``   uint32 (N,)     occupied voxels' linear indices ``(i * Y + j) * Z + k``,
                                    ascending (int64 for grids of more than 2**32 voxels)
  ``voxel_semantic`` uint8 (N,)     their semantic ids (> 0)
  ``voxel_instance`` uint32 (N,)    their instance ids (0 for stuff)
  ================  ==============  ===========================================================

  ``voxel_index`` is stored uncompressed, the labels deflated (level 1: they are long runs).
  The dense arrays with numpy alone::

      d = np.load("OUT.npz")
      semantic = np.zeros(d["shape"], np.uint8); semantic.flat[d["voxel_index"]] = d["voxel_semantic"]
      instance = np.zeros(d["shape"], np.uint32); instance.flat[d["voxel_index"]] = d["voxel_instance"]

  or ``load_voxels("OUT.npz").dense()``; ``np.unravel_index(d["voxel_index"], d["shape"])``
  gives the voxels' ``(i, j, k)``.
* **Dense npz** (``--dense``; the layout before format 1, no ``format`` key): ``semantic`` uint8
  and ``instance`` uint32 of ``shape``, ``voxel_size``, ``voxel_origin``, ``shape``, deflated.
* **Zarr** (``OUT.zarr``): a Zarr v3 group with ``semantic`` and ``instance`` arrays of ``shape``
  carrying the grid attributes, chunks of 128 x 128 x Z voxels; chunks holding no occupied
  voxel are not written (Zarr reads them as zeros). Written an x-slab at a time.

Every writer writes beside the target and renames, so a failed write leaves no partial file.
"""

from __future__ import annotations

import shutil
import zipfile
from pathlib import Path

import numpy as np

from carlaocc.schemas import taxonomy
from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.voxels import SparseVoxels

__all__ = ["save_voxels", "load_voxels", "VOXEL_FILE_FORMAT", "VOXEL_FILE_VERSION", "VoxelFileError"]

VOXEL_FILE_FORMAT = "carlaocc.voxels"
VOXEL_FILE_VERSION = 1
ZARR_CHUNK_XY = 128


class VoxelFileError(ValueError):
    """A file that is not one of the layouts above; the message names it."""


def _grid(origin, shape, voxel_size) -> GridSpec:
    origin = tuple(float(c) for c in origin)
    hi = tuple(o + int(n) * float(voxel_size) for o, n in zip(origin, shape))
    return GridSpec(region_min=origin, region_max=hi, voxel_size=float(voxel_size))


def _header(grid: GridSpec) -> dict[str, np.ndarray]:
    return {"voxel_size": np.float64(grid.voxel_size), "voxel_origin": np.asarray(grid.origin, np.float64),
            "shape": np.asarray(grid.shape, np.int64)}


def _write_npz(path: Path, arrays: dict[str, np.ndarray], stored: set[str]) -> None:
    """An npz (a zip of .npy members, what ``np.load`` reads): ``stored`` members uncompressed,
    the others deflated at level 1."""
    with zipfile.ZipFile(path, "w", allowZip64=True) as zf:
        for name, arr in arrays.items():
            zf.compression = zipfile.ZIP_STORED if name in stored else zipfile.ZIP_DEFLATED
            zf.compresslevel = None if name in stored else 1
            with zf.open(f"{name}.npy", "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, np.asanyarray(arr), allow_pickle=False)


def save_voxels(voxels: SparseVoxels, out: Path, dense: bool = False) -> None:
    """Write ``voxels`` to ``out``: ``.npz`` sparse (``dense``: the dense layout) or ``.zarr``."""
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in (".npz", ".zarr"):
        raise VoxelFileError(f"--out must end in .npz or .zarr, got {out}")
    out.parent.mkdir(parents=True, exist_ok=True)
    g = voxels.grid
    if suffix == ".npz":
        tmp = out.with_name(out.name + ".tmp.npz")
        if dense:
            semantic, instance = voxels.dense()
            np.savez_compressed(tmp, semantic=semantic, instance=instance, **_header(g))
        else:
            index_dtype = np.uint32 if int(np.prod(g.shape, dtype=np.int64)) <= 2**32 else np.int64
            arrays = {"format": np.str_(VOXEL_FILE_FORMAT), "format_version": np.int64(VOXEL_FILE_VERSION),
                      "layout": np.str_("sparse"), **_header(g),
                      "voxel_index": voxels.index.astype(index_dtype, copy=False),
                      "voxel_semantic": voxels.semantic.astype(np.uint8, copy=False),
                      "voxel_instance": voxels.instance.astype(np.uint32, copy=False)}
            _write_npz(tmp, arrays, stored={"voxel_index"})
        tmp.replace(out)
        return
    _save_zarr(voxels, out)


def _save_zarr(voxels: SparseVoxels, out: Path) -> None:
    import zarr

    g = voxels.grid
    X, Y, Z = (int(s) for s in g.shape)
    tmp = out.with_name(out.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    root = zarr.open_group(str(tmp), mode="w")
    cx = min(ZARR_CHUNK_XY, X)
    chunks = (cx, min(ZARR_CHUNK_XY, Y), Z)
    attrs = {**g.attrs(), "dims": ["x", "y", "z"], "taxonomy_version": taxonomy.TAXONOMY_VERSION}
    arrays = {name: root.create_array(name, shape=(X, Y, Z), chunks=chunks, dtype=dtype, fill_value=0,
                                      attributes=attrs)
              for name, dtype in (("semantic", np.uint8), ("instance", np.uint32))}
    plane = Y * Z
    # one x-slab of chunks at a time: dense only for that slab; Zarr skips all-zero chunks
    for x0 in range(0, X, cx):
        x1 = min(x0 + cx, X)
        lo, hi = np.searchsorted(voxels.index, [x0 * plane, x1 * plane])
        if lo == hi:
            continue
        local = voxels.index[lo:hi] - x0 * plane
        for name, values in (("semantic", voxels.semantic), ("instance", voxels.instance)):
            if name == "instance" and not values[lo:hi].any():
                continue
            slab = np.zeros((x1 - x0, Y, Z), dtype=arrays[name].dtype)
            slab.reshape(-1)[local] = values[lo:hi]
            arrays[name][x0:x1] = slab
    if out.exists():
        shutil.rmtree(out)
    tmp.rename(out)


def load_voxels(path: str | Path) -> SparseVoxels:
    """The voxels of a file :func:`save_voxels` wrote (any layout, any earlier version);
    :class:`VoxelFileError` naming the file otherwise. ``.dense()`` gives the dense arrays."""
    path = Path(path)
    if path.suffix.lower() == ".zarr":
        import zarr

        try:
            root = zarr.open_group(str(path), mode="r")
            sem, inst = root["semantic"], root["instance"]
            attrs = dict(sem.attrs)
            grid = _grid(attrs["origin"], attrs["shape"], attrs["voxel_size"])
            return SparseVoxels.from_dense(grid, sem[...], inst[...])
        except (KeyError, FileNotFoundError, ValueError) as exc:
            raise VoxelFileError(f"{path}: not a voxel grid written by carlaocc voxelize ({exc})") from None
    try:
        with np.load(path, allow_pickle=False) as d:
            keys = set(d.files)
            if "voxel_index" in keys:
                version = int(d["format_version"])
                if str(d["format"]) != VOXEL_FILE_FORMAT or version > VOXEL_FILE_VERSION:
                    raise VoxelFileError(f"{path}: format {str(d['format'])!r} version {version}: this carlaocc "
                                         f"reads {VOXEL_FILE_FORMAT!r} up to version {VOXEL_FILE_VERSION}; "
                                         f"update carlaocc")
                grid = _grid(d["voxel_origin"], d["shape"], d["voxel_size"])
                return SparseVoxels(grid, d["voxel_index"], d["voxel_semantic"], d["voxel_instance"])
            if {"semantic", "instance", "voxel_origin", "voxel_size"} <= keys:
                grid = _grid(d["voxel_origin"], d["semantic"].shape, d["voxel_size"])
                return SparseVoxels.from_dense(grid, d["semantic"], d["instance"])
    except (OSError, zipfile.BadZipFile, ValueError, KeyError) as exc:
        if isinstance(exc, VoxelFileError):
            raise
        raise VoxelFileError(f"{path}: cannot read it as a voxel grid ({type(exc).__name__}: {exc})") from None
    raise VoxelFileError(f"{path}: holds neither voxel_index (sparse layout) nor semantic/instance (dense layout): "
                         f"not written by carlaocc voxelize")
