"""Training data loader throughput (:class:`carlaocc.data.CarlaOccDataset`) on a built root.

Two measurements, no thresholds:

1. occupancy alone, one process: our sparse gather (chunk by chunk, only the frame's chunks)
   against what a user would otherwise write with zarr-python (``zarr.open_array`` on the five
   occupancy arrays, ``arr[frame]``, ``np.nonzero``, the other arrays at those voxels), frames/s
   and the ratio; both must give the same rows;
2. whole samples (sparse occupancy, the six RGB images, LiDAR, boxes) through a real
   ``torch.utils.data.DataLoader`` (batch 1, :func:`carlaocc.data.collate`) with 1 and 4 worker
   processes: frames/s and each worker's peak resident memory (``ru_maxrss``).

Usage: ``python -m benchmarks.bench_loader --root R [--voxel-size 0.2] [--frames 24] [--workers 1,4]``
(the root must be built at ``--voxel-size``: ``carlaocc run --voxel-size 0.05 --limit-frames 4 --root R``).
"""

from __future__ import annotations

import argparse
import resource
import time

import numpy as np

from carlaocc.data import CarlaOccDataset, collate


class _WithMemory:
    """The dataset, each sample tagged with the worker's pid and its peak resident memory."""

    def __init__(self, ds: CarlaOccDataset):
        self.ds = ds

    def __len__(self) -> int:
        return len(self.ds)

    def __getitem__(self, i: int) -> dict:
        import os

        s = self.ds[i]
        s["_pid"] = os.getpid()
        s["_maxrss_mib"] = _peak_mib()
        return s


def _peak_mib() -> float:
    """This process's peak resident memory (VmHWM; ``ru_maxrss`` would carry the parent's peak
    across fork + exec)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _zarr_rows(root: str, seq: str, key: str, frame: int) -> dict:
    """The zarr-python way: the five arrays' frame, then the occupied voxels, as the loader
    returns them (the same keys and dtypes)."""
    import zarr

    arrays = {n: zarr.open_array(f"{root}/occupancy.zarr/{seq}/{key}/{n}", mode="r")[frame]
              for n in ("semantic", "instance", "flow", "mask_camera", "mask_lidar")}
    sem = arrays["semantic"]
    i, j, k = np.nonzero(sem)
    occ = np.empty((len(i), 4), np.int32)
    occ[:, 0], occ[:, 1], occ[:, 2], occ[:, 3] = i, j, k, sem[i, j, k]
    return {"occ": occ, "occ_instance": arrays["instance"][i, j, k], "occ_flow": arrays["flow"][i, j, k].astype(np.float32),
            "occ_mask_camera": arrays["mask_camera"][i, j, k].astype(bool),
            "occ_mask_lidar": arrays["mask_lidar"][i, j, k].astype(bool)}


def occupancy_only(root: str, voxel_size: float, frames: int) -> None:
    from carlaocc.schemas.grid import voxel_size_key

    ds = CarlaOccDataset(root, voxel_size=voxel_size, cameras=False, lidar=False, boxes=False)
    idx = list(range(min(frames, len(ds))))
    key = voxel_size_key(voxel_size)
    ds[idx[0]]  # warm the per-process tables, imports and page cache for both sides
    _zarr_rows(root, ds.samples[idx[0]][0], key, ds.samples[idx[0]][1])
    t_ours = t_zarr = 0.0
    for i in idx:  # alternate the two, frame by frame (the same cache state for both)
        t = time.perf_counter()
        a = ds[i]
        t_ours += time.perf_counter() - t
        t = time.perf_counter()
        b = _zarr_rows(root, ds.samples[i][0], key, ds.samples[i][1])
        t_zarr += time.perf_counter() - t
        assert all(np.array_equal(a[k], b[k]) for k in b), "rows differ"
        del a, b  # a 0.05 m frame's rows are ~0.4 GB a side
    n = len(idx)
    voxels = int(np.prod(ds[idx[0]]["grid_shape"]))
    print(f"occupancy alone at {voxel_size:g} m ({voxels / 1e6:.1f} M voxels a frame, {n} frames, one process):")
    print(f"  carlaocc.data sparse  {n / t_ours:7.2f} frames/s")
    print(f"  zarr-python + nonzero {n / t_zarr:7.2f} frames/s   ratio x{t_zarr / t_ours:.2f} (same rows)")


def whole_samples(root: str, voxel_size: float, frames: int, workers: list[int]) -> None:
    import torch

    ds = CarlaOccDataset(root, voxel_size=voxel_size)
    sub = torch.utils.data.Subset(_WithMemory(ds), list(range(min(frames, len(ds)))))
    print(f"whole samples at {voxel_size:g} m (sparse occupancy, {len(ds[0]['camera_names'])} RGB images, LiDAR, boxes):")
    for w in workers:
        loader = torch.utils.data.DataLoader(sub, batch_size=1, num_workers=w, collate_fn=collate,
                                             multiprocessing_context="spawn" if w else None)
        t = time.perf_counter()
        rss: dict[int, float] = {}
        n, t_first = 0, None
        for batch in loader:
            for pid, m in zip(batch["_pid"], batch["_maxrss_mib"]):
                rss[int(pid)] = max(rss.get(int(pid), 0.0), float(m))
            n += len(batch["_pid"])
            if t_first is None:
                t_first = time.perf_counter()  # the workers are up (and have read a frame each)
        dt = time.perf_counter() - t
        steady = (n - max(w, 1)) / max(time.perf_counter() - t_first, 1e-9) if n > max(w, 1) else float("nan")
        print(f"  {max(w, 1)} {'worker process' if w else 'process (no workers)'}{'es' if w > 1 else ''}: "
              f"{steady:6.2f} frames/s once started ({n} frames in {dt:.1f} s with start-up); peak memory per "
              f"worker {max(rss.values()):.0f} MiB")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--root", required=True, help="a built root")
    ap.add_argument("--voxel-size", "--res", dest="voxel_size", type=float, default=0.2, help="voxel size (m) it was built at (--res is the short alias)")
    ap.add_argument("--frames", type=int, default=48, help="frames to read (the first of the index)")
    ap.add_argument("--workers", default="1,4", help="DataLoader worker counts, comma-separated")
    a = ap.parse_args()
    occupancy_only(a.root, a.voxel_size, a.frames)
    whole_samples(a.root, a.voxel_size, a.frames, [int(w) for w in a.workers.split(",")])


if __name__ == "__main__":
    main()
