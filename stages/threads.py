"""How many threads the compiled kernels of this process may use (numba, open3d's ray casting,
OpenCV inside D2NT). A LocalCluster runs one worker process per core, so the pipeline caps every
kernel at one thread there instead of letting each library oversubscribe the machine."""

from __future__ import annotations

_THREADS = 0  # 0: each library's own default (all cores)


def set_kernel_threads(n: int | None) -> None:
    """Cap the kernels of this process at ``n`` threads (None or 0: no cap)."""
    global _THREADS
    _THREADS = int(n or 0)
    if not _THREADS:
        return
    import numba  # 0.3 s to import: paid only when a thread count is set

    numba.set_num_threads(min(_THREADS, numba.config.NUMBA_NUM_THREADS))
    try:
        import cv2
    except ImportError:  # pragma: no cover - cv2 comes with d2nt
        return
    cv2.setNumThreads(_THREADS)


def kernel_threads() -> int:
    """The cap (0 = none), as open3d's ``nthreads`` arguments take it."""
    return _THREADS
