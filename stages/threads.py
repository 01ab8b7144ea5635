"""How many threads the compiled kernels of this process may use: numba's parallel kernels, the
BLAS (OpenBLAS, MKL) and OpenMP runtimes loaded in the process (numpy's, OpenCV's, open3d's),
OpenCV inside D2NT, and open3d's ray casting (its ``nthreads`` arguments, from
:func:`kernel_threads`). A LocalCluster runs one single-threaded worker per core, so the pipeline
caps every kernel at one thread there instead of letting each library start a thread per core
in every worker (:func:`thread_report` says what a process ended up with)."""

from __future__ import annotations

_THREADS = 0  # 0: each library's own default (all cores)
_LIMITED: set[int] = set()  # the caps already applied to the runtimes loaded in this process
# read by OpenBLAS, MKL and OpenMP when they load (the executor sets them for its worker processes)
THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def set_kernel_threads(n: int | None) -> None:
    """Cap the kernels of this process at ``n`` threads (None or 0: no cap). numba's count is
    per calling thread (a Dask worker's task thread calls this before each task); the others are
    per process."""
    global _THREADS
    _THREADS = int(n or 0)
    if not _THREADS:
        return
    # 1. numba's parallel kernels (numba 0.3 s to import: paid only when a thread count is set)
    import numba

    numba.set_num_threads(min(_THREADS, numba.config.NUMBA_NUM_THREADS))
    # 2. OpenCV's own pool (D2NT's reference filters); importing it loads its BLAS before 3.
    try:
        import cv2
    except ImportError:  # pragma: no cover - cv2 comes with d2nt
        cv2 = None
    if cv2 is not None:
        cv2.setNumThreads(_THREADS)
    # 3. the BLAS and OpenMP runtimes loaded in this process (numpy's, OpenCV's...), through
    #    threadpoolctl: once per process and cap (6 ms a call)
    if _THREADS not in _LIMITED:
        from threadpoolctl import threadpool_limits

        threadpool_limits(limits=_THREADS)
        _LIMITED.clear()
        _LIMITED.add(_THREADS)


def kernel_threads() -> int:
    """The cap (0 = none), as open3d's ``nthreads`` arguments take it."""
    return _THREADS


def thread_report() -> dict:
    """The threads this process's kernels may use now: ``numba`` (this thread's count), ``cv2``,
    ``open3d`` (the ``nthreads`` its casts get: 0 = all cores) and ``pools``, one entry per BLAS or
    OpenMP runtime loaded (``threadpoolctl``'s ``internal_api``, ``num_threads``)."""
    import numba
    from threadpoolctl import threadpool_info

    out: dict = {"numba": numba.get_num_threads(), "open3d": _THREADS,
                 "pools": [{"api": i["internal_api"], "threads": i["num_threads"]} for i in threadpool_info()]}
    try:
        import cv2

        out["cv2"] = cv2.getNumThreads()
    except ImportError:  # pragma: no cover - cv2 comes with d2nt
        pass
    return out
