"""Regenerate a validation case's measured table.

    python validation/regenerate.py --list
    python validation/regenerate.py CASE [--quick] [--out DIR] [--commands]
    python validation/regenerate.py --references

Each case runs taichi_mex's own command line (``python -m taichi_mex ...``, one process per
command, one command at a time), reads what the commands wrote (``summary.json``,
``trade.json``, ``stability.json``, ``bench.json``), builds a markdown table and rewrites the
text between ``<!-- table:begin -->`` and ``<!-- table:end -->`` in
``validation/CASE/README.md``, with the date, the machine and the exact commands.
``--quick`` runs coarse, short settings (about 1-3 minutes a case) to check the machinery;
its numbers are not the validation figures. ``--commands`` prints the commands and exits.

Plain Python (stdlib + numpy); the per-case description is the table ``CASES`` below.
"""

import argparse
import datetime
import json
import math
import os
import platform
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
BEGIN, END = "<!-- table:begin -->", "<!-- table:end -->"
QUIET = ["--no-snapshots", "--quiet"]


# ----------------------------------------------------------------------------- readers
def read_summary(out: Path) -> list[dict]:
    """One row: the run's summary.json."""
    return [json.loads((out / "summary.json").read_text())]


def read_study(out: Path) -> list[dict]:
    """One row per ladder run: trade.json's row over the run's own summary.json."""
    rows = []
    for k, row in enumerate(json.loads((out / "trade.json").read_text())):
        path = out / f"run{k:02d}" / "summary.json"
        summary = json.loads(path.read_text()) if path.exists() else {}
        rows.append({**summary, **{key: v for key, v in row.items() if v is not None}})
    return rows


def read_stability(out: Path) -> list[dict]:
    return json.loads((out / "stability.json").read_text())


def read_bench_collapse(out: Path) -> list[dict]:
    """Our row, then SPlisHSPlasH's (bench collapse), the latter with SPlisHSPlasH / ours."""
    result = json.loads((out / "bench.json").read_text())
    rows = [dict(result["ours"])] + ([dict(result["splishsplash"])] if result.get("splishsplash") else [])
    return [{**r, "label": r["code"]} for r in rows]


def inner_choice(r: dict) -> str:
    """Our coupled solve's iterations a step and how many solves each inner operator served."""
    solves = r.get("stokes_inner_operator_solves") or {}
    if r.get("code") != "taichi_mex" or r.get("stokes_iterations_per_step") is None:
        return ""
    return (f"{r['stokes_iterations_per_step']:.0f} / {r['stokes_inner_iterations_per_step']:.0f}; "
            f"{solves.get('weiler2018', 0)} / {solves.get('system', 0)}")


def read_bench(out: Path) -> list[dict]:
    """Our row, then PySPH's runs of the same command (OpenMP, one core), each with ours / it."""
    result = json.loads((out / "bench.json").read_text())
    return [dict(result["ours"])] + [dict(r) for r in result.get("pysph") or []]


def read_summary_or_bench(out: Path) -> list[dict]:
    """A run's summary.json, or our row of ``bench dam-break`` (its keys named as a summary's)."""
    if (out / "bench.json").exists():
        r = read_bench(out)[0]
        return [{**r, "particles_active": r["particles"], "wall_time_s": r["wall_s"],
                 "cpu_threads": r["threads"] if r.get("arch") == "cpu" else None}]
    return read_summary(out)


# ----------------------------------------------------------------------------- columns
def pct(key, digits=1):
    return lambda r: "" if r.get(key) is None else f"{100 * r[key]:.{digits}f} %"


def num(key, fmt="{:,.0f}"):
    return lambda r: "" if r.get(key) is None else fmt.format(r[key])


def ratio_to(key, ref, fmt="{:.3f}"):
    """value / reference and its deviation, e.g. '0.550 (+22 %)'."""
    def cell(r):
        v, w = r.get(key), ref(r)
        if v is None or not w:
            return ""
        return f"{fmt.format(v)} ({100 * (v / w - 1):+.0f} %)"
    return cell


def slicer_width_mm(area_mm2: float, gap_mm: float) -> float:
    """The slicer's rounded rectangle (Comminal et al., Addit. Manuf. 20, 2018):
    W = A / g + (1 - pi / 4) g."""
    return area_mm2 / gap_mm + (1.0 - math.pi / 4.0) * gap_mm


#: the bundled single bead: 0.45 mm x 0.2 mm rounded rectangle, A = (W - g) g + pi g^2 / 4
BEAD_GAP_MM = 0.2
BEAD_AREA_MM2 = (0.45 - BEAD_GAP_MM) * BEAD_GAP_MM + math.pi * BEAD_GAP_MM**2 / 4.0

COMMON = [("particles", num("particles_active")), ("steps", num("steps")),
          ("wall s", num("wall_time_s"))]
BEAD = [("material area mm^2 (commanded %.4f)" % BEAD_AREA_MM2,
         ratio_to("bead_material_area_mm2", lambda r: BEAD_AREA_MM2, "{:.4f}")),
        ("section W mm (rounded rectangle %.3f)" % slicer_width_mm(BEAD_AREA_MM2, BEAD_GAP_MM),
         ratio_to("bead_width_mm", lambda r: slicer_width_mm(BEAD_AREA_MM2, BEAD_GAP_MM))),
        ("section H mm (gap 0.2)", ratio_to("bead_height_mm", lambda r: BEAD_GAP_MM)),
        ("p99 W / H mm", lambda r: f"{r['bead_width_p99_mm']:.3f} / {r['bead_height_p99_mm']:.3f}"
         if r.get("bead_width_p99_mm") else "")]


def _interior_density(r: dict) -> str:
    """|rho / rho0 - 1| over the melt whose kernel is full, with how many particles that is;
    a melt with none (a current one or two particles thick) is read whole, surface and all,
    and says so."""
    if r.get("density_error_mean") is None:
        return ""
    text = f"{100 * r['density_error_mean']:.2f} % / {100 * r['density_error_max']:.1f} %"
    n = r.get("interior_particles")
    if n is None:
        return text
    return f"{text} ({n:,})" if n else f"{text} (no interior: all melt)"


DENSITY = [("compression end max / worst step", lambda r: f"{100 * r['compression_error_max']:.2f} % / "
            f"{100 * r.get('compression_error_max_run', float('nan')):.2f} %"
            if r.get("compression_error_max") is not None else ""),
           ("interior density mean / max", _interior_density),
           ("paired melt", pct("paired_fraction")), ("section voids", pct("void_fraction", 0))]
CG = [("pressure / divergence / viscosity CG per step",
       lambda r: "/".join(f" {r.get(k, 0) or 0:.1f} " for k in (
           "pressure_iterations_per_step", "divergence_iterations_per_step",
           "viscosity_iterations_per_step")).strip())]
LOSSES = [("particles lost", lambda r: f"{r.get('particles_lost', 0)}"),
          ("halvings / worst viscous residual",
           lambda r: f"{r.get('time_step_halvings', 0)} / "
           f"{r.get('viscosity_residual_worst', float('nan')):.2g}")]


# ----------------------------------------------------------------------------- cases
@dataclass
class Case:
    what: str
    #: (label, arguments after 'python -m taichi_mex'[, parameters the columns read from the
    #: row]); '{out}' is the run's output folder
    runs: list
    quick: list
    columns: list
    read: object = read_summary
    rows: list = field(default_factory=list)
    #: the README folder under validation/ (default: the case's name) and the table's tag in
    #: its markers (<!-- table:begin:TAG -->), for a second table in one README
    folder: str | None = None
    tag: str = ""
    #: rows -> rows once every run is read (figures that compare runs, e.g. CPU / GPU)
    finish: object = None
    #: wall seconds a run may take before it is stopped and reported as such (None: no limit)
    timeout_s: float | None = None
    #: pictures the pages show, copied from the runs after a full (not --quick) regeneration:
    #: (run index, file in its folder (a glob; the last match in sorted order), destination
    #: relative to the repository)
    figures: list = field(default_factory=list)


def strain_ratio(strain):
    """The extension's mid radius over R0 exp(-e t / 2) at the sample nearest a strain."""
    def cell(r):
        t = r.get("t_s") or []
        if not t or r["strain_rate_1_s"] * t[-1] < strain - 1e-6:
            return ""
        k = min(range(len(t)), key=lambda i: abs(r["strain_rate_1_s"] * t[i] - strain))
        return f"{r['mid_radius_ratio'][k] / r['reference_ratio'][k]:.3f}"
    return cell


def scene(name, *args):
    return ["scene", name, *map(str, args), *QUIET, "--out", "{out}"]


def bead(*args):
    """A print as it runs by default. These tables measured the split creeping solve until
    2026-12-05, when the split solve's creeping stabilisers went and it began to refuse a
    creeping melt; regenerated, they measure the coupled solve."""
    return [*map(str, args), *QUIET, "--out", "{out}"]


def strand(gap_mm, width_mm, *args):
    """A single bead: the bundled one (0.2 mm gap, 0.45 mm width) or one of the generated
    lines in validation/strands/gcode, coupled solve without the surface traction."""
    gcode = ("single_bead.gcode" if (gap_mm, width_mm) == (0.2, 0.45)
             else f"validation/strands/gcode/gap{gap_mm:.2f}_width{width_mm:.2f}.gcode")
    return [gcode, "--creeping-solve", "coupled", "--no-surface-traction", *map(str, args),
            *QUIET, "--out", "{out}"]


def strand_run(gap_mm, width_mm, resolution):
    """A coupled strand's (label, arguments, parameters): the columns read gap and width from
    the parameters, the label shows the same numbers."""
    return (f"gap {gap_mm:.2f}, width {width_mm:.2f}, {resolution}",
            strand(gap_mm, width_mm, "--resolution", resolution),
            {"gap_mm": gap_mm, "width_mm": width_mm})


#: (gap mm, line width mm, resolution) of the coupled strands; at a 0.1 mm gap draft's
#: 0.067 mm is refused (under 2 particles per layer): 0.05 mm is the coarsest allowed
STRANDS = [(0.2, 0.45, "draft"), (0.2, 0.45, "standard"), (0.1, 0.4, 0.05),
           (0.1, 0.6, 0.05), (0.15, 0.5, "draft"), (0.2, 0.6, "draft"), (0.2, 0.7, "draft")]

#: (gap mm, line width mm, resolution) of the density-source comparison
SOURCE_STRANDS = [(0.2, 0.45, "standard"), (0.2, 0.6, "standard"), (0.15, 0.5, 0.05),
                  (0.1, 0.4, 0.05), (0.1, 0.6, 0.05), (0.2, 0.7, "draft")]

#: the coupled solve's cost and health, per step
COUPLED_SOLVE = [
    ("GMRES / inner CG per step", lambda r: f"{r.get('stokes_iterations_per_step', 0):.0f} / "
     f"{r.get('stokes_inner_iterations_per_step', 0):.0f}"),
    ("particles lost / halvings", lambda r: f"{r.get('particles_lost', '')} / "
     f"{r.get('time_step_halvings', '')}")]

#: the collapse's front against Huppert's similarity solution
HUPPERT = [("coefficient ratio K^(1/8) / Huppert", num("front_coefficient_ratio", "{:.3f}")),
           ("radius ratio, second half", num("front_ratio_late", "{:.3f}")),
           ("growth exponent, last decade (1/8 = 0.125)", num("front_exponent_late", "{:.3f}")),
           ("virtual origin s", num("front_virtual_origin_s", "{:.2f}"))]


def _strand_of(r) -> tuple[float, float]:
    return r["gap_mm"], r["width_mm"]


def _strand_area(r) -> float:
    g, w = _strand_of(r)
    return (w - g) * g + math.pi * g * g / 4.0


STRAND = [("material area / commanded", ratio_to("bead_material_area_mm2", _strand_area, "{:.4f}")),
          ("W mm (nine sections) / rounded rectangle", ratio_to(
              "bead_width_mm", lambda r: slicer_width_mm(_strand_area(r), _strand_of(r)[0]))),
          ("H mm (nine sections) / gap", ratio_to("bead_height_mm", lambda r: _strand_of(r)[0])),
          ("p99 W / H mm", lambda r: f"{r['bead_width_p99_mm']:.3f} / {r['bead_height_p99_mm']:.3f}"
           if r.get("bead_width_p99_mm") else ""),
          # issue 15's flat-top test: every column of the middle half within 10 % of the gap,
          # their median within 5 % (over the nine sections: lowest, mean median, highest)
          ("top of the middle half, min / median / max vs gap", lambda r: " / ".join(
              f"{r['bead_' + k] / _strand_of(r)[0] - 1:+.0%}"
              for k in ("top_min_mm", "top_median_mm", "top_max_mm"))
           if r.get("bead_top_min_mm") is not None else "")]

HYDRO = ("--width-mm", 8, "--height-mm", 12)
SHEAR = ("--length-mm", 6, "--height-mm", 3, "--plate-speed", 0.01, "--until", 0.01)
CYLINDER = ("--radius-mm", 4, "--height-mm", 4, "--density", 1000)
COLLAPSE = (*CYLINDER, "--viscosity", 10)
#: the coupled collapse across viscosities: the same shapes at the same eta-scaled time
#: t rho g H / eta (30 s at 10 Pa s); (spacing mm, eta Pa s, run s)
COUPLED_COLLAPSES = ((0.5, 1, 3), (0.5, 10, 30), (0.5, 1000, 3000))
BLOCK = ("gcode/paper_block_3x3.gcode",)
#: the same 3 x 3 block at a real printer's gaps: 0.2 mm layers, 0.45 mm lines
REAL_BLOCK = ("gcode/block_3x3.gcode",)

COUPLED_STRAND = COMMON + STRAND + DENSITY[:2] + COUPLED_SOLVE

#: a real slicer's part: PrusaSlicer's benchy from pyGCodeDecode's examples, layer 3, at draft
BENCHY = ("pygcodedecode:benchy", "--layers", 3, "--resolution", "draft")
#: where the windows start (print time, s; the plan prints them), for the quick runs' first second
BENCHY_4MM_START_S = 175.75
BENCHY_10MM_START_S = 153.53


def window(region, *args, pictures=False):
    """Benchy's layer 3 in a window of the bed; ``pictures``: with the run's snapshots."""
    quiet = ["--quiet"] if pictures else QUIET
    return [*map(str, BENCHY), "--region", region, *map(str, args), *quiet, "--out", "{out}"]


def _deposited(r) -> str:
    """The window's melt (the substrate below the layer, printed before the run, not counted)
    against the plan's commanded extrusion."""
    if not r.get("commanded_volume_mm3"):
        return ""
    melt, cmd = r["deposited_volume_mm3"], r["commanded_volume_mm3"]
    return f"{melt:.4f} / {cmd:.4f} ({100 * (melt / cmd - 1):+.1f} %)"


def _over_face(r) -> str:
    """The most melt over the nozzle's tip face at any step (when), and at the last step with a
    nozzle, in per cent of the run's melt; '' for a run that did not record it."""
    if "melt_over_face_fraction_max" not in r:
        return ""
    if not r["melt_over_face_fraction_max"]:
        return "0 / 0 %"
    return (f"{100 * r['melt_over_face_fraction_max']:.1f} % ({r['melt_over_face_max_at_s']:.2f}) / "
            f"{100 * r['melt_over_face_fraction']:.1f} %")


def _outside(r) -> str:
    """The most melt outside the domain's box at once (kept since 2026-12-07; dropped and
    counted as lost before), with its faces; '' for a run that did not record it."""
    if "melt_outside_domain_max" not in r:
        return ""
    faces = ", ".join(f"{n} {f.replace('_', ' ')}"
                      for f, n in (r.get("melt_outside_domain_by_face") or {}).items())
    return f"{r['melt_outside_domain_max']}" + (f" ({faces})" if faces else "")


def _estimate_over_wall(r) -> str:
    """The estimate printed before the run over the run's wall time ('-' where there is none)."""
    wall = (r.get("estimate") or {}).get("wall_time_estimate_s")
    return f"{wall / r['wall_time_s']:.2f}" if wall and r.get("wall_time_s") else "-"


WINDOW = COMMON + [
    ("window s / skipped s", lambda r: f"{r['simulated_time_s']:.2f} / {r.get('skipped_time_s', 0):.2f}"),
    ("melt deposited / commanded mm^3", _deposited),
    ("estimate / measured: steps, wall", lambda r: (
        f"{r['estimate']['steps_estimate'] / r['steps']:.2f}, " + _estimate_over_wall(r))
     if r.get("estimate") and r.get("steps") else ""),
    ("melt particle-steps/s", num("melt_particle_steps_per_s")),
    ("fastest melt m/s; steps at 2-4x / >4x the nozzle", lambda r: (
        f"{r['melt_speed_max_m_s']:.3f}; {r['melt_faster_than_walls_steps']['2-4x']:,} / "
        f"{r['melt_faster_than_walls_steps']['>4x']:,}") if r.get("melt_faster_than_walls_steps") else ""),
    ("melt over the nozzle's face: most (t s) / last", _over_face),
    ("melt outside the domain, most", _outside),
    ] + LOSSES[:1] + COUPLED_SOLVE

#: issue 15's blocks: to the end, nothing lost, every solve converged, sections without voids,
#: bead heights within 10 % of the layer; and the estimate printed before the run
BLOCKS = COMMON + [
    ("estimate / measured wall", _estimate_over_wall),
    ("melt deposited / commanded mm^3", _deposited),
    ("section W / H mm (nine sections)", lambda r: f"{r.get('bead_width_mm') or float('nan'):.3f} / "
     f"{r.get('bead_height_mm') or float('nan'):.3f}"),
    ("section voids", pct("void_fraction", 0)),
    # melt over the nozzle's tip face: carried up on it, or laid over the layer it prints
    ("melt over the nozzle's face: most (t s) / last", _over_face),
    ("melt outside the domain, most", _outside),
    ("fastest melt m/s", num("melt_speed_max_m_s", "{:.3f}")),
    ("worst viscous residual", num("viscosity_residual_worst", "{:.2g}")),
    ] + COUPLED_SOLVE


def on_both(label, args, params=None):
    """The same command on the CPU (every core) and on the GPU: two runs, paired by label."""
    return [(f"{label}, {arch}", [*args, "--arch", arch], {**(params or {}), "pair": label})
            for arch in ("cpu", "gpu")]


def cpu_over_gpu(rows: list[dict]) -> list[dict]:
    """Each GPU row gets the CPU row's wall time and particle-steps/s over its own."""
    cpu = {r["pair"]: r for r in rows if r.get("arch") == "cpu" and "failure" not in r}
    for r in rows:
        c = cpu.get(r.get("pair"))
        if r.get("arch") in ("cuda", "vulkan") and c and r.get("wall_time_s"):
            r["speedup_wall"] = c["wall_time_s"] / r["wall_time_s"]
            if c.get("particle_steps_per_s"):
                r["speedup_rate"] = r["particle_steps_per_s"] / c["particle_steps_per_s"]
    return rows


def _melt_check(r) -> str:
    """What says the GPU run is the same physics: melt deposited against commanded, lost
    particles, the bead's section where there is one."""
    out = []
    if r.get("commanded_volume_mm3"):
        out.append(f"melt {r['deposited_volume_mm3'] / r['commanded_volume_mm3'] - 1:+.2%}")
    if r.get("particles_lost") is not None:
        out.append(f"lost {r['particles_lost']}")
    if r.get("bead_width_mm"):
        out.append(f"W / H {r['bead_width_mm']:.3f} / {r['bead_height_mm']:.3f} mm")
    if r.get("stokes_iterations_per_step"):
        out.append(f"{r['stokes_iterations_per_step']:.0f} / {r['stokes_inner_iterations_per_step']:.0f} its")
    if r.get("max_speed_m_s") is not None:
        out.append(f"max speed {r['max_speed_m_s']:.3g} m/s")
    return ", ".join(out)


GPU = [("run", lambda r: r["label"]),
       ("ran on", lambda r: (r.get("arch") or "") + (f", {r['cpu_threads']} threads" if r.get("cpu_threads") else "")),
       ("particles", num("particles_active")), ("steps", num("steps")),
       ("wall s (compile included)", num("wall_time_s", "{:.3g}")),
       ("M particle-steps/s", lambda r: f"{r['particle_steps_per_s'] / 1e6:.3f}" if r.get("particle_steps_per_s") else ""),
       ("GPU speed-up: wall, particle-steps/s", lambda r: f"{r['speedup_wall']:.2f}x, {r['speedup_rate']:.2f}x"
        if r.get("speedup_rate") else ""),
       ("solve / neighbours / output s (`--profile`)", lambda r: " / ".join(
           f"{r['phase_seconds'].get(k, 0):.1f}" for k in ("coupled solve", "neighbour search",
                                                           "output and checkpoint"))
        if r.get("phase_seconds") else ""),
       ("same physics?", _melt_check)]

#: both collapse comparisons' --quick run: the machinery on a coarse, short case
PEER_COLLAPSE_QUICK = [("collapse, 0.8 mm, 0.1 s", ["bench", "collapse", "--spacing-mm", 0.8,
                                                    "--until", 0.1, "--json", "{out}/bench.json"])]

PEER_COLLAPSE_COLUMNS = [
    ("code", lambda r: r["code"] + (" **(stopped)**" if r.get("stopped") else "")),
    ("particles", num("particles")), ("steps", num("steps")),
    ("simulated s", num("simulated_s", "{:.3g}")),
    ("wall s", num("wall_s", "{:.1f}")), ("CPU s", num("cpu_s", "{:.1f}")),
    ("other processes' CPU s", num("others_cpu_s", "{:.1f}")),
    ("Huppert K^(1/8) ratio", num("huppert_coefficient_ratio", "{:.3f}")),
    ("radius ratio, second half", num("huppert_radius_ratio_late", "{:.3f}")),
    ("SPlisHSPlasH / ours wall", num("ratio", "{:.1f}x"))]

CASES = {
    "hydrostatic": Case(
        "water-like column (8 x 8 x 12 mm) at rest: slab-mean pressure against rho g depth",
        [(f"{s} {dx} mm", scene("hydrostatic", *HYDRO, "--scheme", s, "--spacing-mm", dx, "--until", 0.6))
         for s, dx in (("edac", 1), ("edac", 0.667), ("dfsph", 1), ("dfsph", 0.667), ("dfsph", 0.5))],
        [(f"{s} 1.5 mm", scene("hydrostatic", *HYDRO, "--scheme", s, "--spacing-mm", 1.5, "--until", 0.1))
         for s in ("edac", "dfsph")],
        COMMON + [("slope error", pct("pressure_gradient_rel_error")),
                  ("mean error / rho g H", pct("pressure_error_rel_mean")),
                  ("max error / rho g H", pct("pressure_error_rel_max")),
                  ("particles lost", num("particles_lost"))]),
    "shear": Case(
        "Stokes' first problem: u(z) against U erfc(z / (2 sqrt(nu t))) after 0.01 s",
        [(f"{dx} mm {p}", scene("shear", *SHEAR, "--spacing-mm", dx, "--precision", p))
         for dx, p in ((0.4, "f32"), (0.3, "f32"), (0.2, "f32"), (0.2, "f64"), (0.15, "f32"))],
        [(f"{dx} mm f32", scene("shear", *SHEAR, "--spacing-mm", dx)) for dx in (0.4, 0.3)],
        COMMON + [("max error / U", pct("shear_error_max_rel_U")),
                  ("mean error / U", pct("shear_error_mean_rel_U"))]),
    "collapse": Case(
        "4 mm x 4 mm cylinder, 10 Pa s, 1000 kg/m^3, slumping on a no-slip plate, against Huppert (1982)",
        [(f"{dx} mm, {t} s", scene("collapse", *COLLAPSE, "--spacing-mm", dx, "--until", t))
         for dx, t in ((0.5, 12), (0.5, 30), (0.4, 30), (0.3, 30))],
        [("0.8 mm, 6 s", scene("collapse", *COLLAPSE, "--spacing-mm", 0.8, "--until", 6)),
         ("0.6 mm, 6 s", scene("collapse", *COLLAPSE, "--spacing-mm", 0.6, "--until", 6))],
        COMMON + HUPPERT),
    "collapse_coupled": Case(
        "the same cylinder with the coupled creeping solve (viscous stress and pressure in one "
        "solve, the free surface's traction, nothing deleted or clamped)",
        [(f"{dx} mm, {eta} Pa s, {t} s, coupled", scene(
            "collapse", *CYLINDER, "--viscosity", eta, "--spacing-mm", dx, "--until", t,
            "--creeping-solve", "coupled")) for dx, eta, t in COUPLED_COLLAPSES],
        [("0.8 mm, 6 s, coupled", scene("collapse", *COLLAPSE, "--spacing-mm", 0.8, "--until", 6,
                                         "--creeping-solve", "coupled"))],
        COMMON + HUPPERT + COUPLED_SOLVE,
        folder="collapse", tag="coupled"),
    "collapse_source": Case(
        "the coupled collapse with the continuity source one way (compression only) and two ways "
        "on interior particles (--density-source two-way): a thinning current's interior sums",
        [(f"{dx} mm, {eta} Pa s, {t} s, {source}", scene(
            "collapse", *CYLINDER, "--viscosity", eta, "--spacing-mm", dx, "--until", t,
            "--creeping-solve", "coupled", "--density-source", source))
         for dx, eta, t in (*COUPLED_COLLAPSES, (0.3, 10, 30)) for source in ("summation", "two-way")],
        [(f"0.8 mm, 6 s, {source}", scene("collapse", *COLLAPSE, "--spacing-mm", 0.8, "--until", 6,
                                           "--creeping-solve", "coupled", "--density-source", source))
         for source in ("summation", "two-way")],
        COMMON + HUPPERT + DENSITY[1:2] + COUPLED_SOLVE,
        folder="collapse", tag="source"),
    "collapse_coupled_fine": Case(
        "the coupled collapse at finer spacings (10 Pa s, 30 s), where the split solve blows up",
        [(f"{dx} mm, 10 Pa s, 30 s, coupled", scene(
            "collapse", *CYLINDER, "--viscosity", 10, "--spacing-mm", dx, "--until", 30,
            "--creeping-solve", "coupled")) for dx in (0.4, 0.3)],
        [("0.6 mm, 10 Pa s, 6 s, coupled", scene(
            "collapse", *CYLINDER, "--viscosity", 10, "--spacing-mm", 0.6, "--until", 6,
            "--creeping-solve", "coupled"))],
        COMMON + HUPPERT + COUPLED_SOLVE,
        folder="collapse", tag="coupled_fine"),
    "collapse_coupled_02": Case(
        "the issue's 0.2 mm collapse (R = H = 4 mm, 1 Pa s, 3 s), the inner viscous solve on the "
        "system's own block (--stokes-inner-operator system)",
        [("0.2 mm, 1 Pa s, 3 s, coupled, inner: system", scene(
            "collapse", *CYLINDER, "--viscosity", 1, "--spacing-mm", 0.2, "--until", 3,
            "--stokes-inner-operator", "system"))],
        [("0.5 mm, 1 Pa s, 0.5 s, coupled, inner: system", scene(
            "collapse", *CYLINDER, "--viscosity", 1, "--spacing-mm", 0.5, "--until", 0.5,
            "--stokes-inner-operator", "system"))],
        COMMON + HUPPERT + COUPLED_SOLVE,
        folder="collapse", tag="coupled_02"),
    "windows": Case(
        "a real slicer's part: benchy (PrusaSlicer, pyGCodeDecode's example), layer 3, the 4 x 4 mm "
        "window 88-92 mm x 88-92 mm at draft, the coupled solve (the split one, measured beside it "
        "until 2026-12-05, now refuses a creeping melt)",
        [("benchy 4 x 4 mm, coupled", window("88:92,88:92", "--creeping-solve", "coupled",
                                             "--no-surface-traction", pictures=True)),
         ("benchy 4 x 4 mm, coupled, dt x2", window("88:92,88:92", "--creeping-solve", "coupled",
                                                    "--no-surface-traction", "--dt-factor", 2))],
        [("benchy 4 x 4 mm, first second, coupled", window(
            "88:92,88:92", "--until", BENCHY_4MM_START_S + 1, "--creeping-solve", "coupled",
            "--no-surface-traction"))],
        WINDOW, figures=[(0, f"snapshots/final_{view}.png", f"validation/windows/figures/benchy_4mm_{view}.png")
                         for view in ("oblique", "top", "section")]
        + [(0, "sections/section_00.png", "validation/windows/figures/benchy_4mm_analysed_section.png")]),
    "windows_10mm": Case(
        "the same part's 10 x 10 mm window (85-95 mm x 85-95 mm), layer 3, draft, coupled solve",
        [("benchy 10 x 10 mm, coupled", window("85:95,85:95", "--creeping-solve", "coupled",
                                               "--no-surface-traction"))],
        [("benchy 10 x 10 mm, first second, coupled", window(
            "85:95,85:95", "--until", BENCHY_10MM_START_S + 1, "--creeping-solve", "coupled",
            "--no-surface-traction"))],
        WINDOW, folder="windows", tag="10mm"),
    "gpu": Case(
        "the same commands on the CPU (every core) and the GPU, one after the other on one machine: "
        "the dam break's EDAC (143k particles, 100 steps), the bundled bead at draft, benchy's 4 x 4 mm "
        "window's first second and the unscaled paper block to print time 0.8 s (coupled solve)",
        on_both("dam break EDAC", ["bench", "dam-break", "--no-pysph", "--json", "{out}/bench.json"])
        + on_both("bead, draft", strand(0.2, 0.45, "--resolution", "draft", "--profile"))
        + on_both("benchy 4 x 4 mm, first second", window(
            "88:92,88:92", "--until", BENCHY_4MM_START_S + 1, "--creeping-solve", "coupled",
            "--no-surface-traction"))
        + on_both("paper block, draft, unscaled, to 0.8 s", [
            *BLOCK, "--resolution", "draft", "--viscosity-scale", "off", "--until", 0.8, *QUIET,
            "--out", "{out}"]),
        on_both("dam break EDAC, dx 0.04, 10 steps", ["bench", "dam-break", "--no-pysph", "--dx", 0.04,
                                                       "--steps", 10, "--json", "{out}/bench.json"])
        + on_both("bead, 0.1 mm", strand(0.2, 0.45, "--resolution", 0.1)),
        GPU, read=read_summary_or_bench, finish=cpu_over_gpu, timeout_s=300),
    "thermal_beam": Case(
        "the seed paper's aluminium beam, 50 s: centre-line temperature against the analytic "
        "series (a) and a finite-volume solution with losses (b)",
        [(f"(a) conduction, {dx} mm", scene("thermal-beam", "--no-losses", "--spacing-mm", dx))
         for dx in (4, 2)]
        + [(f"(b) {m}, {dx} mm", scene("thermal-beam", "--surface-method", m, "--spacing-mm", dx))
           for dx in (4, 2) for m in ("eigenvalue", "colour_gradient")],
        [("(a) conduction, 4 mm, 10 s", scene("thermal-beam", "--no-losses", "--spacing-mm", 4, "--until", 10))]
        + [(f"(b) {m}, 4 mm, 10 s", scene("thermal-beam", "--surface-method", m, "--spacing-mm", 4,
                                          "--until", 10)) for m in ("eigenvalue", "colour_gradient")],
        COMMON + [("max error K", num("thermal_error_max_c", "{:.2f}")),
                  ("rms error K", num("thermal_error_rms_c", "{:.2f}")),
                  ("area / true area", num("surface_area_ratio", "{:.3f}")),
                  ("reference", lambda r: r.get("thermal_reference", ""))]),
    "strands": Case(
        "the bundled single bead (0.2 mm gap, 0.4 mm nozzle, 60 mm/s, PLA 1000 Pa s, DFSPH): "
        "section against the commanded area and the slicer's rounded rectangle",
        # the default runs the real viscosity (since 2026-12-06); x 0.0127 is what the retired
        # 'auto' scaling gave this bead
        [(f"{res}{', viscosity x 0.0127' if thin else ''}",
          bead("--resolution", res, *(["--viscosity-scale", 0.0127] if thin else [])))
         for res, thin in (("draft", False), ("standard", False), ("standard", True), ("fine", False))],
        [("0.1 mm", bead("--resolution", 0.1))],
        COMMON + BEAD + DENSITY),
    "pictures": Case(
        "the default run (`python -m taichi_mex --out DIR`: the bundled bead at standard, the "
        "coupled solve at the melt's real viscosity) with snapshots every 0.05 s: the README's "
        "pictures",
        [("default run, standard", ["--snapshot-every", 0.05, "--quiet", "--out", "{out}"])],
        [("default run at 0.1 mm", ["--resolution", 0.1, "--quiet", "--out", "{out}"])],
        COMMON + BEAD, folder="strands", tag="pictures",
        figures=[(0, "snapshots/t0.36*_oblique.png", "examples/figures/default_deposition.png"),
                 (0, "snapshots/final_oblique.png", "examples/figures/default_oblique.png"),
                 (0, "snapshots/final_section.png", "examples/figures/default_section.png"),
                 (0, "sections/section_00.png", "examples/figures/default_analysed_section.png")]),
    "strands_coupled": Case(
        "single beads of six gap / line-width combinations under the 0.4 mm nozzle (60 mm/s, "
        "PLA 1000 Pa s), coupled solve without the free surface's traction: section against "
        "the commanded area and the slicer's rounded rectangle",
        [strand_run(g, w, res) for g, w, res in STRANDS], [strand_run(0.2, 0.45, 0.1)],
        COUPLED_STRAND,
        folder="strands", tag="coupled"),
    "strands_convergence": Case(
        "the bundled bead (0.2 mm gap, 0.45 mm line) at draft / standard / fine, coupled solve "
        "without the free surface's traction: does the section converge on the rounded rectangle?",
        [strand_run(0.2, 0.45, res) for res in ("draft", "standard", "fine")],
        [strand_run(0.2, 0.45, 0.1)],
        COUPLED_STRAND,
        folder="strands", tag="convergence"),
    "strands_step": Case(
        "the bundled bead at draft, coupled solve, at half, once and twice the CFL step "
        "(--dt-factor): how much of the section is the time step's",
        [(f"draft, dt x {f:g}", strand(0.2, 0.45, "--resolution", "draft", "--dt-factor", f),
          {"gap_mm": 0.2, "width_mm": 0.45}) for f in (0.5, 1, 2)],
        [(f"0.1 mm, dt x {f:g}", strand(0.2, 0.45, "--resolution", 0.1, "--dt-factor", f),
          {"gap_mm": 0.2, "width_mm": 0.45}) for f in (1, 2)],
        COUPLED_STRAND,
        folder="strands", tag="step"),
    "strands_source": Case(
        "the continuity source one way (compression only, --density-source summation) and two "
        "ways on interior particles (--density-source two-way), at the print's step and twice "
        "it, on strands across gaps and line widths: does correcting the interior's expansion "
        "change the section, and what does it cost?",
        [(f"gap {g:.2f}, width {w:.2f}, {res}, {source}, dt x{f}",
          strand(g, w, "--resolution", res, "--density-source", source, "--dt-factor", f),
          {"gap_mm": g, "width_mm": w})
         for g, w, res in SOURCE_STRANDS for f in (1, 2) for source in ("summation", "two-way")],
        [(f"0.1 mm, {source}", strand(0.2, 0.45, "--resolution", 0.1, "--density-source", source),
          {"gap_mm": 0.2, "width_mm": 0.45}) for source in ("summation", "two-way")],
        COUPLED_STRAND, folder="strands", tag="source"),
    "strands_viscosity": Case(
        "coupled strands at the real viscosity against the creeping-flow scaling 'auto' gave "
        "them until 2026-12-06 (x 0.0127 for the bundled bead, x 0.0143 for the other lines): "
        "does the shape depend on the viscosity, and what does each cost?",
        [(f"gap {g:.2f}, width {w:.2f}, {res if isinstance(res, str) else f'{res} mm'}, {label}",
          strand(g, w, "--resolution", res, "--viscosity-scale", scale),
          {"gap_mm": g, "width_mm": w})
         for g, w, res, auto in ((0.2, 0.45, "draft", 0.0127), (0.2, 0.45, "standard", 0.0127),
                                 (0.15, 0.5, "draft", 0.0143), (0.1, 0.4, 0.05, 0.0143),
                                 (0.2, 0.7, "draft", 0.0143))
         for label, scale in (("scaled", auto), ("real viscosity", "off"))],
        [(f"0.1 mm, {label}", strand(0.2, 0.45, "--resolution", 0.1, "--viscosity-scale", scale),
          {"gap_mm": 0.2, "width_mm": 0.45}) for label, scale in (("scaled", 0.0127),
                                                                   ("real viscosity", "off"))],
        COUPLED_STRAND + [("viscosity x", num("viscosity_scale", "{:.3g}"))],
        folder="strands", tag="viscosity"),
    "strands_surface_rows": Case(
        "the free surface's rows under the pair sum: continuity (a print's default) against "
        "the traction-free condition -p + 2 mu n.D.n = 0 (--surface-rows traction), the "
        "bundled bead at draft and standard: does the surface's pull widen the strand?",
        [(f"gap 0.20, width 0.45, {res}, {rows}",
          strand(0.2, 0.45, "--resolution", res, "--surface-rows", rows),
          {"gap_mm": 0.2, "width_mm": 0.45})
         for res in ("draft", "standard") for rows in ("continuity", "traction")],
        [(f"0.1 mm, {rows}", strand(0.2, 0.45, "--resolution", 0.1, "--surface-rows", rows),
          {"gap_mm": 0.2, "width_mm": 0.45}) for rows in ("continuity", "traction")],
        COUPLED_STRAND, folder="strands", tag="surface_rows"),
    "strands_face": Case(
        "coupled strands under nozzle faces of 0.6, 1.0 (the default) and 1.4 mm outer diameter "
        "and none (the bore's wall alone): the melt spreads under the face before it leaves, so "
        "does the strand's section follow the face, which the slicer's rounded rectangle knows "
        "nothing of?",
        [(f"gap {g:.2f}, width {w:.2f}, {res}, face {face}",
          strand(g, w, "--resolution", res, "--nozzle-tip-mm", face),
          {"gap_mm": g, "width_mm": w, "face_mm": face})
         for g, w, res, faces in ((0.2, 0.45, "standard", ("none", 0.6, 1.0, 1.4)),
                                  (0.2, 0.6, "standard", (0.6, 1.0, 1.4)),
                                  (0.2, 0.45, "fine", (0.6,)))
         for face in faces],
        [(f"0.1 mm, face {face}", strand(0.2, 0.45, "--resolution", 0.1, "--nozzle-tip-mm", face),
          {"gap_mm": 0.2, "width_mm": 0.45, "face_mm": face}) for face in (0.6, 1.0)],
        COUPLED_STRAND, folder="strands", tag="face"),
    "trade": Case(
        "the speed-accuracy ladder on the single bead (study bead): wall time against the "
        "section's largest deviation from the creeping-flow one (W, H, area)",
        [("study bead", ["study", "bead", "--out", "{out}"])],
        [("study bead --quick", ["study", "bead", "--quick", "--out", "{out}"])],
        [("run", lambda r: r.get("label", "")), ("status", lambda r: r.get("status", ""))]
        + COMMON + CG + [("M particle-steps/s", lambda r: f"{r['particle_steps_per_s'] / 1e6:.2f}"
                          if r.get("particle_steps_per_s") else ""),
                         ("viscosity x", num("viscosity_scale", "{:.3g}")),
                         ("section error vs creeping flow", pct("error"))] + BEAD + DENSITY[:2]
        + COUPLED_SOLVE + [("note", lambda r: (r.get("message") or "").split(". ")[0][:120])],
        read=read_study),
    "trade_step": Case(
        "the time step as a trade: strands at twice and three times the print's step "
        "(--dt-factor; the step bounds the nozzle's and the melt's travel to 0.2 spacings), "
        "one after the other",
        [(f"gap {g:.2f}, width {w:.2f}, {res}, dt x{f}",
          strand(g, w, "--resolution", res, "--dt-factor", f), {"gap_mm": g, "width_mm": w})
         for g, w, res, factors in ((0.2, 0.45, "standard", (1, 2, 3)), (0.2, 0.6, "standard", (1, 2)),
                                    (0.15, 0.5, 0.05, (1, 2)))
         for f in factors],
        [(f"0.1 mm, dt x{f}", strand(0.2, 0.45, "--resolution", 0.1, "--dt-factor", f),
          {"gap_mm": 0.2, "width_mm": 0.45}) for f in (1, 2)],
        COUPLED_STRAND, folder="trade", tag="step"),
    "stability": Case(
        "a 1.5 mm bead around the real-printer baseline (DFSPH, 1000 Pa s unscaled, 60 mm/s, "
        "0.2 mm layer, 8 particles per nozzle diameter): every case finishes or is refused up front",
        [("matrix", ["stability", "--out", "{out}"])],
        [("fast cases", ["stability", "--fast", "--out", "{out}"])],
        [("case", lambda r: r["case"]), ("result", lambda r: r["status"]),
         ("compression max / mean", lambda r: f"{100 * r['compression_error_max']:.2f} % / "
          f"{100 * r['compression_error_mean']:.3f} %" if "compression_error_max" in r else ""),
         ("deposited / commanded mm^3", lambda r: f"{r['deposited_mm3']:.4f} / {r['commanded_mm3']:.4f}"
          if "deposited_mm3" in r else ""),
         ("steps", num("steps")), ("step halvings", num("halvings")), ("wall s", num("wall_time_s")),
         ("note", lambda r: r.get("message", "").split(". ")[0][:140])],
        read=read_stability),
    "peer": Case(
        "PySPH's 3D dam break (dx = 0.02 m, 143k particles, EDAC), ours against PySPH 1.0b2 "
        "EDACScheme with OpenMP and on one core, 100 steps each, one after the other in one command",
        [("dam break", ["bench", "dam-break", "--json", "{out}/bench.json"])],
        [("dam break, dx 0.04, 10 steps", ["bench", "dam-break", "--dx", 0.04, "--steps", 10,
                                           "--json", "{out}/bench.json"])],
        [("code", lambda r: r["code"]), ("particles", num("particles")), ("steps", num("steps")),
         ("threads / OpenMP", lambda r: str(r.get("threads", "")) + (" OpenMP" if r.get("openmp") else "")),
         ("wall s", num("wall_s", "{:.1f}")), ("CPU s", num("cpu_s", "{:.1f}")),
         ("other processes' CPU s", num("others_cpu_s", "{:.1f}")),
         ("M particle-steps/s", lambda r: f"{r['particle_steps_per_s'] / 1e6:.3f}"),
         ("M particle-steps per CPU-s", lambda r: f"{r['particles'] * r['steps'] / r['cpu_s'] / 1e6:.3f}"),
         ("ours / PySPH", num("ratio", "{:.1f}x"))],
        read=read_bench),
    "peer_collapse": Case(
        "the viscous collapse (4 mm x 4 mm cylinder, 1 Pa s, 1000 kg/m^3, no-slip plate), ours "
        "against SPlisHSPlasH 2.19 (DFSPH, Weiler et al. 2018 viscosity, Akinci boundaries, same "
        "particles), time to solution and Huppert's coefficient, one after the other in one command",
        [("collapse", ["bench", "collapse", "--json", "{out}/bench.json"])],
        PEER_COLLAPSE_QUICK,
        PEER_COLLAPSE_COLUMNS, read=read_bench_collapse, folder="peer", tag="collapse"),
    "peer_collapse_02": Case(
        "the issue's collapse (0.2 mm, 3 s) side by side: ours (inner operator 'auto', the "
        "default) and SPlisHSPlasH 2.19 at its 1e-4 s step, one after the other in one command",
        [("collapse, 0.2 mm, 3 s", ["bench", "collapse", "--spacing-mm", 0.2, "--until", 3,
                                    "--json", "{out}/bench.json"])],
        PEER_COLLAPSE_QUICK,
        PEER_COLLAPSE_COLUMNS + [
            ("ours: GMRES / inner a step; solves on Weiler's / the form", inner_choice)],
        read=read_bench_collapse, folder="peer", tag="collapse_02"),
    "blocks_step": Case(
        "the paper's 3 x 3 block at draft at the print's step and at twice it (--dt-factor 2): "
        "to print time 0.9 s each, then the whole block at twice the step",
        [(f"paper block to 0.9 s, dt x{f}", bead(*BLOCK, "--resolution", "draft", "--until", 0.9,
                                                  "--dt-factor", f)) for f in (1, 2)]
        + [("paper block, dt x2", bead(*BLOCK, "--resolution", "draft", "--dt-factor", 2))],
        [("paper block to 0.3 s, 0.15 mm, dt x2", bead(*BLOCK, "--resolution", 0.15, "--until", 0.3,
                                                        "--dt-factor", 2))],
        BLOCKS + DENSITY[1:2], folder="blocks", tag="step"),
    "blocks": Case(
        "the seed paper's 3 x 3 block (paper_block_3x3.gcode: 0.4 mm layers, the nozzle one "
        "diameter up) and the same block at a printer's gaps (block_3x3.gcode: 0.2 mm layers), "
        "the whole print, a print's default solve (coupled)",
        [("paper block, draft, 1000 Pa s",
          bead(*BLOCK, "--resolution", "draft")),
         # x 0.2136: what the retired 'auto' scaling gave this block (until 2026-12-06)
         ("printer's block, draft, viscosity x 0.2136",
          bead(*REAL_BLOCK, "--resolution", "draft", "--viscosity-scale", 0.2136)),
         ("printer's block, draft, 1000 Pa s", bead(*REAL_BLOCK, "--resolution", "draft"))],
        [("paper block, 0.1 mm, print time to 0.6 s", bead(*BLOCK, "--resolution", 0.1, "--until", 0.6))],
        BLOCKS),
    "squeeze_film": Case(
        "a disc squeezing a PLA film (1000 Pa s) onto the plate at 1 mm/s, one coupled "
        "viscous-pressure solve: force against Stefan's 3 pi mu V R^4 / (2 h^3), centre pressure "
        "against 3 mu V R^2 / h^3",
        [(f"R {r} mm, h {h} mm ({round(h / 0.05)} layers){', ' + str(mu) + ' Pa s' if mu != 1000 else ''}",
          scene("squeeze-film", "--radius-mm", r, "--gap-mm", h, "--spacing-mm", 0.05,
                "--viscosity", mu))
         for r, h, mu in ((0.5, 0.2, 1000), (0.5, 0.2, 12.7), (1.0, 0.2, 1000), (2.0, 0.2, 1000),
                          (1.5, 0.3, 1000), (2.0, 0.4, 1000))]
        + [(f"pair sum, {ghost}: R {r} mm, h {h} mm ({round(h / 0.05)} layers)",
            scene("squeeze-film", "--radius-mm", r, "--gap-mm", h, "--spacing-mm", 0.05,
                  "--no-surface-traction", "--wall-ghost", ghost))
           for r, h in ((1.0, 0.2), (2.0, 0.2), (1.5, 0.3)) for ghost in ("quadratic", "adami")],
        [("R 0.5 mm, h 0.2 mm", scene("squeeze-film", "--radius-mm", 0.5, "--gap-mm", 0.2))],
        [("particles", num("particles_active")),
         ("R / h", lambda r: f"{r['radius_m'] / r['gap_m']:.1f}" if r.get("gap_m") else ""),
         ("force / Stefan", num("force_ratio", "{:.3f}")),
         ("centre pressure / lubrication", num("centre_pressure_ratio", "{:.3f}")),
         ("GMRES iterations", num("stokes_iterations")),
         ("converged", lambda r: str(r.get("stokes_converged", "")))]),
    "couette": Case(
        "a lid sliding at 60 mm/s over a PLA film (1000 Pa s) on the plate, with and without a "
        "pressure gradient along the slide, one coupled solve: the film's middle, layer by layer, "
        "against plane Couette-Poiseuille flow, under the scenes' strain-energy form (Adami's "
        "mirror at the walls) and a print's pair sum (the quadratic ghost, and the mirror)",
        [(label, scene("couette", *args)) for label, args in (
            ("form: Couette, 4 layers", ()),
            ("form: Couette, 4 layers, 12.7 Pa s", ("--viscosity", 12.7)),
            ("form: Couette + Poiseuille, 4 layers", ("--gradient-pa-mm", 6e6)),
            ("form: Couette + Poiseuille, 6 layers", ("--gradient-pa-mm", 6e6 * 4 / 9,
                                                      "--gap-mm", 0.3, "--radius-mm", 1.5)),
            ("form: Couette + Poiseuille, 8 layers", ("--gradient-pa-mm", 1.5e6, "--gap-mm", 0.4,
                                                      "--radius-mm", 2.0)),
            ("form: Poiseuille alone, 4 layers", ("--gradient-pa-mm", 6e6, "--speed-mm-s", 0)),
            ("pair sum, quadratic: Couette, 4 layers", ("--no-surface-traction", "--wall-ghost", "quadratic")),
            ("pair sum, quadratic: Poiseuille alone, 4 layers", ("--no-surface-traction", "--wall-ghost", "quadratic",
                                                                  "--gradient-pa-mm", 6e6,
                                                                  "--speed-mm-s", 0)),
            ("pair sum, mirror: Poiseuille alone, 4 layers", ("--no-surface-traction",
                                                               "--wall-ghost", "adami",
                                                               "--gradient-pa-mm", 6e6,
                                                               "--speed-mm-s", 0)),
            ("pair sum, quadratic: Couette + Poiseuille, 4 layers", ("--no-surface-traction", "--wall-ghost", "quadratic",
                                                                      "--gradient-pa-mm", 6e6)),
            ("pair sum, quadratic: Couette + Poiseuille, 6 layers", (
                "--no-surface-traction", "--wall-ghost", "quadratic", "--gradient-pa-mm", 6e6 * 4 / 9, "--gap-mm", 0.3,
                "--radius-mm", 1.5)),
            ("pair sum, mirror: lid lifted 0.1 spacing", ("--no-surface-traction",
                                                           "--lid-lift-spacings", 0.1)),
            ("pair sum, mirror: lid lifted 0.2 spacing", ("--no-surface-traction",
                                                           "--lid-lift-spacings", 0.2)),
            ("pair sum, mirror: lid lifted 0.4 spacing", ("--no-surface-traction",
                                                           "--lid-lift-spacings", 0.4)))],
        [("form: Couette, 4 layers", scene("couette"))],
        [("particles", num("particles_active")),
         ("layers", lambda r: f"{r['gap_m'] / (r['spacing_mm'] * 1e-3):.0f}" if r.get("gap_m") else ""),
         ("Poiseuille u_max / V", lambda r: f"{r['poiseuille_u_max_m_s'] / r['speed_m_s']:.2f}"
          if r.get("speed_m_s") else "alone"),
         ("profile error max / (V + u_max)", num("profile_error_max", "{:.4f}")),
         ("parabola / Poiseuille's", num("poiseuille_ratio", "{:.3f}")),
         ("slip plate / lid (spacings)", lambda r: (
             f"{r['slip_plate_m'] / (r['spacing_mm'] * 1e-3):+.2f} / "
             + (f"{r['slip_lid_m'] / (r['spacing_mm'] * 1e-3):+.2f}" if r.get("slip_lid_m") == r.get("slip_lid_m")
                and r.get("slip_lid_m") is not None else "-")) if r.get("slip_plate_m") is not None else ""),
         ("cross flow max / (V + u_max)", num("cross_flow_max", "{:.4f}")),
         ("GMRES iterations", num("stokes_iterations")),
         ("converged", lambda r: str(r.get("stokes_converged", "")))]),
    "bore_flow": Case(
        "PLA (1000 Pa s) falling under gravity through the 0.4 mm nozzle bore, ends open, one "
        "coupled solve: axial velocity of the middle third against Hagen-Poiseuille",
        [(f"{dx} mm ({0.2 / dx:.0f} per radius)", scene("bore-flow", "--spacing-mm", dx))
         for dx in (0.05, 0.033, 0.025)]
        + [(f"{dx} mm, the pair sum (prints)", scene("bore-flow", "--spacing-mm", dx,
                                                       "--no-surface-traction"))
           for dx in (0.05, 0.033, 0.025)]
        + [("0.05 mm, block_diagonal", scene("bore-flow", "--spacing-mm", 0.05,
                                             "--stokes-preconditioner", "block_diagonal"))],
        [("0.05 mm", scene("bore-flow", "--spacing-mm", 0.05))],
        [("particles", num("particles_active")),
         ("centre u / Poiseuille", num("centre_ratio", "{:.3f}")),
         ("max error / u_max", pct("profile_error_max")),
         ("rms error / u_max", pct("profile_error_rms")),
         ("GMRES iterations", num("stokes_iterations")),
         ("inner CG iterations", num("stokes_inner_iterations")),
         ("solve s (with compile)", num("solve_wall_s", "{:.0f}")),
         ("converged", lambda r: str(r.get("stokes_converged", "")))]),
    "extension": Case(
        "a PLA filament (1000 Pa s, R0 = 0.5 mm) whose end pieces carry the uniaxial field "
        "e (x, -y/2, -z/2), e = 1/s, to a Hencky strain of 0.5, coupled solve: mid radius "
        "against R0 exp(-e t / 2), pressure against -mu e",
        [(f"{dx} mm ({0.5 / dx:.0f} per radius), source {source}",
          scene("extension", "--spacing-mm", dx, "--density-source", source))
         for dx, source in ((0.125, "none"), (0.1, "none"), (0.125, "summation"),
                            (0.125, "two-way"))]
        + [(f"0.125 mm (4 per radius), source none, the pair sum, surface rows {rows}",
            scene("extension", "--spacing-mm", 0.125, "--density-source", "none",
                  "--no-surface-traction", "--surface-rows", rows))
           for rows in ("continuity", "traction")],
        [("0.125 mm, strain 0.1", scene("extension", "--spacing-mm", 0.125, "--strain", 0.1))],
        COMMON + [(f"mid R / exact at strain {e}", strain_ratio(e)) for e in (0.1, 0.2, 0.3, 0.4, 0.5)]
        + [("mid pressure / (-mu e), first sample", lambda r: f"{r['mid_pressure_pa'][1] / (-r['viscosity_pa_s'] * r['strain_rate_1_s']):.2f}"
            if len(r.get("mid_pressure_pa", [])) > 1 else ""),
           ("GMRES per step", num("stokes_iterations_per_step")),
           ("particles lost", num("particles_lost"))]),
    "die_swell": Case(
        "PLA (1000 Pa s) pushed out of the 0.4 mm nozzle bore into free space, no gravity: the "
        "free surface iterated to the streamline from the die's lip (one coupled solve per "
        "geometry), its swell against Nickell, Tanner & Caswell's 1.13",
        [(f"{label}, {dx} mm ({0.2 / dx:.0f} per radius)",
          scene("die-swell", "--spacing-mm", dx, *args))
         for label, dx, args in (
             ("traction", 0.05, ["--surface-traction"]),
             ("traction", 0.0333, ["--surface-traction"]),
             ("traction", 0.025, ["--surface-traction"]),
             ("the pair sum (prints)", 0.05, []),
             ("the pair sum (prints)", 0.0333, []),
             ("the pair sum, traction-free surface rows", 0.05, ["--surface-rows", "traction"]),
             ("the pair sum, traction-free surface rows", 0.0333, ["--surface-rows", "traction"]),
             ("Weiler's sum alone", 0.05, ["--viscous-isotropic-share", 0]),
             ("Morris", 0.05, ["--viscous-isotropic-share", 1]),
             ("even blend", 0.05, ["--viscous-isotropic-share", 0.5]))],
        [("traction, 0.05 mm", scene("die-swell", "--surface-traction"))],
        [("swell: streamline / lattice / continuity", lambda r: (
             f"{r['swell']:.3f} / {r['swell_lattice']:.3f} / {r['swell_kinematic']:.3f}")
          if r.get("swell") is not None else ""),
         ("streamline swell / 1.13", lambda r: f"{r['swell_error']:+.1%}"
          if r.get("swell_error") is not None else ""),
         ("streamline swell by iteration", lambda r: ", ".join(
             f"{x:.3f}" for x in r.get("swell_history") or [])),
         ("surface: geometries in its cycle (the swell's spread over it)", lambda r: (
             f"{r['surface_cycle']} ({r['swell_spread']:.3f})" if r["surface_converged"]
             else f"none in {r['geometry_iterations']} solves (spread "
                  f"{r['swell_spread']:.3f})") if r.get("surface_cycle") is not None else ""),
         ("jet particles by geometry", lambda r: ", ".join(
             f"{k:,}" for k in r.get("jet_particles_each") or [])),
         ("GMRES per solve", lambda r: ", ".join(str(k) for k in r.get("stokes_iterations_each") or [])),
         ("converged", lambda r: str(r.get("stokes_converged", "")))]),
    "mesostructure": Case(
        "pairing and voids in the single bead's section (standard spacing, whole bead)",
        [(f"standard, {v}", bead("--resolution", "standard", "--viscosity-scale", v))
         for v in ("off", "0.0127")],
        [("0.1 mm, off", bead("--resolution", 0.1, "--viscosity-scale", "off"))],
        COMMON + [("viscosity x", num("viscosity_scale", "{:.3g}"))] + DENSITY
        + [("section W / H mm", lambda r: f"{r.get('bead_width_mm') or float('nan'):.3f} / "
            f"{r.get('bead_height_mm') or float('nan'):.3f}"), BEAD[0]]),
}


# ----------------------------------------------------------------------------- references
def _hydrostatic():
    rho, g = 1000.0, 9.81
    return ("# p = rho g depth, rho = 1000 kg/m^3, g = 9.81 m/s^2, 12 mm column\ndepth_mm,p_pa",
            [(d, rho * g * d * 1e-3) for d in [0.5 * k for k in range(25)]])


def _shear():
    nu, t, U = 0.1 / 1000.0, 0.01, 0.01
    return (f"# Stokes' first problem: u = U erfc(z / (2 sqrt(nu t))), nu = {nu:g} m^2/s, "
            f"t = {t:g} s, U = {U:g} m/s\nz_mm,u_over_U",
            [(z, math.erfc(z * 1e-3 / (2.0 * math.sqrt(nu * t)))) for z in [0.05 * k for k in range(61)]])


def _collapse():
    eta_n = (2**10 / (3**4 * math.pi**3)) ** 0.125  # Huppert (1982), axisymmetric
    g, nu, vol = 9.81, 10.0 / 1000.0, math.pi * 4e-3**2 * 4e-3
    coeff = eta_n * (g * vol**3 / (3.0 * nu)) ** 0.125
    return (f"# Huppert, J. Fluid Mech. 121 (1982): r = eta_N (g V^3 / (3 nu))^(1/8) t^(1/8), "
            f"eta_N = {eta_n:.4f}, V = pi (4 mm)^2 4 mm, nu = 0.01 m^2/s: coefficient "
            f"{coeff * 1e3:.4f} mm s^-1/8\nt_s,r_mm",
            [(t, coeff * t**0.125 * 1e3) for t in [0.5 * 1.2**k for k in range(23)]])


def _thermal_beam():
    A, z0, B, L = 2500.0, 0.05, 150.0, 0.2
    alpha, t = 237.0 / (2700.0 * 897.0), 50.0

    def series(z):
        T = B + A * ((L - z0) ** 3 + z0**3) / (3.0 * L)
        for n in range(1, 401):
            k = n * math.pi / L
            T += 4.0 * A / (L * k * k) * ((L - z0) * (-1) ** n + z0) * math.cos(k * z) * math.exp(-alpha * k * k * t)
        return T
    return ("# (a) insulated aluminium beam (k 237 W/mK, rho 2700 kg/m^3, c 897 J/kgK), "
            "T(z, 0) = 2500 (z - 0.05)^2 + 150 degC, cosine series at t = 50 s\nz_m,T_C",
            [(z, series(z)) for z in [0.005 * k for k in range(41)]])


def _strands():
    rows = []
    for gap in (0.1, 0.15, 0.2, 0.25, 0.3, 0.4):
        rows.append((gap, BEAD_AREA_MM2, slicer_width_mm(BEAD_AREA_MM2, gap)))
    return ("# slicer's rounded rectangle (Comminal et al., Addit. Manuf. 20, 2018): W = A/g + (1 - pi/4) g;"
            f" A = {BEAD_AREA_MM2:.5f} mm^2 (the bundled single bead: 0.45 mm x 0.2 mm)\n"
            "gap_mm,area_mm2,width_mm", rows)


REFERENCES = {"hydrostatic": _hydrostatic, "shear": _shear, "collapse": _collapse,
              "thermal_beam": _thermal_beam, "strands": _strands}


def write_reference(name: str) -> Path | None:
    if name not in REFERENCES:
        return None
    header, rows = REFERENCES[name]()
    path = HERE / name / "reference.csv"
    path.write_text(header + "\n" + "\n".join(",".join(f"{v:.6g}" for v in r) for r in rows) + "\n")
    return path


# ----------------------------------------------------------------------------- running
def taichi_command(args: list[str]) -> list[str]:
    """``python -m taichi_mex ARGS``."""
    return [sys.executable, "-m", "taichi_mex", *args]


def shown(cmd: list[str]) -> str:
    return shlex.join(["python", *cmd[1:]])


#: what --lean keeps of a run's folder: its figures and its log
LEAN_KEEP = {"summary.json", "bench.json", "config.json", "log.txt"}


def run_case(name: str, case: Case, out_root: Path, quick: bool,
             lean: bool = False) -> tuple[list[dict], list[str]]:
    rows, commands = [], []
    for k, (label, args, *params) in enumerate(case.quick if quick else case.runs):
        out = out_root / f"{k:02d}"
        out.mkdir(parents=True, exist_ok=True)
        cmd = taichi_command([str(a).replace("{out}", str(out)) for a in args])
        commands.append(shown([str(a).replace(str(out_root), "OUT") for a in cmd]))
        print(f"[{name} {k + 1}/{len(case.quick if quick else case.runs)}] {commands[-1]}", flush=True)
        t0 = time.perf_counter()
        try:
            proc = subprocess.run(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                  timeout=case.timeout_s)
        except subprocess.TimeoutExpired as exc:
            log = exc.stdout.decode(errors="replace") if isinstance(exc.stdout, bytes) else (exc.stdout or "")
            proc = subprocess.CompletedProcess(cmd, f"stopped after {case.timeout_s:.0f} s", log)
        (out / "log.txt").write_text(proc.stdout)
        try:
            got = case.read(out)
        except (OSError, ValueError, KeyError) as exc:
            got = [{"failure": f"exit {proc.returncode}: {_last_error(proc.stdout) or exc}"}]
        for r in got:
            r.setdefault("label", label)
            for key, value in (params[0] if params else {}).items():
                r.setdefault(key, value)
            r.setdefault("wall_time_s", time.perf_counter() - t0)
            if isinstance(r.get("error"), str):  # a run that stopped (blow-up, refusal)
                r["stopped"] = r["error"].split(". ")[0]
        rows += got
        if lean:  # frames, checkpoints, sections: the table needs none of them
            for f in out.iterdir():
                if f.name not in LEAN_KEEP:
                    shutil.rmtree(f) if f.is_dir() else f.unlink()
        print(f"    exit {proc.returncode}, {time.perf_counter() - t0:.0f} s", flush=True)
    return rows, commands


def keep_figures(case: Case, out_root: Path) -> None:
    """Copy the case's pictures from its run folders to where the pages show them."""
    for index, pattern, dest in case.figures:
        found = sorted((out_root / f"{index:02d}").glob(pattern))
        if not found:
            print(f"    no {pattern} in run {index + 1}: {dest} left as it was", flush=True)
            continue
        target = ROOT / dest
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(found[-1], target)
        print(f"    kept {found[-1].relative_to(out_root)} as {dest}", flush=True)


def _last_error(log: str) -> str:
    """The last line of a log that reads like an error ('error: ...', 'ValueError: ...')."""
    lines = [ln.strip() for ln in log.strip().splitlines() if ln.strip()]
    hits = [ln for ln in lines if ln.lower().startswith("error") or ln.split(":")[0].endswith(("Error", "Exception"))]
    return (hits or lines or [""])[-1][:200]


def code_version() -> str:
    """The git commit of the code that ran, marked when the work tree differs from it."""
    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                             text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "taichi_mex"], cwd=ROOT,
                               capture_output=True, text=True).stdout.strip()
        return f"code `{rev}`" + (" with uncommitted changes" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "code version unknown"


def markdown(case: Case, rows: list[dict]) -> str:
    heads = [h for h, _ in case.columns]
    if case.read is read_summary:
        heads = ["run", *heads]
    lines = ["| " + " | ".join(heads) + " |", "|" + "---|" * len(heads)]
    for r in rows:
        if "failure" in r:
            lines.append(f"| {r['label']} | failed: {r['failure']} |" + " |" * (len(heads) - 2))
            continue
        cells = [fn(r) for _, fn in case.columns]
        if case.read is read_summary:
            cells = [r["label"] + (" **(stopped)**" if "stopped" in r else ""), *cells]
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    stopped = [f"* {r['label']}: {r['stopped']}" for r in rows if "stopped" in r]
    return "\n".join(lines + (["", "Stopped runs (their figures are at the time they stopped):", *stopped]
                              if stopped else []))


def machine() -> str:
    gpu = ""
    try:  # the GPU a case ran on, where there is one
        names = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"],
                               capture_output=True, text=True, timeout=30).stdout.strip()
        gpu = f", GPU {names.splitlines()[0]}" if names else ""
    except (OSError, subprocess.SubprocessError):
        pass
    return f"{platform.platform()}, {platform.processor() or platform.machine()}, {os.cpu_count()} cores{gpu}"


def rewrite(name: str, block: str, tag: str = "") -> Path:
    path = HERE / name / "README.md"
    text = path.read_text()
    begin, end = (BEGIN, END) if not tag else (BEGIN.replace(" -->", f":{tag} -->"), END.replace(" -->", f":{tag} -->"))
    if begin not in text or end not in text:
        raise SystemExit(f"{path} has no {begin} ... {end} markers")
    head, rest = text.split(begin, 1)
    _, tail = rest.split(end, 1)
    path.write_text(f"{head}{begin}\n{block}\n{end}{tail}")
    return path


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("case", nargs="?", choices=sorted(CASES))
    p.add_argument("--list", action="store_true", help="list the cases and exit")
    p.add_argument("--quick", action="store_true", help="coarse, short runs (checks the machinery)")
    p.add_argument("--out", type=Path, default=None, help="keep the runs here (default: a temporary folder)")
    p.add_argument("--commands", action="store_true", help="print the commands and exit")
    p.add_argument("--lean", action="store_true",
                   help="keep only each run's summary, config and log in --out (a lent machine "
                        "returns few files)")
    p.add_argument("--references", action="store_true",
                   help="(re)write every case's reference.csv from its formula and exit")
    args = p.parse_args(argv)
    if args.references:
        for name in REFERENCES:
            print(f"wrote {write_reference(name)}")
        return 0
    if args.list or not args.case:
        for name, case in CASES.items():
            print(f"{name:14s} {len(case.runs)} command(s), quick {len(case.quick)}: {case.what}")
        return 0
    case = CASES[args.case]
    if args.commands:
        for run in case.quick if args.quick else case.runs:
            print(shown(taichi_command([str(x).replace("{out}", "OUT") for x in run[1]])))
        return 0
    with tempfile.TemporaryDirectory(prefix=f"validation-{args.case}-") as tmp:
        out_root = (args.out or Path(tmp)).resolve()
        t0 = time.perf_counter()
        rows, commands = run_case(args.case, case, out_root, args.quick, args.lean)
        if not (args.quick or args.lean):
            keep_figures(case, out_root)
        if case.finish:
            rows = case.finish(rows)
        wall = time.perf_counter() - t0
    stamp = (f"Regenerated {datetime.date.today().isoformat()} ({code_version()}) on {machine()}, "
             f"Python {platform.python_version()}, {wall / 60:.1f} min in all"
             + (", **`--quick` settings: a check of the machinery, not the validation figures**"
                if args.quick else "")
             + f" (`python validation/regenerate.py {args.case}{' --quick' if args.quick else ''}`). "
             "Commands, run one after the other (OUT: the output folder):")
    block = "\n".join([stamp, "", "```bash", *commands, "```", "", markdown(case, rows)])
    print(block)
    if all("failure" in r for r in rows):  # keep the last good table
        print(f"every command failed; validation/{case.folder or args.case}/README.md left as it was "
              f"(logs: log.txt in each run folder{'' if args.out else ', pass --out DIR to keep them'})")
        return 1
    print(f"wrote {rewrite(case.folder or args.case, block, case.tag)}")
    return 0 if all("failure" not in r for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
