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
    ctx: typer.Context,
    root: RootOpt = "data",
    seq: Annotated[Optional[str], typer.Option("--seq", help="sequence id (default: the root's first)")] = None,
    voxel_size: Annotated[Optional[float], typer.Option("--voxel-size", "--res", help="a built voxel size, m (default: the finest built)")] = None,
    pred: Annotated[Optional[Path], typer.Option("--pred", help="predictions: voxels coloured true positive / false positive / false negative / wrong class. Without --gt: a tree <seq>/<frame:06d>.npz on the root's grid (carlaocc-npz's layout, or npz with 'semantics' in CarlaOcc ids); with --gt: any prediction file or tree carlaocc eval ssc reads")] = None,
    gt: Annotated[Optional[Path], typer.Option("--gt", help="the ground-truth file or tree of --pred, paired as carlaocc eval ssc pairs them (by relative path without suffix), e.g. an export of carlaocc export; each frame drawn on the grid (and in the frame) of the export's grid.json; no root needed (given --root: its cameras, boxes and LiDAR where the paths name its sequence and frame)")] = None,
    map_name: Annotated[str, typer.Option("--map", help="with --gt: the label space of both trees, as carlaocc eval ssc's --map: carlaocc | benchmark | occ3d | sscbench | semantickitti")] = "carlaocc",
    table: Annotated[str, typer.Option("--taxonomy", help="with --gt: the label table of CarlaOcc ids (release | carlaocc-v1), as carlaocc eval's")] = "release",
    ignore: Annotated[str, typer.Option("--ignore", help="with --gt: comma-separated label ids drawn as free (ground truth: void; prediction: abstain), as carlaocc eval's")] = "255",
    frames: Annotated[Optional[str], typer.Option("--frames", help="START:STOP: only these frames (sample indices; with --gt the pairs' indices, sorted by path) on the timeline and in --save")] = None,
    max_points: Annotated[int, typer.Option("--max-points", min=1000, help="surface voxels drawn per frame before the level of detail coarsens them (x2 per step)")] = 400_000,
    host: Annotated[str, typer.Option("--host", help="address to serve on (127.0.0.1: this machine only; reach it through ssh -L)")] = "127.0.0.1",
    port: Annotated[int, typer.Option("--port", min=0, max=65535, help="port to serve on (0: any free one; a taken port: the next free one, the printed URL says which)")] = 8080,
    save: Annotated[Optional[Path], typer.Option("--save", help="write the frames as one offline HTML page (opened by any browser, no dataset or carlaocc needed) instead of serving")] = None,
) -> None:
    """Look around a sequence in a web viewer served on a local port: surface voxels by class,
    instance or against a prediction, per-class toggles, camera/LiDAR masks, flow, boxes, LiDAR,
    the ego and its cameras with their images, a timeline. With --pred and --gt: a prediction
    tree against its ground-truth tree, any pair carlaocc eval ssc reads, without a root. Needs
    the viewer extra."""
    import_viser()
    from carlaocc.pipeline.commands.viewer import (RootFrames, ViewerError, Viewer, open_frames,
                                                    prediction_files, save_html, start_server, stop_server)
    from carlaocc.pipeline.commands.viewer_pairs import pair_frames

    if save is not None and save.suffix.lower() not in (".html", ".htm"):
        fail(f"--save {save}: an .html file")
    if gt is None:
        for opt, value, default in (("--map", map_name, "carlaocc"), ("--taxonomy", table, "release"), ("--ignore", ignore, "255")):
            if value != default:
                fail(f"{opt} {value}: applies to --pred with --gt (a prediction tree against its ground-truth tree)")
    try:
        if gt is not None:
            if pred is None:
                fail(f"--gt {gt}: needs --pred, the predictions to look at against it")
            try:
                ignored = tuple(int(v) for v in ignore.split(",") if v.strip())
            except ValueError:
                fail(f"--ignore {ignore!r}: comma-separated integer label ids")
            source = pair_frames(pred, gt, map_name, table, ignored)
            source = source.select(_frame_range(frames, len(source)))
            # (compared by name: typer's click is its own copy, not the click package)
            if getattr(ctx.get_parameter_source("root"), "name", "DEFAULT") != "DEFAULT":
                # the root's cameras, boxes and LiDAR on the frames the trees' paths name
                open_store(root, writable=False)
                source = source.with_root(root)
            what = f"{gt} against {pred} ({map_name} labels)"
        else:
            open_store(root, writable=False)
            samples = open_frames(root, seq, voxel_size)
            picked = _frame_range(frames, len(samples))
            seq_id = samples.samples[0][0]
            preds = None if pred is None else prediction_files(pred, seq_id, [samples.samples[k][1] for k in picked])
            source = RootFrames(samples, preds, picked)
            what = f"{seq_id} at {samples.voxel_size:g} m"
        if save is not None:
            size = save_html(save, source, max_points)
            typer.echo(f"{what}: {len(source)} frame(s) -> {save} ({size / 2**20:.1f} MiB)")
            typer.echo(f"open it (no dataset needed): python -m webbrowser -t {save.resolve().as_uri()}")
            return
        first = source.prepare(0, max_points)  # a bad first frame is refused before serving
    except ViewerError as exc:
        fail(str(exc))
    try:
        server = start_server(host, port)
    except OSError as exc:
        fail(f"--port {port}: cannot serve on {host}:{port} ({exc.strerror or exc}); pick another with --port, or 0")
    try:
        Viewer(server, source, max_points, prepared={0: first})
        url = f"http://{'localhost' if host in ('127.0.0.1', 'localhost') else host}:{server.get_port()}"
        typer.echo(f"viewing {what}: {url}  (remote: ssh -L {server.get_port()}:"
                   f"localhost:{server.get_port()} <this host>, then open {url}; Ctrl-C stops)", err=False)
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        stop_server(server)
