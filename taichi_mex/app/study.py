"""The speed-accuracy trade, measured: ``python -m taichi_mex study SCENE --out DIR``.

A study runs a ladder of settings (particle spacing, solver, precision, creeping-flow
scaling, surface-area method) on one reference scene, each run in its own process, and
writes ``DIR/trade.csv`` (one row per run: settings, particles, steps, wall time,
particle-steps/s, errors) and ``DIR/trade.png`` (error against wall time). Errors are taken
against an analytic result: the shear profile, the hydrostatic pressure, the beam's
temperature, and for the bead the creeping-flow section of its line (the slicer's rounded
rectangle at the gap, with the commanded area).
"""

import csv
import json
import math
import time
from pathlib import Path

from taichi_mex.app.parsing import Parser
from taichi_mex.errors import UserInputError
from taichi_mex.post.output import read_json

#: each ladder: (label, parameters for jobs.run_job_isolated); the first entry of a study is
#: its reference when the scene has no analytic answer
LADDERS = {
    "bead": {
        # the coupled creeping solve, a print's default, over spacing, precision, the
        # creeping-flow scaling and the time step; two rungs of the split solve (a print's
        # default until 2026-12-03) and the seed paper's EDAC for comparison
        "base": {"gcode": "single_bead", "deposit_for_s": 0.13, "snapshots": False,
                 "run.dfsph.creeping_solve": "coupled", "run.dfsph.stokes_surface_traction": False},
        # single_bead.gcode's line: the creeping-flow section the errors are measured against
        "section": {"gap_mm": 0.2, "width_mm": 0.45},
        "runs": [
            ("coupled dx=0.1", {"spacing_mm": 0.1}),
            ("coupled dx=0.067 (draft)", {"spacing_mm": 0.0667}),
            ("coupled dx=0.067 (draft), dt x2", {"spacing_mm": 0.0667, "dt_factor": 2.0}),
            ("coupled dx=0.05 (standard)", {"spacing_mm": 0.05}),
            ("coupled dx=0.05 f64", {"spacing_mm": 0.05, "precision": "f64"}),
            ("coupled dx=0.05 viscosity x 0.0127", {"spacing_mm": 0.05, "viscosity_scale": 0.0127}),
            ("coupled dx=0.033 (fine)", {"spacing_mm": 0.0333}),
            ("edac paper dx=0.1", {"spacing_mm": 0.1, "preset": "paper", "gcode": "single_bead"}),
        ],
        "quick": [
            ("coupled dx=0.1", {"spacing_mm": 0.1, "deposit_for_s": 0.02}),
            ("coupled dx=0.067 (draft)", {"spacing_mm": 0.0667, "deposit_for_s": 0.02}),
        ],
    },
    "shear": {
        "base": {"scene": "shear", "snapshots": False},
        "runs": [
            ("dfsph dx=0.4", {"spacing_mm": 0.4}),
            ("dfsph dx=0.3", {"spacing_mm": 0.3}),
            ("dfsph dx=0.2", {"spacing_mm": 0.2}),
            ("dfsph dx=0.2 f64", {"spacing_mm": 0.2, "precision": "f64"}),
            ("dfsph dx=0.15", {"spacing_mm": 0.15}),
        ],
        "quick": [("dfsph dx=0.5", {"spacing_mm": 0.5, "scene.until": 0.004}),
                  ("dfsph dx=0.4", {"spacing_mm": 0.4, "scene.until": 0.004})],
    },
    "hydrostatic": {
        "base": {"scene": "hydrostatic", "snapshots": False},
        "runs": [
            ("edac dx=1", {"scheme": "edac", "spacing_mm": 1.0}),
            ("edac dx=0.67", {"scheme": "edac", "spacing_mm": 0.667}),
            ("dfsph dx=1", {"scheme": "dfsph", "spacing_mm": 1.0}),
            ("dfsph dx=0.67", {"scheme": "dfsph", "spacing_mm": 0.667}),
            ("dfsph dx=0.5", {"scheme": "dfsph", "spacing_mm": 0.5}),
        ],
        "quick": [("dfsph dx=1.5", {"scheme": "dfsph", "spacing_mm": 1.5, "scene.until": 0.05}),
                  ("edac dx=1.5", {"scheme": "edac", "spacing_mm": 1.5, "scene.until": 0.05})],
    },
    "thermal-beam": {
        "base": {"scene": "thermal-beam", "snapshots": False},
        "runs": [
            ("eigenvalue dx=4", {"spacing_mm": 4.0, "run.thermal.surface_method": "eigenvalue"}),
            ("colour_gradient dx=4", {"spacing_mm": 4.0, "run.thermal.surface_method": "colour_gradient"}),
            ("eigenvalue dx=2", {"spacing_mm": 2.0, "run.thermal.surface_method": "eigenvalue"}),
            ("colour_gradient dx=2", {"spacing_mm": 2.0, "run.thermal.surface_method": "colour_gradient"}),
            ("colour_gradient dx=2 f64", {"spacing_mm": 2.0, "precision": "f64",
                                         "run.thermal.surface_method": "colour_gradient"}),
        ],
        "quick": [("colour_gradient dx=5", {"spacing_mm": 5.0, "scene.until": 5.0})],
    },
}

#: the error a scene's runs are compared by, and where to find it (summary.json keys)
ERRORS = {
    "bead": ("bead_shape_error", None),
    "shear": ("shear_error_max_rel_U", "shear_error_max_rel_U"),
    "hydrostatic": ("pressure_error_rel_mean", "pressure_error_rel_mean"),
    "thermal-beam": ("thermal_error_max_c", "thermal_error_max_c"),
}

COLUMNS = ["scene", "label", "scheme", "spacing_mm", "precision", "viscosity_scale", "status",
           "particles", "steps", "wall_time_s", "simulated_time_s", "particle_steps_per_s",
           "wall_per_simulated_s", "error", "error_kind", "bead_width_mm", "bead_height_mm",
           "bead_area_mm2", "bead_material_area_mm2", "bead_top_median_mm", "density_error_mean", "compression_error_max", "message"]


def run_study(scene: str, out_dir: Path, quick: bool = False, timeout_s: float = 3600.0,
              only: list[str] | None = None, arch: str = "cpu") -> list[dict]:
    from taichi_mex.app.jobs import run_job_isolated

    if scene not in LADDERS:
        raise UserInputError(f"No study for '{scene}'; choose {', '.join(LADDERS)}.")
    spec = LADDERS[scene]
    ladder = spec["quick"] if quick else spec["runs"]
    if only:
        ladder = [r for r in ladder if any(o in r[0] for o in only)]
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    for k, (label, params) in enumerate(ladder):
        run_dir = out_dir / f"run{k:02d}"
        merged = {**spec["base"], **params, "cpu_threads": params.get("cpu_threads", None)}
        merged = {key: v for key, v in merged.items() if v is not None}
        if arch != "cpu":
            merged["arch"] = arch
        print(f"[{k + 1}/{len(ladder)}] {label} ...", flush=True)
        t0 = time.perf_counter()
        record = run_job_isolated(merged, run_dir, timeout_s=timeout_s)
        summary = read_json(run_dir / "summary.json") or {}
        row = _row(scene, label, merged, record, summary, time.perf_counter() - t0)
        rows.append(row)
        print(f"    {row['status']}: {row['wall_time_s']:.1f} s, {row.get('particles') or 0:,} particles"
              + (f", error {row['error']:.4g}" if isinstance(row.get("error"), float) else ""), flush=True)
    _bead_errors(scene, rows)
    write_trade(rows, out_dir)
    return rows


def _row(scene, label, params, record, summary, wall) -> dict:
    kind, key = ERRORS[scene]
    err = summary.get(key) if key else None
    scale = summary.get("viscosity_scale")
    sim_wall = summary.get("wall_time_s") or wall
    return {
        "scene": scene, "label": label, "scheme": summary.get("scheme", params.get("scheme", "dfsph")),
        "spacing_mm": summary.get("spacing_mm", params.get("spacing_mm")),
        "precision": summary.get("precision", params.get("precision", "f32")),
        "viscosity_scale": scale, "status": record.get("status", "failed"),
        "particles": summary.get("particles_active"), "steps": summary.get("steps"),
        "wall_time_s": sim_wall, "simulated_time_s": summary.get("simulated_time_s"),
        "particle_steps_per_s": summary.get("particle_steps_per_s"),
        "wall_per_simulated_s": summary.get("wall_time_per_simulated_s"),
        "error": err, "error_kind": kind,
        "bead_width_mm": summary.get("bead_width_mm"), "bead_height_mm": summary.get("bead_height_mm"),
        "bead_area_mm2": summary.get("bead_area_mm2"),
        "bead_material_area_mm2": summary.get("bead_material_area_mm2"),
        "bead_top_median_mm": summary.get("bead_top_median_mm"),
        "density_error_mean": summary.get("density_error_mean"),
        "compression_error_max": summary.get("compression_error_max"),
        "message": (record.get("error") or "")[:300],
    }


def _bead_errors(scene: str, rows: list[dict]) -> None:
    """Bead shape error: the largest relative deviation of the section's width, height and
    material area from the creeping-flow section of the line (issue 15): under a flat nozzle
    face at the gap g a strand of area A leaves with a flat top at g and rounded sides, close
    to the slicer's rounded rectangle, W = A / g + (1 - pi / 4) g (Comminal et al., Addit.
    Manuf. 20, 2018; Serdeczny et al. 2018). A physical answer, not the finest run's, so a
    ladder converging to a wrong shape shows its error."""
    if scene != "bead":
        return
    sec = LADDERS["bead"]["section"]
    g, w = sec["gap_mm"], sec["width_mm"]
    area = (w - g) * g + math.pi * g * g / 4.0
    ref = {"bead_width_mm": area / g + (1.0 - math.pi / 4.0) * g, "bead_height_mm": g,
           "bead_material_area_mm2": area}
    for r in rows:
        if r["status"] != "done" or not r.get("bead_width_mm"):
            continue
        devs = [abs(r[k] / v - 1.0) for k, v in ref.items() if r.get(k)]
        r["error"] = max(devs) if devs else None
        r["error_kind"] = (f"bead section vs the creeping-flow one (W {ref['bead_width_mm']:.3f}, "
                           f"H {g:g}, area {area:.4f} mm^2)")


def write_trade(rows: list[dict], out_dir: Path) -> None:
    with (out_dir / "trade.csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=COLUMNS, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in COLUMNS})
    (out_dir / "trade.json").write_text(json.dumps(rows, indent=2, default=str))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for r in rows:
        if r["status"] == "done" and isinstance(r.get("error"), (int, float)) and r["error"] > 0:
            ax.plot(r["wall_time_s"], r["error"], "o")
            ax.annotate(r["label"], (r["wall_time_s"], r["error"]), fontsize=7,
                        xytext=(4, 3), textcoords="offset points")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("wall time [s] (2-core CPU unless noted)")
    kinds = {r["error_kind"] for r in rows if r.get("error_kind")}
    ax.set_ylabel("error: " + "; ".join(sorted(kinds))[:80])
    ax.set_title(f"speed-accuracy trade: {rows[0]['scene'] if rows else ''}")
    fig.tight_layout()
    fig.savefig(out_dir / "trade.png", dpi=120)
    plt.close(fig)


def main(argv: list[str]) -> int:
    p = Parser(prog="python -m taichi_mex study",
                description="Run a ladder of settings on a reference scene and write trade.csv")
    p.add_argument("scene", choices=sorted(LADDERS))
    p.add_argument("--out", type=Path, default=Path("study_out"))
    p.add_argument("--quick", action="store_true", help="a two-run ladder (seconds, for checks)")
    p.add_argument("--only", nargs="*", default=None, help="run only ladder labels containing these")
    p.add_argument("--timeout", type=float, default=3600.0, help="per-run limit (s)")
    p.add_argument("--arch", choices=["cpu", "gpu"], default="cpu", help="cpu (default) or gpu")
    args = p.parse_args(argv)
    rows = run_study(args.scene, args.out, args.quick, args.timeout, args.only, args.arch)
    print(f"{sum(r['status'] == 'done' for r in rows)} of {len(rows)} runs done; "
          f"{args.out / 'trade.csv'}, {args.out / 'trade.png'}")
    return 0 if rows and all(r["status"] == "done" for r in rows) else 1


if __name__ == "__main__":  # pragma: no cover
    import sys

    sys.exit(main(sys.argv[1:]))
