"""Per-thread scratch buffers reused between calls (frames, tiles, ray sets).

A fresh multi-hundred-megabyte ``np.zeros`` is cheap to allocate but every first touch of its
pages is a page fault; at 0.05 m that costs more than the voxelization itself. Buffers here stay
mapped for the life of the thread (a Dask worker thread), keyed by name; callers zero what they
need (zeroing mapped memory is ~30x cheaper than faulting in fresh pages).
"""

from __future__ import annotations

import threading

import numpy as np

_LOCAL = threading.local()


def scratch(name: str, size: int, dtype, zero: bool = False) -> np.ndarray:
    """A flat buffer of ``size`` elements of ``dtype``, private to the calling thread and reused
    by the next call with the same ``name`` (its contents are then overwritten: copy what you
    keep). ``zero`` clears it first."""
    cache = getattr(_LOCAL, "cache", None)
    if cache is None:
        cache = _LOCAL.cache = {}
    buf = cache.get(name)
    if buf is None or buf.size < size or buf.dtype != np.dtype(dtype):
        buf = cache[name] = np.zeros(max(int(size), 1), dtype=dtype)
        return buf[:size]
    out = buf[:size]
    if zero:
        out[:] = 0
    return out
