"""The viewer's ``--pred P --gt G`` mode: a prediction tree against its ground-truth tree, paired
and read as ``carlaocc eval ssc`` pairs and reads them (:mod:`carlaocc.catalog.formats.predictions`),
each frame on the grid its export's ``grid.json`` states, with the root's boxes, cameras and ego
when ``--root`` is given and the file's path names a root frame. The viewer itself (drawing, the
GUI, the root's own frames) is :mod:`carlaocc.pipeline.commands.viewer`; a :class:`PairFrames` is
one of its frame sources."""

from __future__ import annotations

import re
import time
from pathlib import Path

import numpy as np

from carlaocc.catalog.samples import DatasetError, FrameSamples
from carlaocc.catalog.sensors import LidarStore, SensorStore
from carlaocc.catalog.store import Store
from carlaocc.pipeline.commands.viewer import FrameView, Labels, ViewerError, add_overlays
from carlaocc.schemas import taxonomy
from carlaocc.stages.render.viewer import OUTCOMES, label_colours, level_of_detail, surface_voxels, voxel_centres


def sample_of_key(key: str, samples: FrameSamples) -> int | None:
    """The sample of ``samples`` a paired file's key names (``gts/<seq>/<seq>_<frame:06d>/labels``
    of an Occ3D tree, ``<seq>/<frame:06d>`` of a carlaocc-npz one): a path component that is one
    of the root's sequence ids, and the frame the last component after it ending in digits
    gives; None when the key names none (the release layout renames sequences)."""
    parts = key.split("/")
    seqs = {seq for seq, _ in samples.samples}
    at = next((k for k, p in enumerate(parts) if p in seqs), None)
    if at is None:
        return None
    for p in reversed(parts[at + 1:]):
        m = re.search(r"(\d+)$", p)
        if m:
            try:
                return samples.samples.index((parts[at], int(m.group(1))))
            except ValueError:
                return None
    return None


def pair_frames(pred: Path, gt: Path, map_name: str = "carlaocc", table: str | None = None,
                ignore: tuple[int, ...] = (255,)) -> "PairFrames":
    """A prediction tree against its ground-truth tree, paired and read as ``carlaocc eval ssc``
    pairs and reads them (by relative path without suffix; labels in ``map_name``), each frame on
    the grid its export's ``grid.json`` states."""
    from carlaocc.catalog.formats.predictions import InputError, pair_files
    from carlaocc.stages.evaluation import label_map

    try:
        lm = label_map(map_name, table)
    except ValueError as exc:
        raise ViewerError(f"--map / --taxonomy: {exc}") from None
    try:
        pairs = pair_files(pred, gt, (".npz", ".npy"))
    except InputError as exc:
        raise ViewerError(str(exc)) from None
    return PairFrames(pairs, lm, tuple(ignore), gt)


class PairFrames:
    """Paired prediction / ground-truth files (``pairs``: key, prediction, ground truth) in the
    label space ``lm``; ``gt`` the ground-truth tree, where ``grid.json`` is looked for."""

    def __init__(self, pairs: list, lm, ignore: tuple[int, ...], gt: Path, indices: list[int] | None = None,
                 root: FrameSamples | None = None) -> None:
        self.pairs, self.lm, self.ignore, self.gt, self.root = pairs, lm, ignore, Path(gt), root
        self.indices = list(range(len(pairs))) if indices is None else list(indices)
        self.names = [pairs[k][0] for k in self.indices]
        colours = label_colours(lm.from_carlaocc)
        self.labels = Labels(tuple(lm.names), colours, frozenset(lm.things))
        self.has_pred = True
        self.grids = [self.grid(k) for k in range(len(self.indices))]
        self.voxel_size = self.grids[0]["voxel_size"] if self.grids else 1.0
        self.title = f"**{self.gt.name}** ({lm.name} labels) against a prediction"

    def __len__(self) -> int:
        return len(self.indices)

    def select(self, indices: list[int]) -> "PairFrames":
        return PairFrames(self.pairs, self.lm, self.ignore, self.gt, indices, self.root)

    def with_root(self, root: str) -> "PairFrames":
        """The same pairs with a root's overlays (cameras, boxes, LiDAR) on the frames whose keys
        name one of its samples, in the grid's frame (ego or LiDAR)."""
        try:
            samples = FrameSamples(root, occupancy="none", cameras=False, lidar=False, boxes=False)
            cams = {seq: bool(SensorStore(Store(root)).cameras(seq)) for seq in {q for q, _ in samples.samples}}
            lidar = bool(samples.samples) and LidarStore(Store(root)).exists(*samples.samples[0])
            samples = FrameSamples(root, voxel_size=samples.voxel_size, occupancy="none", cameras=all(cams.values()),
                                   camera_maps=("depth", "semantic") if all(cams.values()) else (), lidar=lidar,
                                   boxes=True)
        except DatasetError as exc:
            raise ViewerError(str(exc)) from None
        return PairFrames(self.pairs, self.lm, self.ignore, self.gt, self.indices, samples)

    def grid(self, k: int) -> dict:
        """The grid of frame ``k`` from the grid.json nearest above its ground-truth file (the
        export's); without one, voxel indices (origin 0, 1 m) in an unknown frame."""
        from carlaocc.catalog.formats.manifest import find_grid_manifest, grid_of

        gf = self.pairs[self.indices[k]][2]
        try:
            found = find_grid_manifest(gf)
            if found is None:
                return {"origin": (0.0, 0.0, 0.0), "voxel_size": 1.0, "shape": None, "frame": None}
            doc, folder = found
            return grid_of(doc, Path(gf).resolve().relative_to(folder))
        except ValueError as exc:
            raise ViewerError(f"--gt {self.gt}: {exc}") from None

    def prepare(self, k: int, budget: int) -> FrameView:
        from carlaocc.catalog.formats.predictions import InputError, load_occupancy

        t0 = time.perf_counter()
        _, pf, gf = self.pairs[self.indices[k]]
        try:
            p_sem, _, _ = load_occupancy(pf, self.lm, False)
            g_sem, g_inst, masks = load_occupancy(gf, self.lm, False)
        except InputError as exc:
            raise ViewerError(str(exc)) from None
        grid = self.grids[k]
        if p_sem.shape != g_sem.shape:
            raise ViewerError(f"--pred {pf}: shape {p_sem.shape} differs from the ground truth {gf} {g_sem.shape}")
        if grid["shape"] is not None and tuple(g_sem.shape) != grid["shape"]:
            raise ViewerError(f"--gt {gf}: shape {tuple(g_sem.shape)}, but its grid.json's grid is {grid['shape']}")
        p_sem, g_sem = (self._labels(a, path) for a, path in ((p_sem, pf), (g_sem, gf)))
        view = prepare_pair(p_sem, g_sem, g_inst, masks, self.lm.free, self.ignore, grid, budget, t0)
        at = None if self.root is None or grid["frame"] not in ("ego", "lidar") else \
            sample_of_key(self.pairs[self.indices[k]][0], self.root)
        if at is not None:
            add_overlays(view, self.root, at, self.root[at], grid["frame"])
            view.seconds = time.perf_counter() - t0
        return view

    def _labels(self, a: np.ndarray, path: Path) -> np.ndarray:
        """``a`` as uint8 labels, every one an id of the map or an ignored id (else the one-line
        error naming the file and the map)."""
        lo, hi = (int(a.min()), int(a.max())) if a.size else (0, 0)
        valid = np.zeros(256, bool)
        valid[[i for i in (*range(self.lm.n), *self.ignore) if 0 <= i < 256]] = True
        if lo < 0 or hi > 255:
            bad = lo if lo < 0 else hi
        else:
            a = a.astype(np.uint8, copy=False)
            # a lookup per voxel, no sort (a 0.1 m grid has 51 M voxels)
            ok = valid[a]
            bad = None if ok.all() else int(a.reshape(-1)[np.argmin(ok.reshape(-1))])
        if bad is not None:
            raise ViewerError(f"{path}: label {bad} is not an id of --map {self.lm.name} (0..{self.lm.n - 1}, "
                              f"or --ignore); pick the map the tree is in")
        return a

    def masks(self, k: int, view: FrameView) -> FrameView:
        return view


def prepare_pair(p_sem: np.ndarray, g_sem: np.ndarray, g_inst: np.ndarray | None, masks: dict, free: int | None,
                 ignore: tuple[int, ...], grid: dict, budget: int, t0: float | None = None) -> FrameView:
    """A prediction against its ground truth, both dense uint8 label grids of one shape: the surface of
    the voxels either side occupies (any label but ``free`` and ``ignore``: void ground truth and
    an abstaining prediction are free), their outcome, the class shown, the ground truth's masks
    (observed where it has none), placed by ``grid`` (origin, voxel size)."""
    t0 = time.perf_counter() if t0 is None else t0
    shape = g_sem.shape
    void = np.zeros(256, bool)
    void[[i for i in (*ignore, *(() if free is None else (free,))) if 0 <= i < 256]] = True
    g_sem, p_sem = g_sem.reshape(-1), p_sem.reshape(-1)
    # occupied on either side by one lookup per voxel, then each side's label at those voxels
    g_occ, p_occ = ~void[g_sem], ~void[p_sem]
    flat = np.flatnonzero(g_occ | p_occ)
    g, p, g_on, p_on = g_sem[flat], p_sem[flat], g_occ[flat], p_occ[flat]
    # the outcome codes of OUTCOMES, and the class shown: the prediction's, or the truth's it missed
    outcome = np.where(~g_on, 1, np.where(~p_on, 2, np.where(g == p, 0, 3))).astype(np.uint8)
    shown = np.where(p_on, p, g).astype(np.uint8)
    ijk = np.column_stack(np.unravel_index(flat, shape)).astype(np.int64)
    surf = np.flatnonzero(surface_voxels(ijk, shape))
    ijk, outcome, sem = ijk[surf], outcome[surf], shown[surf]
    inst = np.zeros(len(ijk), np.uint32) if g_inst is None else g_inst[tuple(ijk.T)].astype(np.uint32)
    mcam, mlid = (masks[n][tuple(ijk.T)].astype(bool) if n in masks and masks[n].shape == shape
                  else np.ones(len(ijk), bool) for n in ("mask_camera", "mask_lidar"))
    keep, factor = level_of_detail(ijk, budget)
    origin, voxel_size = np.asarray(grid["origin"], np.float64), float(grid["voxel_size"])
    view = FrameView(centres=voxel_centres(ijk[keep], origin, voxel_size), semantic=sem[keep], instance=inst[keep],
                     mask_camera=mcam[keep], mask_lidar=mlid[keep], outcome=outcome[keep],
                     point_size=voxel_size * factor, occupied=len(flat), ijk=ijk[keep])
    if grid.get("frame") == "ego":
        view.ego = np.eye(4)
    view.seconds = time.perf_counter() - t0
    return view
