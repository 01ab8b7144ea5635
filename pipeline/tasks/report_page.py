"""The report page: ``metrics/report.html``, one self-contained page (PNGs inlined as data URIs,
inline CSS, no script, font or link outside the file) that opens offline — dataset size,
sequences, class statistics, quality scores, a rendered frame and the lineage of every stage
(collapsed per stage from the lineage log).

Everything but the lineage section (run ids and times) is a function of the dataset's content,
so two builds of the same dataset differ only there.
"""

from __future__ import annotations

import base64
import hashlib
import html
import json
import math
from collections import defaultdict
from dataclasses import dataclass, field

from carlaocc.catalog.store import LIDAR_DIR, LIDAR_RECORDED_DIR
from carlaocc.schemas import taxonomy
from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.records import AssetStatisticsRecord, QualityRecord, RunRecord, SequenceRecord
from carlaocc.stages.report.plots import metric_label
from carlaocc.stages.report.statistics import VoxelSizeStats

REPORT_HTML = "metrics/report.html"
PLOTS_DIR = "metrics/plots"
SENSOR_STEP = 4  # the camera sheet draws every 4th pixel row and column (1408x376 -> 352x94)


@dataclass
class StageLineage:
    stage: str
    partitions: int
    completed: int
    run_ids: list[str]
    code_versions: list[str]
    config_hashes: list[str]
    started: str
    ended: str
    task_seconds: float
    inputs: dict[str, int]  # upstream stage (or "file") -> partitions/files read
    outputs: dict[str, int]  # output kind -> artefacts written
    input_digest: str
    output_digest: str
    records: list[RunRecord] = field(default_factory=list)


def _kind(path: str) -> str:
    """An output's kind for the collapsed view: ``occupancy.zarr/<array>``, ``lidar`` (and
    ``lidar_recorded``), or the
    directory of a file (``admesh/meshes``, ``metrics/quality``...)."""
    if path.endswith("]") and ".zarr/" in path:  # a frame of a Zarr array
        root, rest = path.split("/", 1)
        return f"{root}/{rest.rsplit('[', 1)[0].rsplit('/', 1)[-1]}"
    parts = path.split("/")
    if parts[0] in (LIDAR_DIR, LIDAR_RECORDED_DIR):  # lidar[_recorded]/<seq>/<frame>.parquet
        return parts[0]
    return "/".join(parts[:2]) if len(parts) > 2 else parts[0]


def stage_lineage(records: list[RunRecord]) -> list[StageLineage]:
    """The latest record of every partition of every stage, collapsed per stage: runs, code
    versions, config hashes, time span, and the input -> output fingerprint mapping as counts
    per upstream stage and output kind with one digest of each side. Stages in the order their
    latest tasks started (the pipeline's order for a full run)."""
    latest: dict[str, dict[str, RunRecord]] = defaultdict(dict)
    for rec in sorted(records, key=lambda r: r.run_id):
        latest[rec.stage][rec.partition] = rec
    out = []
    for stage, by_part in latest.items():
        recs = [by_part[k] for k in sorted(by_part) if by_part[k].status != "retired"]
        if not recs:
            continue
        inputs: dict[str, int] = defaultdict(int)
        outputs: dict[str, int] = defaultdict(int)
        h_in, h_out = hashlib.sha256(), hashlib.sha256()
        for r in recs:
            ins, outs = json.loads(r.input_fingerprints), json.loads(r.output_fingerprints)
            for k in ins:
                inputs["file" if k.startswith("file:") else k.split("/", 1)[0]] += 1
            for k in outs:
                outputs[_kind(k)] += 1
            h_in.update(json.dumps([r.partition, ins], sort_keys=True).encode())
            h_out.update(json.dumps([r.partition, outs], sort_keys=True).encode())
        out.append(StageLineage(
            stage=stage, partitions=len(recs), completed=sum(r.status == "completed" for r in recs),
            run_ids=sorted({r.run_id for r in recs}),
            code_versions=sorted({r.code_version for r in recs}), config_hashes=sorted({r.config_hash for r in recs}),
            started=min(r.started_at for r in recs).strftime("%Y-%m-%d %H:%M:%S"),
            ended=max(r.ended_at for r in recs).strftime("%Y-%m-%d %H:%M:%S"),
            task_seconds=sum((r.ended_at - r.started_at).total_seconds() for r in recs),
            inputs=dict(sorted(inputs.items())), outputs=dict(sorted(outputs.items())),
            input_digest=h_in.hexdigest()[:12], output_digest=h_out.hexdigest()[:12], records=recs,
        ))
    return sorted(out, key=lambda L: (L.started, L.stage))


_CSS = """
body{font-family:-apple-system,"Segoe UI",Helvetica,Arial,sans-serif;margin:0;color:#222;background:#f6f7f9}
main{max-width:1280px;margin:0 auto;padding:16px 28px 48px;background:#fff}
h1{font-size:1.6em;margin:.4em 0 .2em}h2{border-bottom:2px solid #dde;padding-bottom:4px;margin-top:1.8em}
h3{margin:1.2em 0 .4em;font-size:1.05em}
nav a{margin-right:14px;color:#2a5db0;text-decoration:none}
table{border-collapse:collapse;font-size:13px;margin:6px 0 14px}
th,td{border:1px solid #d8dbe0;padding:3px 8px;text-align:left;vertical-align:top}
th{background:#eef0f4}td.n{text-align:right;font-variant-numeric:tabular-nums}
img{max-width:100%;height:auto;border:1px solid #e2e4e8;margin:4px 0}
.muted{color:#666;font-size:13px}.sw{display:inline-block;width:11px;height:11px;border:1px solid #555;
margin-right:5px;vertical-align:-1px}.bad{color:#b00020;font-weight:600}
code{font-size:12px;background:#f1f2f4;padding:0 3px}details{margin:4px 0 10px}summary{cursor:pointer}
.grid2{display:flex;flex-wrap:wrap;gap:10px}.grid2>div{flex:1 1 560px}
"""


def _e(v) -> str:
    return html.escape(str(v), quote=True)


def _bytes(n: int) -> str:
    for div, unit in ((1 << 30, "GiB"), (1 << 20, "MiB"), (1 << 10, "KiB")):
        if n >= div:
            return f"{n / div:.1f} {unit}"
    return f"{n} B"


def _img(images: dict[str, bytes], name: str, alt: str) -> str:
    if name not in images:
        return ""
    data = base64.b64encode(images[name]).decode("ascii")
    return f'<img alt="{_e(alt)}" src="data:image/png;base64,{data}">'


def _table(head: list[str], rows: list[list], numeric: set[int] = frozenset()) -> str:
    th = "".join(f"<th>{_e(h)}</th>" for h in head)
    body = "".join("<tr>" + "".join(f'<td class="n">{c}</td>' if i in numeric else f"<td>{c}</td>"
                                    for i, c in enumerate(r)) + "</tr>" for r in rows)
    return f"<table><thead><tr>{th}</tr></thead><tbody>{body}</tbody></table>"


def _duration(seconds: float) -> str:
    """12.3 -> '12.3 s', 754 -> '12 min 34 s', 7384 -> '2 h 03 min'."""
    if seconds < 60:
        return f"{seconds:.1f} s"
    m, s = divmod(int(round(seconds)), 60)
    if m < 60:
        return f"{m} min {s:02d} s"
    h, m = divmod(m, 60)
    return f"{h} h {m:02d} min"


def short_version(version: str) -> str:
    """A code version's first 8 characters (as git shortens a commit)."""
    return version[:8]


def _short_versions(versions: list[str]) -> str:
    """The short code version of a stage's partitions; several when they were built with
    different code (the latest build first would need the records: they are listed sorted)."""
    short = [f"<code>{_e(short_version(v))}</code>" for v in versions]
    return short[0] if len(short) == 1 else f"{len(short)} versions: " + ", ".join(short)


def _swatch(class_id: int) -> str:
    r, g, b = taxonomy.by_id(class_id).color
    return f'<span class="sw" style="background:rgb({r},{g},{b})"></span>{_e(taxonomy.by_id(class_id).name)}'


def _fmt_score(v: float | None) -> str:
    return "–" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.5f}"


SECTIONS = ("size", "sequences", "statistics", "quality", "frame", "lineage")


def render_html(*, root: str, sequences: list[SequenceRecord], grids: list[GridSpec],
                totals: dict[float, VoxelSizeStats], asset_rows: list[AssetStatisticsRecord],
                quality: list[QualityRecord], usage: list[tuple[str, int, int]], lineage: list[StageLineage],
                images: dict[str, bytes], label_table: str | None = None, slice: str | None = None) -> str:
    """The report page: one string of HTML with every picture inlined (``images``: name -> PNG);
    ``label_table``: the dataset's (which classes are things); ``slice``: the part of the
    dataset's plan it covers, in words."""

    table = taxonomy.label_table(label_table)
    voxel_size_keys = ", ".join(f"{g.key} m" for g in grids)
    frames = sum(s.frame_count for s in sequences)
    out = [f"<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>carlaocc dataset report</title>"
           f"<style>{_CSS}</style></head><body><main>",
           "<h1>carlaocc dataset report</h1>",
           f"<p class=\"muted\">root <code>{_e(root)}</code> · {len(sequences)} sequences · {frames} frames · "
           f"voxel sizes {_e(voxel_size_keys)} · taxonomy {_e(table.version)}</p>",
           f"<p class=\"muted\" id=\"slice\">covers: {_e(slice)}</p>" if slice else "",
           "<nav>" + "".join(f'<a href="#{s}">{s}</a>' for s in SECTIONS) + "</nav>"]
    # dataset size
    total_files, total_bytes = sum(u[1] for u in usage), sum(u[2] for u in usage)
    rows = [[f"<code>{_e(p)}</code>", f"{n:,}", _bytes(b), f"{b:,}"] for p, n, b in usage]
    rows.append(["<b>total</b>", f"<b>{total_files:,}</b>", f"<b>{_bytes(total_bytes)}</b>", f"{total_bytes:,}"])
    out += ['<h2 id="size">Dataset size</h2>', _table(["part", "files", "size", "bytes"], rows, {1, 2, 3}),
            f'<p class="muted">this report\'s own files ({REPORT_HTML}, {PLOTS_DIR}/) are not counted</p>']
    # sequences
    rows = [[_e(s.sequence_id), _e(s.town), _e(s.traffic_level), s.frame_count, f"{s.rate_hz:g}",
             _e(s.parent_sequence_id or "")] for s in sequences]
    out += ['<h2 id="sequences">Sequences</h2>',
            _table(["sequence", "town", "traffic", "frames", "rate (Hz)", "edited from"], rows, {3, 4})]
    # statistics
    out.append('<h2 id="statistics">Statistics</h2>')
    for grid in grids:
        k = grid.key
        t = totals.get(float(grid.voxel_size))
        if t is None:
            continue
        occupied = int(t.voxels[1:].sum())
        rows = [[_swatch(c), _e(table.by_id(c).kind), f"{t.voxels[c]:,}",
                 f"{100 * t.voxels[c] / max(occupied, 1):.3f}",
                 f"{t.instances[c]:,}" if table.by_id(c).kind == "thing" else "",
                 f"{t.moving[c]:,}" if t.moving[c] else ""]
                for c in range(1, len(t.voxels)) if t.voxels[c] or t.instances[c]]
        out += [f"<h3>{_e(k)} m</h3>", '<div class="grid2"><div>',
                _img(images, f"class_voxels_{k}", f"voxels per class at {k} m"), "</div><div>",
                _img(images, f"instances_{k}", f"instances per class at {k} m"), "</div></div>",
                _img(images, f"motion_{k}", f"static vs dynamic at {k} m"),
                "<details><summary>per-class table</summary>",
                _table(["class", "kind", "voxels", "% of occupied", "instances", "dynamic actors"], rows, {2, 3, 4, 5}),
                "</details>"]
    total_assets = sum(r.assets for r in asset_rows)
    out += [f"<h3>ADMesh library: {total_assets} assets</h3>", _img(images, "assets", "assets per class and source")]
    # quality
    out.append('<h2 id="quality">Quality scores</h2>')
    seq_q = [q for q in quality if q.frame_index is None]
    frame_q = [q for q in quality if q.frame_index is not None]
    metrics = sorted({q.metric for q in quality})
    if metrics:
        worst: dict[tuple, float] = {}
        for q in frame_q:
            if not math.isnan(q.value):
                key = (q.sequence_id, q.voxel_size, q.metric)
                worst[key] = min(worst.get(key, math.inf), q.value)
        for q in seq_q:  # the aggregate stage's sequence rows carry their worst frame
            if q.worst_value is not None:
                worst[(q.sequence_id, q.voxel_size, q.metric)] = q.worst_value
        value = {(q.sequence_id, q.voxel_size, q.metric): q.value for q in seq_q}
        rows = []
        for s in sequences:
            for g in grids:
                cells = []
                for m in metrics:
                    key = (s.sequence_id, float(g.voxel_size), m)
                    cells += [_fmt_score(value.get(key)), _fmt_score(worst.get(key))]
                rows.append([_e(s.sequence_id), f"{g.key} m", *cells])
        head = ["sequence", "voxel"] + [f"{metric_label(m)} {w}" for m in metrics
                                        for w in ("(sequence)", "(worst frame)")]
        out += [_table(head, rows, set(range(2, 2 + 2 * len(metrics)))), _img(images, "quality", "quality scores")]
    else:
        out.append('<p class="bad">no quality scores: run the metrics stage</p>')
    # a rendered frame
    out.append('<h2 id="frame">A rendered frame</h2>')
    out.append(_img(images, "frame", "occupancy of one frame") or "<p class=\"muted\">no occupancy frame</p>")
    if "sensors" in images:
        out += [f'<h3>Its cameras: RGB (when the sensors stage stored it) and maps, every {SENSOR_STEP}th pixel</h3>',
                '<p class="muted">a column per camera, titled with the direction it faces (from the recorded '
                'sensor poses); each row ends in its key</p>',
                _img(images, "sensors", "camera RGB and maps")]
    # lineage
    out.append('<h2 id="lineage">Lineage</h2>')
    rows, hashes = [], []
    for L in lineage:
        status = f"{L.completed} of {L.partitions}"
        if L.completed != L.partitions:
            status = f'<span class="bad">{status}</span>'
        rows.append([f"<b>{_e(L.stage)}</b>", status, f"{_e(L.ended)}", _duration(L.task_seconds),
                     _short_versions(L.code_versions),
                     ", ".join(f"{'external files' if k == 'file' else _e(k)} ×{n:,}" for k, n in L.inputs.items())
                     or "—",
                     ", ".join(f"{_e(k)} ×{n:,}" for k, n in L.outputs.items())])
        hashes.append([_e(L.stage), "<br>".join(_e(r) for r in L.run_ids),
                       "<br>".join(f"<code>{_e(c)}</code>" for c in L.code_versions),
                       "<br>".join(f"<code>{_e(c)}</code>" for c in L.config_hashes),
                       f"<code>{L.input_digest}</code> → <code>{L.output_digest}</code>",
                       f"{_e(L.started)} → {_e(L.ended)}"])
    out += ['<p class="muted">what built this root, stage by stage: the latest record of every partition '
            '(catalog/runs). <i>Completed</i>: partitions whose latest run succeeded; <i>finished</i>: when the '
            'last of them ended (UTC); <i>task time</i>: the tasks\' durations added up; <i>code</i>: the short '
            'code version (a hash of the stage\'s source) its partitions were built with; <i>read</i> and '
            '<i>wrote</i>: upstream partitions (and external files) read, artefacts written. This page is '
            'recorded after it is written: a report row is the previous build of the page.</p>',
            _table(["stage", "completed", "finished (UTC)", "task time", "code", "read", "wrote"], rows),
            "<details><summary>hashes: run ids, code versions, config hashes, input → output digests</summary>",
            _table(["stage", "run", "code version", "config hash", "inputs → outputs digest", "time span (UTC)"],
                   hashes),
            "</details>"]
    for L in lineage:
        rows = []
        for r in L.records:
            ins, outs = json.loads(r.input_fingerprints), json.loads(r.output_fingerprints)
            rows.append([_e(r.partition), _e(r.status) + (f"<br>{_e(r.error)}" if r.error else ""),
                         "<br>".join(f"{_e(k)} <code>{_e(str(v)[-12:])}</code>" for k, v in sorted(ins.items())),
                         "<br>".join(f"{_e(k)} <code>{_e(str(v)[-12:])}</code>" for k, v in sorted(outs.items()))])
        out += [f"<details><summary>{_e(L.stage)}: every artefact ({sum(L.outputs.values()):,} outputs of "
                f"{L.partitions} partitions)</summary>",
                _table(["partition", "status", "inputs → fingerprint", "outputs → fingerprint"], rows),
                "</details>"]
    out.append("</main></body></html>")
    return "\n".join(out)
