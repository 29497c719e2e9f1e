"""Stability at the extremes: a matrix of single-bead cases around a real-printer baseline.

Each case changes one or two settings from the baseline (DFSPH, unscaled 1000 Pa s melt,
60 mm/s, 0.2 mm layer under a 0.4 mm nozzle, 8 particles per nozzle diameter, f32, the
stable time step) towards an extreme, prints a short bead, and must either finish with
finite values, bounded compression and the commanded mass deposited, or be refused before
it starts with a message that says what to change. ``python -m taichi_mex stability`` runs
the whole matrix and prints the table that README.md shows; the tests run the fast cases.
"""

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

from taichi_mex.errors import SimulationDiverged, UserInputError

BASE = {"viscosity_pa_s": 1000.0, "speed_mm_s": 60.0, "layer_height_mm": 0.2,
        "spacing_mm": 0.05, "precision": "f32", "dt_factor": 1.0, "scheme": "dfsph"}

#: compression (rho/rho0 - 1 over the melt) a finished case may show at most
MAX_COMPRESSION = 0.05


@dataclass
class Case:
    name: str
    changes: dict
    slow: bool = False
    params: dict = field(init=False)

    def __post_init__(self):
        self.params = {**BASE, **self.changes}


# slow: not in the default test run, which keeps the extremes of viscosity, speed and step
# and the refusals (python -m pytest -m slow runs the rest)
CASES = [
    Case("baseline", {}, slow=True),
    Case("viscosity 0.1 Pa s", {"viscosity_pa_s": 0.1}),
    Case("viscosity 1e4 Pa s", {"viscosity_pa_s": 1e4}),
    Case("speed 10 mm/s", {"speed_mm_s": 10.0}, slow=True),
    Case("speed 200 mm/s", {"speed_mm_s": 200.0}),
    Case("layer 0.25 D", {"layer_height_mm": 0.1}, slow=True),
    Case("layer 1.0 D", {"layer_height_mm": 0.4}, slow=True),
    Case("4 particles per D", {"spacing_mm": 0.1}, slow=True),
    Case("4 per D, layer 0.25 D", {"spacing_mm": 0.1, "layer_height_mm": 0.1}),
    Case("16 particles per D", {"spacing_mm": 0.025}, slow=True),
    Case("f64", {"precision": "f64"}, slow=True),
    Case("dt factor 2", {"dt_factor": 2.0}, slow=True),
    Case("dt factor 4", {"dt_factor": 4.0}),
    Case("viscosity 1e4, 200 mm/s, f64", {"viscosity_pa_s": 1e4, "speed_mm_s": 200.0,
                                          "precision": "f64"}, slow=True),
    Case("EDAC at 1000 Pa s", {"scheme": "edac"}),
]


def run_case(case: Case, out_dir: Path, bead_length_mm: float = 1.5, arch: str = "cpu") -> dict:
    """Run one case in this process; returns a row for the table (never raises)."""
    from taichi_mex.sim.simulation import Simulation
    from taichi_mex.spec import RunSpec
    from taichi_mex.toolpath.generate import write_pattern

    p = case.params
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    row = {"case": case.name, **{k: p[k] for k in BASE}, "status": "", "message": ""}
    t0 = time.perf_counter()
    try:
        gcode = write_pattern(out_dir / "bead.gcode", layer_height_mm=p["layer_height_mm"],
                              speed_mm_s=p["speed_mm_s"], bead_length_mm=bead_length_mm,
                              line_width_mm=max(0.45, p["layer_height_mm"] + 0.1))
        spec = RunSpec.create("print", changes={
            "scene.gcode": str(gcode), "run.scheme": p["scheme"], "run.spacing_mm": p["spacing_mm"],
            "run.precision": p["precision"], "run.dt_factor": p["dt_factor"],
            "run.viscosity_scale": 1.0, "run.progress": False, "run.arch": arch,
            "run.snapshots": False, "run.edac.sound_speed_m_s": 6.0,
            "material.viscosity_pa_s": p["viscosity_pa_s"]})
        sim = Simulation.from_spec(spec, out_dir)
        s = sim.run()
        slice_mm3 = sim.inlet.n_slice * p["spacing_mm"] ** 3
        mass_ok = abs(s["deposited_volume_mm3"] - s["commanded_volume_mm3"]) <= 0.5 * slice_mm3 + 1e-9
        ok = mass_ok and s["compression_error_max"] <= MAX_COMPRESSION and s["particles_lost"] == 0
        row.update(status="ok" if ok else "bad",
                   compression_error_max=s["compression_error_max"],
                   compression_error_mean=s["compression_error_mean"],
                   deposited_mm3=s["deposited_volume_mm3"], commanded_mm3=s["commanded_volume_mm3"],
                   steps=s["steps"], particles=s["particles_active"],
                   halvings=s.get("time_step_halvings", 0),
                   message="" if ok else ("mass not conserved" if not mass_ok else
                                          "compression above 5 %" if s["compression_error_max"] > MAX_COMPRESSION
                                          else "particles lost"))
    except UserInputError as exc:
        row.update(status="refused", message=str(exc))
    except SimulationDiverged as exc:
        row.update(status="diverged", message=str(exc))
    row["wall_time_s"] = time.perf_counter() - t0
    return row


def table(rows: list[dict]) -> str:
    lines = ["| case | result | compression max | deposited / commanded | steps | wall s | note |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        comp = f"{100 * r['compression_error_max']:.2f} %" if "compression_error_max" in r else ""
        mass = f"{r['deposited_mm3']:.4f} / {r['commanded_mm3']:.4f}" if "deposited_mm3" in r else ""
        note = r["message"].split(". ")[0][:90]
        lines.append(f"| {r['case']} | {r['status']} | {comp} | {mass} | {r.get('steps', '')} | "
                     f"{r['wall_time_s']:.0f} | {note} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    from taichi_mex.app.parsing import Parser

    p = Parser(prog="python -m taichi_mex stability",
               description="The stability matrix: single-bead cases at the extremes")
    p.add_argument("--out", type=Path, default=Path("stability_out"), help="output folder")
    p.add_argument("--fast", action="store_true", help="only the cases the test suite runs")
    p.add_argument("--arch", choices=["cpu", "gpu"], default="cpu", help="cpu (default) or gpu")
    args = p.parse_args(argv)
    rows = []
    for k, case in enumerate(CASES):
        if args.fast and case.slow:
            continue
        row = run_case(case, args.out / f"case{k:02d}", arch=args.arch)
        rows.append(row)
        print(f"{case.name:32s} {row['status']:9s} {row['wall_time_s']:7.1f} s  {row['message'][:80]}",
              flush=True)
    (args.out / "stability.json").write_text(json.dumps(rows, indent=2, default=float))
    (args.out / "stability.md").write_text(table(rows) + "\n")
    print(table(rows))
    return 0 if all(r["status"] in ("ok", "refused") for r in rows) else 1


if __name__ == "__main__":  # pragma: no cover
    import sys

    sys.exit(main())
