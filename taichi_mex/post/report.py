"""``report.html``: one self-contained page per run (pictures inlined, no network), and an
index page per sweep. Built from the files a run leaves, so it also works on old runs:
``plan.json``, ``config.json``, ``summary.json``, ``mesostructure.json``, ``probes.csv`` and
the PNGs under ``snapshots/``, ``sections/`` and the run folder."""

from __future__ import annotations

import base64
import csv
import html
import json
import math
from pathlib import Path

from taichi_mex.post.analysis import layer_height_mm, slicer_model
from taichi_mex.post.output import read_json

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:2em auto;max-width:1100px;
color:#222;padding:0 1em}h1{font-size:1.6em;margin-bottom:.2em}h2{font-size:1.2em;margin-top:1.6em;
border-bottom:1px solid #ddd;padding-bottom:.2em}.sub{color:#666}table{border-collapse:collapse;
margin:.5em 0}td,th{border:1px solid #ddd;padding:.25em .6em;text-align:left;font-size:.92em}
th{background:#f5f5f5}td.num{text-align:right;font-variant-numeric:tabular-nums}.bad{color:#b00}
.ok{color:#070}figure{display:inline-block;margin:.5em;vertical-align:top}figure img{max-width:520px;
border:1px solid #eee}figcaption{font-size:.85em;color:#555}pre{background:#f7f7f7;padding:.8em;
overflow:auto;font-size:.8em;max-height:28em}details summary{cursor:pointer;color:#246}
"""


def _num(value, digits: int = 4) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return f"{value:,}"
    if isinstance(value, float):
        return f"{value:.{digits}g}"
    return html.escape(str(value))


def _table(rows, head=None) -> str:
    out = ["<table>"]
    if head:
        out.append("<tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>")
    for row in rows:
        cells = []
        for k, cell in enumerate(row):
            cls = ' class="num"' if k and isinstance(cell, (int, float)) else ""
            cells.append(f"<td{cls}>{cell if isinstance(cell, str) and cell.startswith('<') else _num(cell)}</td>")
        out.append("<tr>" + "".join(cells) + "</tr>")
    out.append("</table>")
    return "\n".join(out)


def _img(path: Path, caption: str) -> str:
    data = base64.b64encode(path.read_bytes()).decode()
    return (f'<figure><img src="data:image/png;base64,{data}" alt="{html.escape(caption)}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def _verdict(ok: bool, text: str) -> str:
    return f'<span class="{"ok" if ok else "bad"}">{html.escape(text)}</span>'


def _sections(meso: dict | None, plan, config) -> str:
    if not meso or not meso.get("sections"):
        return "<p>No mesostructure analysis for this run.</p>"
    gap = layer_height_mm(plan)
    parts = []
    for sec in meso["sections"]:
        pos = sec.get("position", {})
        rows = []
        for b in sec.get("beads", []):
            law = slicer_model(b["area_mm2"], gap) if gap else None
            rows.append([str(b.get("bead_id")) + (" (substrate)" if b.get("substrate") else ""),
                         b.get("width_mm"), law,
                         None if not law else 100 * (b["width_mm"] / law - 1),
                         b.get("height_mm"), None if not gap else 100 * (b["height_mm"] / gap - 1),
                         b.get("area_mm2")])
        where = f"{pos.get('axis', '?')} = {_num(pos.get('coordinate_mm'))} mm"
        parts.append(f"<h3>Section at {where}</h3>")
        parts.append(_table(rows, ["bead", "width mm", "rounded-rectangle width mm", "width vs law %",
                                   "height mm", "height vs layer %", "area mm²"]))
        parts.append(_table([
            ["beads", sec.get("beads_count")],
            ["mean neck between side-by-side beads (mm)", sec.get("mean_neck_side_mm")],
            ["mean neck between layers (mm)", sec.get("mean_neck_layer_mm")],
            ["void fraction", sec.get("void_fraction")], ["voids", sec.get("voids_count")]]))
    mid = meso.get("along_middle")
    if mid:
        c = mid["coordinates_mm"]
        law = slicer_model(mid["mean_area_mm2"], gap) if gap else None
        parts.append(f"<h3>Over the middle: {mid['sections']} sections, {mid['axis']} = "
                     f"{_num(c[0])}-{_num(c[-1])} mm</h3>")
        parts.append(_table([
            ["width mm: mean, smallest, largest", mid["mean_width_mm"], mid["width_min_mm"],
             mid["width_max_mm"]],
            ["height mm", mid["mean_height_mm"], mid["height_min_mm"], mid["height_max_mm"]],
            ["area mm²", mid["mean_area_mm2"], mid["area_min_mm2"], mid["area_max_mm2"]],
            ["rounded-rectangle width mm (mean area)", law, None, None],
            ["void fraction", mid["void_fraction"], None, mid["void_fraction_max"]]]))
    if gap:
        parts.append(f"<p class='sub'>{law_note(gap, config)}</p>")
    return "\n".join(parts)


def law_note(gap_mm: float, config: dict | None) -> str:
    """What the sections' width is compared with, and how far this solver's strands are from
    it (validation/strands)."""
    face = ((config or {}).get("scene_options") or {}).get("nozzle_tip_outer_diameter_mm")
    under = f"this run's nozzle face ({face:.3g} mm across)" if face else "a nozzle's flat face"
    return (f"Law: W = A/g + (1 − π/4) g with the bead's own area A and the layer height "
            f"g = {gap_mm:.3g} mm (the slicer's rounded rectangle; Comminal et al., Addit. Manuf. "
            f"20, 2018): a creeping strand that fills the gap under {under} leaves with a flat "
            "top at g. This solver's strands leave the face lower than g and wider than the law "
            "(validation/strands: the bundled bead at standard spacing +9 / +12 / +16 % under "
            "0.6 / 1.0 / 1.4 mm faces): the melt under the face's trailing half carries about "
            "three quarters of a full gap's flow. Whether a face that wide spreads a real strand "
            "so, or the solver does, is not yet settled.")


def lost_melt_where(summary: dict, key: str = "particles_lost") -> str:
    """Where and when melt was dropped (key 'particles_lost': only positions that are not
    finite are, e.g. '2 with a position not finite, t = 0.5-1.25 s') or outside the domain's
    box ('melt_outside_domain', e.g. '2 beyond top, 1 beyond x min, t = 0.5-1.25 s'); ''
    where the run recorded neither."""
    def where(face: str) -> str:
        if face == "not_finite":
            return "with a position not finite"
        return ("through " if key == "particles_lost" else "beyond ") + face.replace("_", " ")

    parts = [f"{n} {where(face)}" for face, n in (summary.get(f"{key}_by_face") or {}).items()]
    span = summary.get(f"{key}_between_s") or []
    if len(span) == 2:
        parts.append(f"t = {span[0]:.4g}-{span[1]:.4g} s")
    return ", ".join(parts)


#: the share of a run's melt over the nozzle's tip face at any step from which the command
#: line warns: a reporting choice (a bead's melt stays under the face; the blocks, printed
#: without retraction, reached 24-37 %, validation/blocks), not a physical limit
OVER_FACE_WARN = 0.01


def melt_over_face_text(summary: dict) -> str:
    """How much melt stood over the nozzle's tip face, most and at the last step with a
    nozzle, e.g. '23 % of the melt at t = 1.66 s, 11 % at t = 2.56 s'; '' where the run has
    no nozzle tip."""
    if "melt_over_face_fraction_max" not in summary:
        return ""
    most, end = summary["melt_over_face_fraction_max"], summary["melt_over_face_fraction"]
    if most == 0:
        return "none"
    return (f"{100 * most:.2g} % of the melt at t = {summary['melt_over_face_max_at_s']:.4g} s, "
            f"{100 * end:.2g} % at t = {summary['melt_over_face_at_s']:.4g} s")


def _outside(summary: dict) -> str:
    n = summary.get("melt_outside_domain_max", 0)
    where = lost_melt_where(summary, "melt_outside_domain")
    return f"{n}" + (f" ({where})" if where else "")


def _health(summary: dict) -> str:
    """The solver's figures this run recorded; a row whose figures the run did not record (a
    scheme without that solve) is left out."""
    def pct(key):
        value = summary.get(key)
        return None if value is None else f"{_num(100 * value, 3)} %"

    lost = summary.get("particles_lost", 0)
    where = lost_melt_where(summary)
    redone = summary.get("unconverged_solves_redone") or {}
    rows = [
        ["particles lost", [_verdict(not lost, f"{lost}" + (f" ({where})" if where else ""))]],
        ["melt outside the domain's box (kept): most at once",
         [_outside(summary) if "melt_outside_domain_max" in summary else None]],
        ["melt over the nozzle's tip face (carried up, or in its way): most / last", [_verdict(
            summary.get("melt_over_face_fraction_max", 0.0) < OVER_FACE_WARN,
            melt_over_face_text(summary)) if "melt_over_face_fraction_max" in summary else None]],
        ["deposited / commanded volume (mm³)",
         [_num(summary.get("deposited_volume_mm3")), _num(summary.get("commanded_volume_mm3"))]],
        ["density error, interior melt: mean / max",
         [pct("density_error_mean"), pct("density_error_max")]],
        ["compression, all melt: mean / max (end) / worst step",
         [pct("compression_error_mean"), pct("compression_error_max"),
          pct("compression_error_max_run")]],
        ["pressure / viscosity CG iterations per step",
         [_num(summary.get("pressure_iterations_per_step")),
          _num(summary.get("viscosity_iterations_per_step"))]],
        ["coupled solve: GMRES iterations per step / worst momentum residual / worst density "
         "error", [_num(summary.get("stokes_iterations_per_step")),
                   _num(summary.get("stokes_momentum_residual_worst")),
                   _num(summary.get("stokes_density_error_worst"))]],
        ["worst viscous residual", [_num(summary.get("viscosity_residual_worst"))]],
        ["unconverged solves (each step redone at half size)",
         [_verdict(not sum(redone.values()), ", ".join(f"{k} {v}" for k, v in redone.items()))
          if redone else None]],
        ["time-step halvings", [_num(summary.get("time_step_halvings"))]],
        ["paired fraction (SPH pairing)", [_num(summary.get("paired_fraction"))]],
    ]
    shown = [[label, " / ".join(v for v in values)] for label, values in rows
             if label == "particles lost"
             or all(v is not None and v != _num(None) for v in values)
             and not all(v == _num(0.0) for v in values)]
    return _table(shown)


def _thermal(summary: dict) -> str:
    keys = [k for k in summary if k.startswith(("temperature_", "cooling", "bead_cooling"))]
    if not keys:
        return "<p>Heat was off in this run.</p>"
    return _table([[k, summary[k]] for k in sorted(keys) if not isinstance(summary[k], (list, dict))])


def _estimate(summary: dict) -> str:
    est = summary.get("estimate") or {}
    rows = [["particles", est.get("particles"), summary.get("particles_active")],
            ["time steps", est.get("steps_estimate"), summary.get("steps")],
            ["wall time (s)", est.get("wall_time_estimate_s"), summary.get("wall_time_s")]]
    return _table(rows, ["", "estimated before the run", "measured"])


def _plan(plan: dict | None) -> str:
    if not plan:
        return "<p>No plan (not a G-code print).</p>"
    keep = ["gcode", "printer", "nozzle_diameter_mm", "print_time_s", "n_layers", "selected_layers",
            "selected_time_window_s", "selected_region_mm", "selected_extruded_volume_mm3",
            "extruded_volume_mm3"]
    return _table([[k, json.dumps(plan[k]) if isinstance(plan.get(k), list) else plan.get(k)]
                   for k in keep if k in plan])


def write_report(run_dir) -> Path:
    """Write ``run_dir/report.html`` from the run's files; returns its path."""
    run_dir = Path(run_dir)
    summary = read_json(run_dir / "summary.json") or {}
    config = read_json(run_dir / "config.json")
    plan = read_json(run_dir / "plan.json")
    meso = read_json(run_dir / "mesostructure.json")
    scene = summary.get("scene", (config or {}).get("scene", "?"))
    material = ((config or {}).get("material") or {}).get("name", "")
    state = ("interrupted" if summary.get("interrupted") else
             "failed: " + summary["error"] if summary.get("error") else "finished")
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>taichi_mex: {html.escape(run_dir.name)}"
             f"</title><style>{_CSS}</style></head><body>",
             f"<h1>{html.escape(run_dir.name)}</h1>",
             f"<p class='sub'>{html.escape(str(scene))} · {html.escape(material)} · "
             f"{html.escape(str(summary.get('scheme', '')))} at {_num(summary.get('spacing_mm'))} mm · "
             f"{_num(summary.get('simulated_time_s'))} s simulated in {_num(summary.get('wall_time_s'))} s"
             f" · {html.escape(state)}</p>"]
    pictures = sorted((run_dir / "snapshots").glob("final_*.png")) if (run_dir / "snapshots").is_dir() else []
    if pictures:
        parts.append("<h2>Snapshots</h2>" + "".join(_img(p, p.stem.replace("_", " ")) for p in pictures))
    parts.append("<h2>Bead shapes, necks and voids</h2>" + _sections(meso, plan, config))
    sections = sorted((run_dir / "sections").glob("*.png")) if (run_dir / "sections").is_dir() else []
    parts.extend(_img(p, f"cross-section {p.stem}") for p in sections)
    parts.append("<h2>Solver health</h2>" + _health(summary))
    parts.append("<h2>Heat</h2>" + _thermal(summary))
    plots = [p for p in sorted(run_dir.glob("*.png"))]
    if plots:
        parts.append("<h2>Plots</h2>" + "".join(_img(p, p.stem.replace("_", " ")) for p in plots))
    if (run_dir / "animation.gif").is_file():
        data = base64.b64encode((run_dir / "animation.gif").read_bytes()).decode()
        parts.append(f"<h2>Animation</h2><img src='data:image/gif;base64,{data}' alt='animation'>")
    elif (run_dir / "animation.mp4").is_file():
        data = base64.b64encode((run_dir / "animation.mp4").read_bytes()).decode()
        parts.append("<h2>Animation</h2><video controls loop width='720' "
                     f"src='data:video/mp4;base64,{data}'></video>")
    parts.append("<h2>Plan, and the estimate against what was measured</h2>" + _plan(plan) + _estimate(summary))
    parts.append("<h2>Configuration</h2><details><summary>config.json (re-run with "
                 "<code>python -m taichi_mex --config config.json --out DIR</code>)</summary><pre>"
                 + html.escape(json.dumps(config, indent=2)) + "</pre></details>")
    parts.append("<details><summary>summary.json</summary><pre>"
                 + html.escape(json.dumps(summary, indent=2, default=str)) + "</pre></details>")
    parts.append("</body></html>")
    path = run_dir / "report.html"
    path.write_text("\n".join(parts))
    return path


def write_index(out_dir, title: str, results_csv: Path, plots: list[Path]) -> Path:
    """A sweep's ``index.html``: the results table, its plots and links to each run's report."""
    out_dir = Path(out_dir)
    with Path(results_csv).open() as fh:
        rows = list(csv.DictReader(fh))
    head = list(rows[0].keys()) if rows else []
    body = ["<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>"]
    for row in rows:
        cells = []
        for h in head:
            text = html.escape(row.get(h, ""))
            if h == "run" and (out_dir / "runs" / row[h] / "report.html").is_file():
                text = f"<a href='runs/{text}/report.html'>{text}</a>"
            cells.append(f"<td>{text}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    body.append("</table>")
    page = (f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
            f"<style>{_CSS}</style></head><body><h1>{html.escape(title)}</h1>"
            f"<p class='sub'>{len(rows)} runs; each run's own report is linked from its name.</p>"
            + "\n".join(body) + "".join(_img(p, p.stem) for p in plots if p.is_file())
            + "</body></html>")
    path = out_dir / "index.html"
    path.write_text(page)
    return path
