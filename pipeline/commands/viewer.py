"""``carlaocc view``: a sequence of a built root in a web viewer (viser: a Python server, a
three.js client in the browser, usable through SSH port forwarding), and ``--save``: the same
scene as one offline HTML page.

Two sources of frames, one viewer (:class:`Viewer`, :func:`save_html`):

* :class:`RootFrames`: a root's sequence. A frame's surface is read chunk by chunk
  (:func:`read_surface`: never the dense or the whole sparse frame), its masks only when a display
  asks (:func:`load_masks`); cameras, their maps, LiDAR and actor boxes through
  :class:`carlaocc.catalog.samples.FrameSamples`. With ``--pred``, prediction files on the root's
  grid.
* :class:`~carlaocc.pipeline.commands.viewer_pairs.PairFrames` (``--pred P --gt G``, in
  :mod:`carlaocc.pipeline.commands.viewer_pairs`): a prediction tree against its ground-truth tree,
  paired and read by ``carlaocc eval ssc``'s own functions (:mod:`carlaocc.catalog.formats.predictions`)
  in its label space (``--map``), each frame on the grid and in the frame of the export's
  ``grid.json`` (:mod:`carlaocc.catalog.formats.manifest`).

What is drawn is prepared by the pure functions of :mod:`carlaocc.stages.render.viewer`. One scene
node per class (``/voxels/<Class>``), so a class toggles without re-sending anything; a frame
switch replaces the nodes' arrays.
"""

from __future__ import annotations

import contextlib
import io
import logging
import re
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.samples import DatasetError, FrameSamples
from carlaocc.catalog.sensors import LidarStore, SensorStore
from carlaocc.catalog.store import Store
from carlaocc.schemas import taxonomy
from carlaocc.stages.geometry import boxes_in_frame
from carlaocc.stages.render.colours import height_ramp
from carlaocc.stages.render.viewer import (OUTCOME_COLOURS, OUTCOMES, block_surface, box_edges, camera_frustum,
                                           class_colours, flow_arrows, ghost, label_colours, level_of_detail,
                                           linear_index, prediction_outcome, surface_voxels, voxel_centres)

DEFAULT_BUDGET = 400_000
"""Surface voxels drawn per frame before the level of detail coarsens (x2 per step)."""
COLOUR_MODES = ("semantic", "instance", "outcome")
UNOBSERVED = ("show", "ghost", "hide")
INITIAL_CAMERA = ((-22.0, 0.0, 18.0), (12.0, 0.0, 0.0))
"""Position and target (m, LiDAR frame) of the first view: behind and above the ego, looking ahead."""
IMAGE_WIDTH = 320  # camera images are sent at this width (the frustums are small on screen)


class ViewerError(ValueError):
    """A bad option or input of ``carlaocc view``; the message names it and what to do."""


@dataclass
class FrameView:
    """One frame, prepared: surface voxels (after the level of detail) with their classes,
    instances, masks, outcome against a prediction; the overlays; how long preparing took."""

    centres: np.ndarray          # (N, 3) float32 m, LiDAR frame
    semantic: np.ndarray         # (N,) uint8 (the prediction's class where it has one, with --pred)
    instance: np.ndarray         # (N,) uint32
    mask_camera: np.ndarray | None   # (N,) bool; None until a display needs it (read_masks)
    mask_lidar: np.ndarray | None    # (N,) bool
    outcome: np.ndarray | None   # (N,) uint8 codes of OUTCOMES, with --pred
    point_size: float            # m: the voxel size times the level-of-detail factor
    occupied: int                # occupied voxels of the frame (before surface and LOD)
    arrows: tuple = ()           # (start, end) float32 (M, 3) m
    boxes: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 3), np.float32))
    box_labels: list = field(default_factory=list)   # (text, position)
    points: np.ndarray | None = None                  # LiDAR (P, 3) m
    points_semantic: np.ndarray | None = None
    cameras: list = field(default_factory=list)       # dicts: name, fov, aspect, wxyz, position, rgb/semantic/depth
    ego: np.ndarray | None = None                     # (4, 4) ego-to-LiDAR
    seconds: float = 0.0
    ijk: np.ndarray | None = None                     # (N, 3) int64 grid indices of the drawn voxels


def open_frames(root: str, seq: str | None, voxel_size: float | None) -> FrameSamples:
    """The frames of sequence ``seq`` (the root's first when None) at ``voxel_size`` (its finest
    when None), with cameras, camera maps and LiDAR where the root has them; the occupancy is
    read by :func:`read_surface` (only the surface), or whole for a prediction."""
    try:
        index = FrameSamples(root, voxel_size=voxel_size, occupancy="none", cameras=False, lidar=False, boxes=False,
                             sequences=None if seq is None else [seq])
    except DatasetError as exc:
        raise ViewerError(str(exc)) from None
    seqs = sorted({s for s, _ in index.samples})
    if not seqs:
        raise ViewerError(f"{root}: sequence {seq} has no frames")
    seq = seqs[0] if seq is None else seq
    store = Store(root)
    cameras = bool(SensorStore(store).cameras(seq))
    lidar = LidarStore(store).exists(seq, index.samples[0][1]) if index.samples else False
    return FrameSamples(root, voxel_size=index.voxel_size, occupancy="none", cameras=cameras,
                        camera_maps=("depth", "semantic") if cameras else (), lidar=lidar, boxes=True,
                        sequences=[seq])


def read_surface(occ: OccupancyStore, seq: str, grid, frame: int, flow: bool = True) -> dict:
    """The surface voxels of one stored frame (:func:`carlaocc.stages.render.viewer.block_surface`),
    read chunk by chunk and never assembled: ``ijk`` (N, 3) int64 in C order, ``semantic``,
    ``instance`` and, with ``flow``, ``flow`` (m/s; zero off things) at them, and ``occupied``
    (the frame's occupied voxel count). Reads every semantic chunk once, an instance chunk where
    the frame has one, a flow chunk only where a surface voxel is a thing's; the masks are read
    by :func:`read_at` when a display needs them."""
    shape, chunks, _ = occ.layout(seq, grid, "semantic")
    X, Y = shape[1], shape[2]
    cx, cy = chunks[1], chunks[2]
    nx, ny = -(-X // cx), -(-Y // cy)
    names = {n for n in ("instance", "flow") if _has_array(occ, seq, grid, n)}
    rows: dict[int, list] = {}

    def row(ci: int) -> list:
        # a row of semantic chunks along y, read once and kept until the next row is done
        if ci not in rows:
            rows[ci] = [occ.read_chunk(seq, grid, frame, "semantic", ci, cj) for cj in range(ny)]
        return rows[ci]

    parts: dict[str, list] = {"ijk": [], "semantic": [], "instance": [], "flow": []}
    occupied = 0
    for ci in range(nx):
        here, first = row(ci), len(parts["ijk"])
        for cj, block in enumerate(here):
            if block is None:
                continue
            count = int(np.count_nonzero(block))
            occupied += count
            # the neighbours' facing planes (a missing chunk or the grid's border: free)
            prev = rows.get(ci - 1, [None] * ny)[cj] if ci > 0 else None
            nxt = row(ci + 1)[cj] if ci + 1 < nx else None
            flat = block_surface(block, None if prev is None else prev[-1], None if nxt is None else nxt[0],
                                 None if cj == 0 or here[cj - 1] is None else here[cj - 1][:, -1],
                                 None if cj + 1 == ny or here[cj + 1] is None else here[cj + 1][:, 0], count)
            ii, jj, kk = np.unravel_index(flat, block.shape)
            parts["ijk"].append(np.column_stack([ii + ci * cx, jj + cj * cy, kk]).astype(np.int64))
            parts["semantic"].append(block[ii, jj, kk])
            inst = occ.read_chunk(seq, grid, frame, "instance", ci, cj) if "instance" in names else None
            inst = np.zeros(len(flat), np.uint32) if inst is None else inst[ii, jj, kk].astype(np.uint32)
            parts["instance"].append(inst)
            if flow:
                things = np.flatnonzero(inst)
                f = np.zeros((len(flat), 3), np.float32)
                block_flow = occ.read_chunk(seq, grid, frame, "flow", ci, cj) \
                    if len(things) and "flow" in names else None
                if block_flow is not None:
                    f[things] = block_flow[ii[things], jj[things], kk[things]]
                parts["flow"].append(f)
        rows.pop(ci - 1, None)
        # C order over the grid: a row of chunks holds its voxels chunk after chunk along y, each
        # in C order, so a stable sort on i alone orders them (i, j, k)
        if len(parts["ijk"]) > first:
            order = np.argsort(np.concatenate([a[:, 0] for a in parts["ijk"][first:]]), kind="stable")
            for key in ("ijk", "semantic", "instance") + (("flow",) if flow else ()):
                parts[key][first:] = [np.concatenate(parts[key][first:])[order]]
    empty = {"ijk": np.zeros((0, 3), np.int64), "semantic": np.zeros(0, np.uint8),
             "instance": np.zeros(0, np.uint32), "flow": np.zeros((0, 3), np.float32)}
    out = {k: np.concatenate(v) if v else empty[k] for k, v in parts.items() if k != "flow" or flow}
    out["occupied"] = occupied
    return out


def read_at(occ: OccupancyStore, seq: str, grid, frame: int, name: str, ijk: np.ndarray) -> np.ndarray:
    """Array ``name`` of one stored frame at the voxels ``ijk`` (N, 3), reading only the chunks
    they fall in (zero where a chunk is not stored)."""
    shape, chunks, dtype = occ.layout(seq, grid, name)
    cx, cy = chunks[1], chunks[2]
    out = np.zeros((len(ijk), *shape[4:]), dtype)
    if not len(ijk):
        return out
    # the voxels grouped by chunk, each group read from its one chunk
    key = (ijk[:, 0] // cx) * (-(-shape[2] // cy)) + ijk[:, 1] // cy
    order = np.argsort(key, kind="stable")
    bounds = np.flatnonzero(np.diff(key[order])) + 1
    for group in np.split(order, bounds):
        i, j, k = ijk[group].T
        ci, cj = int(i[0] // cx), int(j[0] // cy)
        block = occ.read_chunk(seq, grid, frame, name, ci, cj)
        if block is not None:
            out[group] = block[i - ci * cx, j - cj * cy, k]
    return out


def _has_array(occ: OccupancyStore, seq: str, grid, name: str) -> bool:
    try:
        occ.layout(seq, grid, name)
        return True
    except ValueError:
        return False


def prediction_files(pred: Path, seq: str, frames: list[int]) -> dict[int, Path]:
    """The prediction file of every frame: ``<pred>/<seq>/<frame:06d>.npz`` (the layout of
    ``carlaocc export carlaocc-npz``, which ``carlaocc eval`` reads); a missing one is an error."""
    if not pred.is_dir():
        raise ViewerError(f"--pred {pred}: not a directory (a prediction tree <seq>/<frame:06d>.npz on the root's grid)")
    out = {}
    for f in frames:
        p = pred / seq / f"{f:06d}.npz"
        if not p.is_file():
            raise ViewerError(f"--pred {pred}: no prediction for {seq} frame {f} (expected {p})")
        out[f] = p
    return out


def load_prediction(path: Path, shape) -> tuple[np.ndarray, np.ndarray]:
    """``(flat indices, classes)`` of the occupied voxels of one prediction file on a grid of
    ``shape``: a CarlaOcc npz (``occupancy`` rows) or an npz whose ``semantics`` is the dense grid
    in CarlaOcc ids (0 free), as ``carlaocc eval ssc --map carlaocc`` reads them."""
    from carlaocc.catalog.formats import FormatError
    from carlaocc.catalog.formats.carlaocc_npz import load_carlaocc_rows

    shape = tuple(int(s) for s in shape)
    try:
        with np.load(path, allow_pickle=False) as z:
            files = list(z.files)
            sem = z["semantics"] if "semantics" in files and "occupancy" not in files else None
    except (OSError, ValueError, EOFError) as exc:
        raise ViewerError(f"--pred: {path} unreadable ({exc})") from None
    if sem is None:
        try:
            rows = load_carlaocc_rows(path)
        except (FormatError, ValueError) as exc:
            raise ViewerError(f"--pred: {path}: {exc} (a CarlaOcc npz or an npz with 'semantics')") from None
        if tuple(rows.volume_size) != shape:
            raise ViewerError(f"--pred: {path} is a {tuple(rows.volume_size)} grid, the root's is {shape}")
        return linear_index(rows.index, shape), rows.semantic.astype(np.uint8)
    if sem.shape != shape or not np.issubdtype(sem.dtype, np.integer):
        raise ViewerError(f"--pred: {path}: 'semantics' is {sem.dtype} {sem.shape}, the root's grid is {shape} "
                          f"(integer CarlaOcc ids)")
    flat = np.flatnonzero(sem)
    return flat.astype(np.int64), sem.reshape(-1)[flat].astype(np.uint8)


def _sparse_frame(samples: FrameSamples, index: int) -> dict:
    """Sample ``index`` with its whole occupancy as sparse rows (what a prediction is scored on)."""
    seq, frame = samples.samples[index]
    full = FrameSamples(samples.root, voxel_size=samples.voxel_size, occupancy="sparse", cameras=False, lidar=False,
                        boxes=False, sequences=[seq])
    return full[full.samples.index((seq, frame))]


def load_masks(samples: FrameSamples, index: int, view: FrameView) -> FrameView:
    """``view`` with its voxels' camera and LiDAR masks (read once, when a display first needs them)."""
    if view.mask_camera is None:
        seq, frame = samples.samples[index]
        occ, grid = OccupancyStore(Store(samples.root)), samples.grid(seq)
        for name in ("mask_camera", "mask_lidar"):
            m = read_at(occ, seq, grid, frame, name, view.ijk) if _has_array(occ, seq, grid, name) \
                else np.ones(len(view.ijk), np.uint8)
            setattr(view, name, m.astype(bool))
    return view


def _thumbnail(image: np.ndarray, width: int = IMAGE_WIDTH) -> np.ndarray:
    step = max(1, image.shape[1] // width)
    return np.ascontiguousarray(image[::step, ::step])


def prepare_frame(samples: FrameSamples, index: int, pred: Path | None = None,
                  budget: int = DEFAULT_BUDGET) -> FrameView:
    """Reads sample ``index`` and prepares what the viewer draws (timed in ``seconds``)."""
    t0 = time.perf_counter()
    s = samples[index]
    seq = s["sequence_id"]
    shape = tuple(int(v) for v in s["grid_shape"])
    origin, voxel_size = np.asarray(s["grid_origin"], np.float64), float(s["voxel_size"])
    outcome, mcam, mlid = None, None, None
    if pred is None:
        # only the surface, read chunk by chunk; the masks wait until a display asks for them
        surf = read_surface(OccupancyStore(Store(samples.root)), seq, samples.grid(seq), int(s["frame_index"]))
        ijk, sem, inst, flow, occupied = surf["ijk"], surf["semantic"], surf["instance"], surf["flow"], surf["occupied"]
    else:
        # the union of both sides' occupied voxels, each with its outcome and the class shown
        full = _sparse_frame(samples, index)
        rows = full["occ"]
        ijk, sem = rows[:, :3].astype(np.int64), rows[:, 3].astype(np.uint8)
        n = len(rows)
        inst = full.get("occ_instance", np.zeros(n, np.uint32))
        flow = full.get("occ_flow", np.zeros((n, 3), np.float32))
        mcam = full.get("occ_mask_camera", np.ones(n, bool))
        mlid = full.get("occ_mask_lidar", np.ones(n, bool))
        gt_flat = linear_index(ijk, shape)
        p_flat, p_cls = load_prediction(pred, shape)
        flat, outcome, shown = prediction_outcome(gt_flat, sem, p_flat, p_cls)
        at = np.searchsorted(gt_flat, flat)
        in_gt = (at < n) & (gt_flat[np.minimum(at, n - 1)] == flat)
        take = np.minimum(at, n - 1)
        inst = np.where(in_gt, inst[take], 0).astype(np.uint32)
        flow = np.where(in_gt[:, None], flow[take], 0).astype(np.float32)
        mcam, mlid = np.where(in_gt, mcam[take], True), np.where(in_gt, mlid[take], True)
        ijk = np.column_stack(np.unravel_index(flat, shape)).astype(np.int64)
        sem = shown
        occupied = len(flat)
        # the surface of the union
        surf = np.flatnonzero(surface_voxels(ijk, shape))
        ijk, sem, inst, flow, mcam, mlid, outcome = (a[surf] for a in (ijk, sem, inst, flow, mcam, mlid, outcome))
    # flow arrows from the surface voxels of each moving thing
    things = inst != 0
    arrows = flow_arrows(voxel_centres(ijk[things], origin, voxel_size), inst[things], flow[things])[:2]
    keep, factor = level_of_detail(ijk, budget)
    view = FrameView(centres=voxel_centres(ijk[keep], origin, voxel_size), semantic=sem[keep], instance=inst[keep],
                     mask_camera=None if mcam is None else mcam[keep], mask_lidar=None if mlid is None else mlid[keep],
                     outcome=None if outcome is None else outcome[keep], point_size=voxel_size * factor,
                     occupied=occupied, arrows=arrows, ijk=ijk[keep])
    add_overlays(view, samples, index, s, "lidar")
    view.seconds = time.perf_counter() - t0
    return view


@dataclass(frozen=True)
class Labels:
    """A label space as the viewer shows it: ``names[id]``, ``colours`` (256, 3) uint8 by id,
    the ``things`` ids (coloured by instance in ``instance`` mode)."""

    names: tuple[str, ...]
    colours: np.ndarray
    things: frozenset

    def name(self, cid: int) -> str:
        return self.names[cid] if 0 <= cid < len(self.names) else f"label {cid}"


ROOT_LABELS = Labels(tuple(c.name for c in taxonomy.label_table().classes), np.asarray(
    taxonomy.palette() + ((0, 0, 0),) * (256 - len(taxonomy.palette())), np.uint8), frozenset(taxonomy.thing_ids()))
"""A root's labels: the CarlaOcc classes in the label table's palette."""


def add_overlays(view: FrameView, samples: FrameSamples, index: int, s: dict, frame: str = "lidar") -> FrameView:
    """Puts the root's overlays of sample ``index`` (``s`` = ``samples[index]``) into ``view``, in
    ``frame`` (``"lidar"``, the root's grids; ``"ego"``, Occ3D's): the actor boxes with their class
    and id, the LiDAR points, the ego's axes, the cameras with their images."""
    if frame not in ("lidar", "ego"):
        raise ValueError(f"frame {frame!r}: lidar or ego")
    lidar_to_frame = np.eye(4) if frame == "lidar" else s["lidar_to_ego"]
    world_to_frame = np.linalg.inv(s["lidar_pose"] if frame == "lidar" else s["ego_pose"])
    boxes = boxes_in_frame(samples.actor_rows(index), world_to_frame)
    view.boxes = box_edges(boxes["box_pose"], boxes["boxes"][:, 3:6])
    view.box_labels = [(f"{taxonomy.by_id(int(c)).name} #{int(i)}",
                        boxes["boxes"][k, :3] + np.array([0, 0, boxes["boxes"][k, 5] / 2 + 0.3]))
                       for k, (i, c) in enumerate(zip(boxes["box_instance"], boxes["box_semantic"]))]
    if "points" in s:
        pts = s["points"].astype(np.float64) @ lidar_to_frame[:3, :3].T + lidar_to_frame[:3, 3]
        view.points, view.points_semantic = pts.astype(np.float32), s["points_semantic"]
    view.ego = lidar_to_frame @ np.linalg.inv(s["lidar_to_ego"])  # ego-to-frame
    view.cameras = []
    for c, name in enumerate(s.get("camera_names", [])):
        rgb = s["images"][c]
        h, w = rgb.shape[:2]
        cam = camera_frustum(s["cam_intrinsics"][c], lidar_to_frame @ s["cam_to_lidar"][c], w, h)
        # thumbnails first, then coloured: only the pixels sent are coloured
        depth, semantic = _thumbnail(s["cam_depth"][c]), _thumbnail(s["cam_semantic"][c])
        cam.update(name=name, rgb=_thumbnail(rgb),
                   semantic=class_colours(semantic.reshape(-1)).reshape(*semantic.shape, 3),
                   depth=np.round(height_ramp(np.nan_to_num(depth, posinf=80.0) / 80.0)).astype(np.uint8))
        view.cameras.append(cam)
    return view


def voxel_colours(view: FrameView, mode: str, unobserved: str, mask: str,
                  labels: Labels = ROOT_LABELS) -> tuple[np.ndarray, np.ndarray]:
    """``(colours (N, 3) uint8, shown (N,) bool)`` of a frame's voxels: coloured by ``mode``, and
    those ``mask`` (camera | lidar) marks unobserved shown, ghosted or hidden."""
    if mode == "outcome" and view.outcome is not None:
        col = OUTCOME_COLOURS[view.outcome]
    else:
        col = class_colours(view.semantic, view.instance, "instance" if mode == "instance" else "semantic",
                            labels.colours)
    shown = np.ones(len(col), bool)
    if unobserved == "show":
        return col, shown
    observed = view.mask_camera if mask == "camera" else view.mask_lidar
    if observed is None:
        raise ValueError("the frame's masks are not loaded (load_masks)")
    if unobserved == "ghost":
        col = ghost(col, observed)
    elif unobserved == "hide":
        shown = observed.copy()
    return col, shown


class RootFrames:
    """The frames of a root's sequence the viewer shows (sample ``indices``), each optionally
    against a prediction file on the root's grid (``preds`` by frame index)."""

    def __init__(self, samples: FrameSamples, preds: dict[int, Path] | None = None,
                 indices: list[int] | None = None) -> None:
        self.samples, self.preds = samples, preds
        self.indices = list(range(len(samples))) if indices is None else list(indices)
        self.frame_ids = [samples.samples[k][1] for k in self.indices]
        self.names = [str(f) for f in self.frame_ids]
        self.labels, self.has_pred, self.voxel_size = ROOT_LABELS, preds is not None, samples.voxel_size
        self.title = f"**{samples.samples[0][0]}** at {samples.voxel_size:g} m" + (" against a prediction" if preds else "")

    def __len__(self) -> int:
        return len(self.indices)

    def prepare(self, k: int, budget: int) -> FrameView:
        return prepare_frame(self.samples, self.indices[k], None if self.preds is None else self.preds[self.frame_ids[k]],
                             budget)

    def masks(self, k: int, view: FrameView) -> FrameView:
        return load_masks(self.samples, self.indices[k], view)


class Viewer:
    """The live scene of one sequence or tree on a viser server: a timeline, per-class toggles,
    colour modes, masks and overlays (GUI on the right), one scene node per class."""

    def __init__(self, server, source, budget: int, first: int = 0, prepared: dict | None = None) -> None:
        self.server, self.source, self.budget = server, source, budget
        self.labels: Labels = source.labels
        self.cache: dict[int, FrameView] = dict(prepared or {})  # frames prepared already, by index
        self.lock = threading.Lock()  # guards the cache: GUI callbacks and the prefetch run in other threads
        self.nodes: dict[int, object] = {}
        self.overlays: list = []
        gui = server.gui
        preds = source.has_pred
        gui.add_markdown(source.title)
        if preds:
            gui.add_markdown(legend_text(True))
        last = max(len(source) - 1, 0)
        self.frame = gui.add_slider("frame", min=0, max=last, step=1, initial_value=min(max(first, 0), last))
        self.mode = gui.add_dropdown("colour", COLOUR_MODES if preds else COLOUR_MODES[:2],
                                     initial_value="outcome" if preds else "semantic")
        self.mask = gui.add_dropdown("mask", ("camera", "lidar"), initial_value="camera")
        self.unobserved = gui.add_dropdown("unobserved", UNOBSERVED, initial_value="show")
        with gui.add_folder("layers"):
            self.show_flow = gui.add_checkbox("flow", True)
            self.show_boxes = gui.add_checkbox("boxes", True)
            self.show_lidar = gui.add_checkbox("LiDAR", False)
            self.show_cameras = gui.add_checkbox("cameras", True)
            self.image = gui.add_dropdown("camera image", ("rgb", "semantic", "depth"), initial_value="rgb")
        self.status = gui.add_markdown("")
        self.class_boxes: dict[int, object] = {}
        self.class_folder = gui.add_folder("classes")
        with self.class_folder:
            self.class_legend = gui.add_markdown("")
        for handle in (self.frame, self.mode, self.mask, self.unobserved, self.show_flow, self.show_boxes,
                       self.show_lidar, self.show_cameras, self.image):
            handle.on_update(lambda _: self.draw())
        self.draw()

    def view(self, k: int) -> FrameView:
        """Frame ``k``, prepared once and kept (the last 8)."""
        with self.lock:
            v = self.cache.get(k)
        if v is None:
            # prepared outside the lock: a redraw of a cached frame never waits for a prefetch
            v = self.source.prepare(k, self.budget)
            with self.lock:
                v = self.cache.setdefault(k, v)
                while len(self.cache) > 8:
                    self.cache.pop(next(iter(self.cache)))
        return v

    def prefetch(self, k: int) -> None:
        """Prepares frame ``k`` in the background (the next frame while the current one is looked
        at), so stepping forward along the timeline finds it ready."""
        if 0 <= k < len(self.source) and k not in self.cache:
            def work() -> None:
                # a frame that cannot be prepared is said in the status line when it is shown
                # (view() raises the same error again then)
                with contextlib.suppress(ViewerError):
                    self.view(k)
            threading.Thread(target=work, daemon=True).start()

    def _class_box(self, cid: int):
        if cid not in self.class_boxes:
            with self.class_folder:
                box = self.server.gui.add_checkbox(self.labels.name(cid), True)
            box.on_update(lambda _, c=cid: self._toggle(c))
            self.class_boxes[cid] = box
        return self.class_boxes[cid]

    def _toggle(self, cid: int) -> None:
        node = self.nodes.get(cid)
        if node is not None:
            node.visible = bool(self.class_boxes[cid].value)

    def draw(self) -> None:
        """(Re)draws the current frame with the current settings; a frame that cannot be read
        (a prediction of another shape...) says why in the status line."""
        k = int(self.frame.value)
        try:
            v = self.view(k)
        except ViewerError as exc:
            self.status.content = f"frame {wrappable(self.source.names[k])}: error: {exc}"
            return
        if self.unobserved.value != "show":
            self.source.masks(k, v)
        draw_frame(self.server.scene, v, self.mode.value, self.unobserved.value, self.mask.value, self.nodes,
                   self.overlays, flow=self.show_flow.value, boxes=self.show_boxes.value, lidar=self.show_lidar.value,
                   cameras=self.show_cameras.value, image=self.image.value,
                   visible={c: bool(b.value) for c, b in self.class_boxes.items()}, labels=self.labels)
        for cid in np.unique(v.semantic):
            self._class_box(int(cid))
        for cid in self.class_boxes:
            self._toggle(cid)
        self.class_legend.content = class_legend_text(sorted(self.class_boxes), self.mode.value, self.labels)
        lod = "" if v.point_size <= self.source.voxel_size * 1.01 else \
            f", level of detail {v.point_size:g} m (budget {self.budget:,})"
        self.status.content = (f"frame {wrappable(self.source.names[k])}: {len(v.centres):,} surface voxels of "
                               f"{v.occupied:,}{lod}; prepared in {v.seconds:.2f} s")
        self.prefetch(k + 1)


def wrappable(name: str) -> str:
    """``name`` (a frame's path in a prediction tree can be long) with a zero-width space after
    each ``/``, so the panel's status line wraps it there instead of running out of the panel."""
    return name.replace("/", "/\u200b")


def draw_frame(scene, v: FrameView, mode: str, unobserved: str, mask: str, nodes: dict, overlays: list, *,
               flow: bool = True, boxes: bool = True, lidar: bool = False, cameras: bool = True, image: str = "rgb",
               visible: dict | None = None, labels: Labels = ROOT_LABELS) -> None:
    """Puts frame ``v`` into a viser scene: one point cloud per class (``nodes``, by label id:
    replaced, or removed when the class is absent) and the overlays (removed and drawn again)."""
    col, shown = voxel_colours(v, mode, unobserved, mask, labels)
    present = set()
    for cid in np.unique(v.semantic):
        cid = int(cid)
        sel = (v.semantic == cid) & shown
        if not sel.any():
            continue
        present.add(cid)
        if cid in nodes:
            nodes[cid].remove()
        nodes[cid] = scene.add_point_cloud(f"/voxels/{labels.name(cid).replace(' ', '_')}", v.centres[sel], col[sel],
                                           point_size=v.point_size, point_shape="square", point_shading="flat",
                                           precision="float32", visible=(visible or {}).get(cid, True))
    for cid in [c for c in nodes if c not in present]:
        nodes.pop(cid).remove()
    for handle in overlays:
        handle.remove()
    overlays.clear()
    if flow and len(v.arrows) and len(v.arrows[0]):
        start, end = v.arrows
        overlays.append(scene.add_line_segments("/flow", np.stack([start, end], 1), colors=(255, 0, 255),
                                                thickness=0.08))
    if boxes and len(v.boxes):
        overlays.append(scene.add_line_segments("/boxes/edges", v.boxes, colors=(255, 255, 0), thickness=0.04))
        for k, (text, pos) in enumerate(v.box_labels):
            overlays.append(scene.add_label(f"/boxes/label_{k}", text, position=tuple(float(x) for x in pos)))
    if lidar and v.points is not None:
        overlays.append(scene.add_point_cloud("/lidar", v.points, class_colours(v.points_semantic), point_size=0.06,
                                              point_shape="circle", point_shading="flat"))
    if v.ego is not None:
        from carlaocc.stages.geometry import quaternion_wxyz

        overlays.append(scene.add_frame("/ego", axes_length=1.5, axes_radius=0.05,
                                        wxyz=tuple(quaternion_wxyz(v.ego[:3, :3])), position=tuple(v.ego[:3, 3])))
    if cameras:
        for cam in v.cameras:
            overlays.append(scene.add_camera_frustum(f"/cameras/{cam['name']}", fov=cam["fov"], aspect=cam["aspect"],
                                                     scale=0.6, image=cam[image], wxyz=tuple(cam["wxyz"]),
                                                     position=tuple(cam["position"]), color=(40, 40, 40)))


def class_legend_text(class_ids, mode: str, labels: Labels = ROOT_LABELS) -> str:
    """The classes' colour legend (Markdown) above their toggles: each class's swatch in the label
    space's colours when voxels are coloured by class (``semantic``), the stuff classes' swatches
    when things are coloured by instance, nothing in ``outcome`` mode (its legend is at the top)."""
    if mode == "outcome":
        return ""
    shown = [c for c in class_ids if (c or labels is not ROOT_LABELS) and (mode == "semantic" or c not in labels.things)]
    swatches = ", ".join(f"<span style='color:rgb{tuple(int(x) for x in labels.colours[c])}'>&#9632;</span> "
                         f"{labels.name(c)}" for c in shown)
    if mode == "semantic":
        return f"class colours: {swatches}"
    return f"things: a colour per instance; stuff: {swatches}" if swatches else "things: a colour per instance"


def legend_text(preds: bool) -> str:
    """The outcome legend (Markdown) shown with ``--pred``."""
    if not preds:
        return ""
    names = [f"<span style='color:rgb{tuple(int(x) for x in c)}'>&#9632;</span> {o}" for o, c in zip(OUTCOMES, OUTCOME_COLOURS)]
    return "outcome colours: " + ", ".join(names)


def start_server(host: str = "127.0.0.1", port: int = 0):
    """A viser server on ``host:port`` (0: a free port), its banner kept off stdout (the command
    prints its own line); ``OSError`` when the port is taken. z is up; the first view looks
    forward from behind and above the ego (LiDAR frame, metres)."""
    import viser

    # a browser's speculative connection closed before its handshake is logged as a traceback
    # by websockets' server: not an error of ours, kept off the terminal
    logging.getLogger("websockets.server").setLevel(logging.CRITICAL)
    with contextlib.redirect_stdout(io.StringIO()):
        server = viser.ViserServer(host=host, port=port, verbose=False)
    server.scene.set_up_direction("+z")
    server.initial_camera.position = INITIAL_CAMERA[0]
    server.initial_camera.look_at = INITIAL_CAMERA[1]
    server.initial_camera.up = (0.0, 0.0, 1.0)
    return server


def stop_server(server) -> None:
    """Stops a server of :func:`start_server` (quietly)."""
    with contextlib.redirect_stdout(io.StringIO()):
        server.stop()


def save_html(out: Path, source, budget: int, seconds_per_frame: float = 1.0) -> int:
    """Writes the frames of ``source`` (:class:`RootFrames` or :class:`PairFrames`) as one offline
    HTML page (viser's embedded client and the scene, played back frame after frame); returns its
    size in bytes."""
    server = start_server()
    try:
        nodes: dict = {}
        overlays: list = []
        mode = "outcome" if source.has_pred else "semantic"
        serializer = None
        for k in range(len(source)):
            v = source.prepare(k, budget)
            draw_frame(server.scene, v, mode, "show", "camera", nodes, overlays, labels=source.labels)
            if serializer is None:
                serializer = server.get_scene_serializer()
            serializer.insert_sleep(seconds_per_frame)
        html = serializer.as_html() if serializer is not None else server.scene.as_html()
    finally:
        stop_server(server)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(html)
    return out.stat().st_size
