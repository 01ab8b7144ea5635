"""``carlaocc view`` in a real browser: the viewer served on loopback (a free port) over the
shared 0.1 m root, opened in headless Chromium (WebGL on SwiftShader, driven over the DevTools
protocol: tools/headless_chromium.py). Inside the 3D canvas -- pixels where the page's topmost
element is the canvas, never the GUI panel or a notification -- the class colours of the frame's
largest classes appear; unticking one class in the GUI removes its colour. Under CI a missing
Chromium fails the test (tests/browser.py)."""

from __future__ import annotations

import io
import time

import numpy as np
import pytest
from PIL import Image

from browser import chromium, headless_chromium

pytest.importorskip("viser", reason="the viewer extra (pip install 'carlaocc[viewer]'; in the test extra)")

BUDGET = 15_000  # surface voxels drawn (the level of detail): software rendering stays quick
STEP = 8  # px between the probes of which element is on top

# 1 where the topmost element at the probe is the 3D canvas, sampled every STEP pixels
CANVAS_PROBE = f"""(() => {{
  const out = []; const w = innerWidth, h = innerHeight;
  for (let y = 0; y < h; y += {STEP}) {{ let row = '';
    for (let x = 0; x < w; x += {STEP}) {{ const e = document.elementFromPoint(x, y);
      row += (e && e.tagName === 'CANVAS') ? '1' : '0'; }}
    out.push(row); }}
  return out.join('\\n'); }})()"""


def _canvas_pixels(png: bytes, probe: str) -> np.ndarray:
    """(M, 3) int RGB of the screenshot's pixels inside the canvas (probe blocks all on the canvas)."""
    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    mask = np.array([[c == "1" for c in row] for row in probe.splitlines()])
    full = np.repeat(np.repeat(mask, STEP, 0), STEP, 1)[:img.shape[0], :img.shape[1]]
    return img[full]


def _count(pixels: np.ndarray, rgb) -> int:
    return int((np.abs(pixels - np.asarray(rgb)).max(axis=1) <= 4).sum())


def _wait_for_pixels(page, rgb, at_least: int, timeout: float = 90.0) -> tuple[int, bytes, str]:
    end = time.monotonic() + timeout
    while True:
        png, probe = page.screenshot(), page.eval(CANVAS_PROBE)
        n = _count(_canvas_pixels(png, probe), rgb)
        if n >= at_least or time.monotonic() > end:
            return n, png, probe
        time.sleep(0.3)


def test_viewer_draws_classes_and_a_toggle_removes_one(default_01, tmp_path):
    from carlaocc.pipeline.commands.viewer import RootFrames, Viewer, open_frames, start_server, stop_server
    from carlaocc.schemas import taxonomy

    exe = chromium()
    samples = open_frames(default_01.url, None, 0.1)
    server = start_server("127.0.0.1", 0)
    try:
        viewer = Viewer(server, RootFrames(samples), BUDGET)
        v = viewer.view(0)
        # the two classes with the most drawn voxels: the road and the next (sidewalk, terrain...)
        ids, counts = np.unique(v.semantic, return_counts=True)
        top = [int(i) for i in ids[np.argsort(-counts)][:2]]
        colours = {c: taxonomy.palette()[c] for c in top}
        with headless_chromium.Browser(exe, 720, 480) as browser:
            page = browser.open(f"http://127.0.0.1:{server.get_port()}")
            page.wait_for("[...document.querySelectorAll('label')].some(l => l.textContent.trim() === 'Road')", 90)
            seen = {}
            for c in top:
                seen[c], png, probe = _wait_for_pixels(page, colours[c], 300)
            (tmp_path / "before.png").write_bytes(png)
            assert all(n >= 300 for n in seen.values()), \
                f"class colours in the canvas: {({taxonomy.by_id(c).name: n for c, n in seen.items()})}"
            # untick the largest class in the GUI: its colour leaves the canvas, the other's stays
            off, kept = top
            name = taxonomy.by_id(off).name
            page.eval(f"document.getElementById([...document.querySelectorAll('label')]"
                      f".find(l => l.textContent.trim() === {name!r}).htmlFor).click()")
            end = time.monotonic() + 60
            while True:
                pixels = _canvas_pixels(page.screenshot(), page.eval(CANVAS_PROBE))
                gone, still = _count(pixels, colours[off]), _count(pixels, colours[kept])
                if gone <= seen[off] // 50 or time.monotonic() > end:
                    break
                time.sleep(0.3)
            assert not viewer.class_boxes[off].value  # the GUI told the server
            assert gone <= seen[off] // 50, f"{name} still covers {gone} px after unticking (was {seen[off]})"
            assert still >= 100, f"{taxonomy.by_id(kept).name} vanished too ({still} px)"
    finally:
        stop_server(server)
