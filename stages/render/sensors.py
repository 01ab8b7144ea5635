"""Headless pictures of camera maps: depth, normals, semantics, instances, and the paper's
rectification figure (raw vs rectified, repaired pixels highlighted).

Inputs are the maps of :mod:`carlaocc.stages.sensors` ((H, W) depth float32 metres with 0 = no surface,
semantic uint8, instance uint32, normal (H, W, 3) in the OpenCV camera frame); outputs are
(H, W, 3) uint8 RGB images, deterministic (write them with ``carlaocc.catalog.images.save_png``).

Colours: depth by inverse depth on a dark-to-bright ramp (near = bright, no surface = black);
normals as ``(1 - n) / 2`` per channel (a surface facing the camera, n = (0, 0, -1), is light
blue-violet; zero normals are black); semantics by the taxonomy palette; instances by
:func:`carlaocc.stages.render.colours.instance_colors` with stuff in its class colour darkened to 40 %.
In the rectification rows, pixels of the transparency region are tinted red and those of the
omission region blue (the paper's figure). :func:`sensor_sheet` lays the maps out with
:func:`carlaocc.stages.render.layout.compose`: a key per row says all of this on the sheet.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from carlaocc.schemas import taxonomy
from carlaocc.stages.render.colours import instance_colors
from carlaocc.stages.render.figures import class_entries
from carlaocc.stages.render.layout import ColourScale, Key, LegendEntry, Panel, Sheet, compose
from carlaocc.stages.scenes.people.pedestrians import SKELETON_BONES

_DEPTH_T = np.array([0.0, 0.2, 0.45, 0.7, 1.0])
_DEPTH_RGB = np.array([[20, 12, 50], [95, 30, 120], [200, 60, 90], [250, 150, 50], [252, 250, 190]], dtype=np.float64)
TRANSPARENCY_TINT = (230, 30, 30)
OMISSION_TINT = (30, 90, 240)


def depth_image(depth: np.ndarray, near: float = 1.0) -> np.ndarray:
    """RGB of a depth map: ``t = near / depth`` (1 at ``near`` metres or closer) on the ramp;
    no surface (0) black."""
    d = np.asarray(depth, dtype=np.float64)
    t = np.where(d > 0, np.clip(near / np.maximum(d, 1e-6), 0.0, 1.0), 0.0)
    # a square root spreads the far range, where most pixels of a street are
    t = np.sqrt(t)
    rgb = np.stack([np.interp(t, _DEPTH_T, _DEPTH_RGB[:, c]) for c in range(3)], axis=-1)
    rgb[d <= 0] = 0
    return np.round(rgb).astype(np.uint8)


def normal_image(normal: np.ndarray) -> np.ndarray:
    """RGB of a normal map, ``(1 - n) / 2 * 255`` per channel; zero normals black."""
    n = np.asarray(normal, dtype=np.float32)
    rgb = np.round((1.0 - n) * 127.5).clip(0, 255).astype(np.uint8)
    rgb[~np.any(n != 0, axis=-1)] = 0
    return rgb


def semantic_image(semantic: np.ndarray) -> np.ndarray:
    """RGB of a semantic map by the taxonomy palette."""
    pal = np.asarray(taxonomy.palette(), dtype=np.uint8)
    return pal[np.asarray(semantic, dtype=np.intp).clip(0, len(pal) - 1)]


def instance_image(semantic: np.ndarray, instance: np.ndarray) -> np.ndarray:
    """RGB of an instance map: things by a colour hashed from the id, stuff by its darkened class
    colour."""
    rgb = (semantic_image(semantic).astype(np.float32) * 0.4).astype(np.uint8)
    inst = np.asarray(instance)
    things = inst > 0
    rgb[things] = instance_colors(inst[things])
    return rgb


def highlight(image: np.ndarray, transparency: np.ndarray, omission: np.ndarray, strength: float = 0.6) -> np.ndarray:
    """``image`` with the transparency region tinted red and the omission region blue."""
    out = image.astype(np.float32)
    for mask, tint in ((omission, OMISSION_TINT), (transparency, TRANSPARENCY_TINT)):
        out[mask] = (1 - strength) * out[mask] + strength * np.asarray(tint, dtype=np.float32)
    return np.round(out).astype(np.uint8)


@dataclass(frozen=True)
class CameraView:
    """One camera's maps to draw (raw maps None when there are none)."""

    camera: str
    depth: np.ndarray
    semantic: np.ndarray
    instance: np.ndarray | None
    normal: np.ndarray
    depth_raw: np.ndarray | None = None
    semantic_raw: np.ndarray | None = None
    rgb: np.ndarray | None = None  # (H, W, 3) uint8, recorded sequences
    # walkers' skeletons to draw over the semantic and instance maps: (W, J, 2) pixel coordinates
    # (u right, v down, pixel centres at i + 0.5; NaN behind the camera) and (W, J) visibility
    skeleton_uv: np.ndarray | None = None
    skeleton_visible: np.ndarray | None = None
    # the direction the camera faces in words, e.g. "front, stereo left (with camera_01)"
    # (carlaocc.schemas.rig.camera_roles); "" when the rig does not know the camera
    direction: str = ""


def project_skeletons(joints_cam: np.ndarray, K, depth: np.ndarray, tolerance: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates and visibility of joints given in a camera's OpenCV optical frame
    ((W, J, 3) metres: x right, y down, z forward) through the 3x3 intrinsics ``K`` (pixel centres
    at i + 0.5). A joint is visible when it is in front of the camera, inside the image and not
    more than ``tolerance`` metres behind the planar ``depth`` map's surface at its pixel (its
    own body's surface lies a few centimetres in front of it). Returns ((W, J, 2), (W, J) bool);
    joints behind the camera get NaN coordinates."""
    P = np.asarray(joints_cam, dtype=np.float64)
    K = np.asarray(K, dtype=np.float64).reshape(3, 3)
    z = P[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        # 1. pinhole projection of the points in front of the camera
        u = np.where(z > 1e-6, K[0, 0] * P[..., 0] / z + K[0, 2], np.nan)
        v = np.where(z > 1e-6, K[1, 1] * P[..., 1] / z + K[1, 2], np.nan)
    uv = np.stack([u, v], axis=-1)
    H, W = depth.shape
    inside = np.isfinite(u) & np.isfinite(v) & (u >= 0) & (u < W) & (v >= 0) & (v < H)
    # 2. occlusion: the depth map's surface at the joint's pixel is not well in front of it
    i = np.clip(np.nan_to_num(np.floor(v), nan=0).astype(int), 0, H - 1)
    j = np.clip(np.nan_to_num(np.floor(u), nan=0).astype(int), 0, W - 1)
    d = depth[i, j]
    visible = inside & ((d <= 0) | (z <= d + tolerance))
    return uv, visible


def draw_skeletons(image: np.ndarray, uv: np.ndarray, visible: np.ndarray, bones, step: int = 1) -> np.ndarray:
    """``image`` (H, W, 3) uint8 (subsampled by ``step``) with every skeleton drawn: bones as
    one-pixel lines and joints as 3x3 dots, white where visible, grey where hidden."""
    out = image.copy()
    H, W = out.shape[:2]
    q = np.asarray(uv, dtype=np.float64) / max(int(step), 1)

    def put(r, c, colour):
        ok = (r >= 0) & (r < H) & (c >= 0) & (c < W)
        out[r[ok], c[ok]] = colour

    J = q.shape[1]
    for s in range(q.shape[0]):
        for a, b in bones:
            # a skeleton with fewer joints (a recording's two knees) draws the bones it has
            if a >= J or b >= J or not (np.isfinite(q[s, a]).all() and np.isfinite(q[s, b]).all()):
                continue
            # sample the segment at least once per pixel
            n = int(max(abs(q[s, b, 0] - q[s, a, 0]), abs(q[s, b, 1] - q[s, a, 1]), 1.0)) + 1
            t = np.linspace(0.0, 1.0, n)[:, None]
            pts = q[s, a] + t * (q[s, b] - q[s, a])
            colour = (255, 255, 255) if visible[s, a] and visible[s, b] else (140, 140, 140)
            put(np.floor(pts[:, 1]).astype(int), np.floor(pts[:, 0]).astype(int), colour)
        for k in range(q.shape[1]):
            if not np.isfinite(q[s, k]).all():
                continue
            r0, c0 = int(np.floor(q[s, k, 1])), int(np.floor(q[s, k, 0]))
            rr, cc = np.mgrid[r0 - 1 : r0 + 2, c0 - 1 : c0 + 2]
            put(rr.ravel(), cc.ravel(), (255, 255, 255) if visible[s, k] else (140, 140, 140))
    return out


def repair_regions(view: CameraView, epsilon: float) -> tuple[np.ndarray, np.ndarray]:
    """(transparency, omission) regions recomputed from stored maps: raw depth at least
    ``epsilon`` behind the rectified depth (no raw surface counts as infinitely far), and the
    empty raw label."""
    d = np.where(view.depth > 0, view.depth, np.inf)
    d_raw = np.where(view.depth_raw > 0, view.depth_raw, np.inf)
    with np.errstate(invalid="ignore"):
        transparency = (d_raw - d) >= epsilon
    return transparency, view.semantic_raw == 0


def _skeletons(image: np.ndarray, view: CameraView, step: int) -> np.ndarray:
    """``image`` with the view's skeletons drawn, when it has any."""
    if view.skeleton_uv is None or len(view.skeleton_uv) == 0:
        return image

    return draw_skeletons(image, view.skeleton_uv, view.skeleton_visible, SKELETON_BONES, step)


def _depth_scale(near: float = 1.0) -> ColourScale:
    """The colour scale of :func:`depth_image`: the ramp sampled through the function itself,
    ticks at round depths in metres (position ``sqrt(near / depth)``)."""
    t = np.linspace(0.0, 1.0, 64)
    depths = np.where(t > 0, near / np.maximum(t, 1e-9) ** 2, 0.0)
    ramp = depth_image(depths[:, None])[:, 0]
    ramp[0] = depth_image(np.array([[1e9]]))[0, 0]  # the far end of the ramp, not "no surface" black
    ticks = tuple((float(np.sqrt(near / d)), f"{d:g}" + (" or less" if d <= near else "")) for d in (1, 2, 5, 10, 20, 80))
    return ColourScale("planar depth, m", ramp, ticks)


# canonical normals in the OpenCV camera frame (x right, y down, z forward) and their words
_NORMAL_KEY = (((0.0, 0.0, -1.0), "faces the camera"), ((0.0, -1.0, 0.0), "faces up (ground)"),
               ((-1.0, 0.0, 0.0), "faces the image's left"), ((1.0, 0.0, 0.0), "faces the image's right"))


def _keys(views: Sequence[CameraView], step: int, epsilon: float) -> dict[str, Key]:
    """The key of each row of :func:`sensor_sheet`, its colours computed by the functions that
    draw the row."""
    s = slice(None, None, max(int(step), 1))
    black = LegendEntry("no surface", ((0, 0, 0),))
    normals = tuple(LegendEntry(words, (tuple(int(v) for v in normal_image(np.array([[n]], np.float32))[0, 0]),))
                    for n, words in _NORMAL_KEY)
    sem = np.concatenate([v.semantic[s, s].ravel() for v in views])
    keys = {
        "rgb": Key("RGB: recorded, or rendered from the scene"),
        "depth": Key("depth: near bright, far dark", (black,), _depth_scale()),
        "normal": Key("normal, camera frame: RGB = (1 - n) / 2", (*normals, black)),
        "semantic": Key("colour: class (taxonomy palette)", tuple(class_entries(sem, None, "semantic"))),
    }
    skeleton = ()
    if any(v.skeleton_uv is not None and len(v.skeleton_uv) for v in views):
        skeleton = (LegendEntry("skeleton, visible", ((255, 255, 255),)), LegendEntry("skeleton, hidden", ((140, 140, 140),)))
        keys["semantic"] = Key(keys["semantic"].heading, keys["semantic"].entries + skeleton)
    if all(v.instance is not None for v in views):
        inst = np.concatenate([v.instance[s, s].ravel() for v in views])
        ids = np.unique(inst[inst > 0])
        entries = []
        if len(ids):
            cols = tuple(tuple(int(c) for c in col) for col in instance_colors(ids[:4]))
            entries.append(LegendEntry(f"things: one colour per instance ({len(ids)} here)", cols, "instances"))
        entries.append(LegendEntry("stuff: its class colour at 40 %", kind="text"))
        keys["instance"] = Key("colour: instance", (*entries, *skeleton))
    repaired = (LegendEntry(f"transparency region (raw depth >= {epsilon:g} m behind)", (TRANSPARENCY_TINT,)),
                LegendEntry("omission region (no raw label)", (OMISSION_TINT,)))
    keys["raw depth"] = Key("raw: repaired pixels tinted", repaired, _depth_scale())
    keys["rectified depth"] = Key("rectified depth", (black,), _depth_scale())
    keys["raw semantic"] = Key("raw: repaired pixels tinted", repaired)
    keys["rectified semantic"] = keys["semantic"]
    return keys


def camera_title(view: CameraView, row: str) -> str:
    """A panel's title: the camera, the direction it faces (when known) and the row's map."""
    return f"{view.camera} ({view.direction}): {row}" if view.direction else f"{view.camera}: {row}"


def sensor_sheet(views: Sequence[CameraView], epsilon: float = 0.05, step: int = 2) -> Sheet:
    """The sheet of a frame's camera maps: a column per camera, rows (the recorded RGB when every
    view has it,) depth, normals, semantics, instances and, where raw maps exist, raw depth /
    rectified depth / raw semantics / rectified semantics with the repaired pixels highlighted;
    skeletons (when the views carry them) over the semantic and instance maps. Images are
    subsampled by ``step``. Every panel is titled with its camera, the direction it faces and
    its map (:func:`camera_title`); every row ends in its key (the depth scale in metres, the
    normal colours, the classes present, the instance colouring, the tints)."""
    if not views:
        raise ValueError("no camera maps to draw")
    s = slice(None, None, max(int(step), 1))
    rows: list[tuple[str, list[np.ndarray]]] = []
    if all(v.rgb is not None for v in views):
        rows.append(("rgb", [np.ascontiguousarray(v.rgb[s, s, :3]) for v in views]))
    rows += [
        ("depth", [depth_image(v.depth[s, s]) for v in views]),
        ("normal", [normal_image(v.normal[s, s]) for v in views]),
        ("semantic", [_skeletons(semantic_image(v.semantic[s, s]), v, step) for v in views]),
    ]
    if all(v.instance is not None for v in views):
        rows.append(("instance", [_skeletons(instance_image(v.semantic[s, s], v.instance[s, s]), v, step) for v in views]))
    if all(v.depth_raw is not None and v.semantic_raw is not None for v in views):
        regions = [repair_regions(v, epsilon) for v in views]
        rows += [
            ("raw depth", [highlight(depth_image(v.depth_raw[s, s]), t[s, s], o[s, s]) for v, (t, o) in zip(views, regions)]),
            ("rectified depth", [depth_image(v.depth[s, s]) for v in views]),
            ("raw semantic", [highlight(semantic_image(v.semantic_raw[s, s]), t[s, s], o[s, s])
                              for v, (t, o) in zip(views, regions)]),
            ("rectified semantic", [semantic_image(v.semantic[s, s]) for v in views]),
        ]
    keys = _keys(views, step, epsilon)
    return compose([([Panel(camera_title(v, name), im) for v, im in zip(views, ims)], keys[name]) for name, ims in rows])
