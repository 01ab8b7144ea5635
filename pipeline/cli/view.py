"""``carlaocc view``: look around a sequence in a web viewer (the optional ``viewer`` extra, viser),
or ``--save`` it as one offline HTML page. The work is :mod:`carlaocc.pipeline.commands.viewer`."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated, Optional

import typer

from carlaocc.pipeline.cli.app import app
from carlaocc.pipeline.cli.common import RootOpt, fail, open_store

EXTRA_HINT = "pip install 'carlaocc[viewer]'"


def import_viser():
    """The viser module, or the one-line error naming the extra (exit 2)."""
    try:
        import viser
    except ImportError as exc:
        fail(f"carlaocc view needs the viewer extra ({exc.name or 'viser'} is not installed): {EXTRA_HINT}")
    return viser


def _frame_range(text: Optional[str], n: int) -> list[int]:
    if text is None:
        return list(range(n))
    try:
        a, _, b = text.partition(":")
        lo = int(a) if a else 0
        hi = (int(b) if b else n) if _ else lo + 1
    except ValueError:
        fail(f"--frames {text}: START:STOP (sample indices, e.g. 0:5) or one index")
    if not 0 <= lo < hi <= n:
        fail(f"--frames {text}: the sequence has frames 0..{n - 1}")
    return list(range(lo, hi))


@app.command("view")
def view(
    root: RootOpt = "data",
    seq: Annotated[Optional[str], typer.Option("--seq", help="sequence id (default: the root's first)")] = None,
    voxel_size: Annotated[Optional[float], typer.Option("--voxel-size", "--res", help="a built voxel size, m (default: the finest built)")] = None,
    pred: Annotated[Optional[Path], typer.Option("--pred", help="a prediction tree <seq>/<frame:06d>.npz on the root's grid (carlaocc export carlaocc-npz's layout, or npz with 'semantics'): voxels coloured true positive / false positive / false negative / wrong class")] = None,
    frames: Annotated[Optional[str], typer.Option("--frames", help="START:STOP: only these frames (sample indices) on the timeline and in --save")] = None,
    max_points: Annotated[int, typer.Option("--max-points", min=1000, help="surface voxels drawn per frame before the level of detail coarsens them (x2 per step)")] = 400_000,
    host: Annotated[str, typer.Option("--host", help="address to serve on (127.0.0.1: this machine only; reach it through ssh -L)")] = "127.0.0.1",
    port: Annotated[int, typer.Option("--port", min=0, max=65535, help="port to serve on (0: any free one; a taken port: the next free one, the printed URL says which)")] = 8080,
    save: Annotated[Optional[Path], typer.Option("--save", help="write the frames as one offline HTML page (opened by any browser, no dataset or carlaocc needed) instead of serving")] = None,
) -> None:
    """Look around a sequence in a web viewer served on a local port: surface voxels by class,
    instance or against a prediction, per-class toggles, camera/LiDAR masks, flow, boxes, LiDAR,
    the ego and its cameras with their images, a timeline. Needs the viewer extra."""
    import_viser()
    from carlaocc.pipeline.commands.viewer import (ViewerError, Viewer, open_frames, prediction_files, save_html,
                                                    start_server, stop_server)

    open_store(root, writable=False)
    try:
        samples = open_frames(root, seq, voxel_size)
        picked = _frame_range(frames, len(samples))
        seq_id = samples.samples[0][0]
        preds = None if pred is None else prediction_files(pred, seq_id, [samples.samples[k][1] for k in picked])
        if save is not None:
            if save.suffix.lower() not in (".html", ".htm"):
                fail(f"--save {save}: an .html file")
            size = save_html(save, samples, preds, max_points, picked)
            typer.echo(f"{seq_id}: {len(picked)} frame(s) at {samples.voxel_size:g} m -> {save} ({size / 2**20:.1f} MiB)")
            typer.echo(f"open it (no dataset needed): python -m webbrowser -t {save.resolve().as_uri()}")
            return
        server = start_server(host, port)
    except ViewerError as exc:
        fail(str(exc))
    except OSError as exc:
        fail(f"--port {port}: cannot serve on {host}:{port} ({exc.strerror or exc}); pick another with --port, or 0")
    try:
        Viewer(server, samples, preds, max_points, picked)
        url = f"http://{'localhost' if host in ('127.0.0.1', 'localhost') else host}:{server.get_port()}"
        typer.echo(f"viewing {seq_id} at {samples.voxel_size:g} m: {url}  (remote: ssh -L {server.get_port()}:"
                   f"localhost:{server.get_port()} <this host>, then open {url}; Ctrl-C stops)", err=False)
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        stop_server(server)
