"""Command line: ``python -m taichi_mex [FILE.gcode] [options]`` and its sub-commands.

Every user mistake ends as one paragraph on stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from taichi_mex import bundled
from taichi_mex.errors import SimulationDiverged, UserInputError

SUBCOMMANDS = ("scene", "study", "bench", "sweep", "analyse")


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a number") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"'{text}' must be positive")
    return value


def _resolution(text: str) -> float:
    from taichi_mex.options import RESOLUTION_PRESETS

    if text in RESOLUTION_PRESETS:
        return float(RESOLUTION_PRESETS[text]["run"]["spacing_mm"])
    try:
        return _positive_float(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(
            f"'{text}' is neither a spacing in mm nor one of {', '.join(RESOLUTION_PRESETS)}") from None


class _Parser(argparse.ArgumentParser):
    """argparse that reports errors through UserInputError (one paragraph, exit 2)."""

    def error(self, message):
        raise UserInputError(f"{message}. Run '{self.prog} --help' for the options.")


def print_parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="python -m taichi_mex",
        description="Simulate the beads a 3D printer lays down from a G-code file. Sub-commands: "
        + ", ".join(SUBCOMMANDS) + " (run 'python -m taichi_mex scene --help').",
    )
    p.add_argument("gcode", nargs="?", default=None,
                   help=f"G-code file (default: the bundled {bundled.DEFAULT_GCODE})")
    p.add_argument("--out", type=Path, default=Path("taichi_mex_out"), help="output folder")
    p.add_argument("--printer", default="prusa_mini",
                   help="pyGCodeDecode printer preset name, or FILE.yaml[:NAME] (default prusa_mini)")
    p.add_argument("--layers", default=None, help="layers to simulate, e.g. 2-3 (1-based)")
    p.add_argument("--region", default=None, help="XY box XMIN:XMAX,YMIN:YMAX in mm")
    p.add_argument("--until", type=_positive_float, default=None, help="stop at this print time (s)")
    p.add_argument("--dry-run", action="store_true", help="plan only: print the plan and write plan.json")
    add_run_options(p)
    p.add_argument("--settle", type=float, default=0.0,
                   help="simulate this long (s) after the last deposition (default 0)")
    return p


def add_run_options(p: argparse.ArgumentParser) -> None:
    """Options shared by the print command and the scenes."""
    from taichi_mex.backend import ARCHES, PRECISIONS
    from taichi_mex.options import PRESETS, SCHEMES

    p.add_argument("--resolution", "--spacing-mm", dest="spacing_mm", type=_resolution,
                   default=None, help="particle spacing in mm, or draft / standard / fine "
                                      "(3 / 4 / 6 particles across a 0.2 mm layer; default standard)")
    p.add_argument("--scheme", "--solver", dest="scheme", choices=SCHEMES, default=None,
                   help="pressure solver: dfsph (default: implicit pressure and viscosity) or edac (the seed paper's explicit baseline)")
    p.add_argument("--preset", choices=sorted(PRESETS), default=None,
                   help="named parameter set: 'paper' = the seed paper's EDAC baseline")
    p.add_argument("--viscosity", type=_positive_float, default=None,
                   help="Newtonian melt viscosity in Pa s (overrides the material)")
    p.add_argument("--viscosity-scale", default=None, metavar="FACTOR|auto|off",
                   help="creeping-flow scaling of the melt viscosity (default auto for DFSPH prints: "
                        "the smallest factor keeping Re, gravity number and slump below 0.05)")
    p.add_argument("--sound-speed", type=_positive_float, default=None,
                   help="EDAC artificial sound speed in m/s")
    p.add_argument("--arch", choices=ARCHES, default="cpu", help="cpu (default) or gpu")
    p.add_argument("--precision", choices=PRECISIONS, default="f32", help="f32 (default) or f64")
    p.add_argument("--threads", type=int, default=None, help="CPU threads (default: all cores)")
    p.add_argument("--output-every", type=_positive_float, default=None,
                   help="write an HDF5 frame every this many simulated seconds (default: 10 frames)")
    p.add_argument("--snapshot-every", type=_positive_float, default=None,
                   help="also write PNG snapshots every this many simulated seconds (default: end only)")
    p.add_argument("--field", default="density",
                   help="field the snapshots are coloured by (density, pressure, velocity, temperature, ...)")
    p.add_argument("--no-snapshots", action="store_true", help="skip the PNG snapshots")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    heat = p.add_argument_group("heat (off unless --thermal)")
    heat.add_argument("--thermal", action="store_true", help="simulate temperature")
    heat.add_argument("--convection", type=float, default=None, metavar="W_M2K",
                      help="convective heat transfer coefficient h_c (W/m^2/K)")
    heat.add_argument("--radiation", type=float, default=None, metavar="EMISSIVITY",
                      help="radiate to ambient with this emissivity (off unless given)")
    heat.add_argument("--ambient", type=float, default=None, help="ambient temperature (degC)")
    heat.add_argument("--plate-temperature", type=float, default=None, help="build plate (degC)")
    heat.add_argument("--surface-method", choices=["colour_gradient", "eigenvalue"], default=None,
                      help="free-surface area estimate for losses (default colour_gradient)")


def build_options(args, scheme_default: str = "dfsph"):
    """RunOptions and Material from parsed arguments and an optional preset."""
    from taichi_mex.options import PRESETS, Material, RunOptions, apply_overrides

    run = RunOptions(scheme=scheme_default)
    material = Material()
    preset = PRESETS.get(getattr(args, "preset", None) or "", {})
    if preset:
        run = apply_overrides(run, preset.get("run", {}))
        material = apply_overrides(material, preset.get("material", {}))
    changes = {}
    if args.spacing_mm is not None:
        changes["spacing_mm"] = args.spacing_mm
    if args.scheme is not None:
        changes["scheme"] = args.scheme
    changes.update(arch=args.arch, precision=args.precision, cpu_threads=args.threads,
                   output_every_s=args.output_every, snapshot_field=args.field,
                   snapshots=not args.no_snapshots, progress=not args.quiet)
    if args.sound_speed is not None:
        changes["edac"] = {"sound_speed_m_s": args.sound_speed}
    if args.viscosity_scale is not None:
        text = str(args.viscosity_scale).lower()
        if text == "auto":
            changes["viscosity_scale"] = "auto"
        elif text in ("off", "none", "1"):
            changes["viscosity_scale"] = 1.0
        else:
            try:
                changes["viscosity_scale"] = float(text)
            except ValueError:
                raise UserInputError(f"--viscosity-scale takes a number, 'auto' or 'off', not "
                                     f"'{args.viscosity_scale}'.") from None
    thermal = {}
    if getattr(args, "thermal", False):
        thermal["enabled"] = True
    for arg, key in (("convection", "convection_w_m2k"), ("radiation", "radiation_emissivity"),
                     ("ambient", "ambient_c"), ("plate_temperature", "plate_temperature_c"),
                     ("surface_method", "surface_method")):
        if getattr(args, arg, None) is not None:
            thermal[key] = getattr(args, arg)
    if thermal:
        changes["thermal"] = thermal
    run = apply_overrides(run, changes)
    if args.viscosity is not None:
        material = apply_overrides(material, {"viscosity_pa_s": args.viscosity,
                                              "viscosity_model": "newtonian"})
    return run, material, preset


def run_simulation(sim, out_dir: Path, snapshot_every: float | None = None) -> dict:
    """Print the estimate, run with a progress bar, report where the results are."""
    print(f"estimate: {sim.describe_estimate()}")
    creeping = sim.describe_creeping()
    if creeping:
        print(creeping)
    for warning in sim.estimate["warnings"]:
        print(f"warning: {warning}")
    sim.snapshot_every_s = snapshot_every
    summary = sim.run()
    state = "interrupted (frames so far kept)" if summary.get("interrupted") else "done"
    print(f"{state}: {summary['steps']} steps, {summary['simulated_time_s']:.4g} s simulated in "
          f"{summary['wall_time_s']:.1f} s ({summary['particle_steps_per_s'] / 1e6:.2f} M particle-steps/s)")
    for key in ("pressure_error_rel_mean", "shear_error_max_rel_U", "front_ratio_late",
                "thermal_error_max_c"):
        if key in summary:
            print(f"{key}: {summary[key]:.4g}")
    if "commanded_volume_mm3" in summary:
        print(f"deposited {summary['deposited_volume_mm3']:.4f} mm^3 of "
              f"{summary['commanded_volume_mm3']:.4f} mm^3 commanded; density error mean "
              f"{100 * summary['density_error_mean']:.3f} %, max {100 * summary['density_error_max']:.3f} %")
    for warning in run_warnings(summary, sim.run_opts):
        print(f"warning: {warning}")
    print(f"results in {out_dir}: particles.h5, particles.xdmf, summary.json"
          + (", snapshots/" if sim.run_opts.snapshots else ""))
    return summary


def run_warnings(summary: dict, run) -> list[str]:
    """What went wrong in a run that still finished: lost melt, unconverged viscous solves."""
    out = []
    lost = summary.get("particles_lost", 0)
    if lost:
        ejected = summary.get("droplets_ejected", 0)
        why = (f"{ejected} of them droplets flung faster than the ejection speed"
               if ejected else "flung off the nozzle or the part")
        out.append(f"{lost} melt particles left the domain ({why})")
    worst = summary.get("viscosity_residual_worst")
    tol = run.dfsph.viscosity_tolerance
    if worst is not None and worst > 10 * tol:
        out.append(f"the implicit viscosity solve stopped short of its tolerance in at least one "
                   f"step (worst relative residual {worst:.2g} against {tol:g}); raise "
                   f"DFSPHOptions.viscosity_max_iterations ({run.dfsph.viscosity_max_iterations}) "
                   "or lower the CFL factor")
    return out


def run_print(argv: list[str]) -> int:
    from taichi_mex.toolpath.plan import make_plan
    from taichi_mex.toolpath.trajectory import parse_layers, parse_region

    args = print_parser().parse_args(argv)
    run, material, preset = build_options(args)
    default = preset.get("gcode", bundled.DEFAULT_GCODE)
    gcode = Path(args.gcode) if args.gcode else bundled.gcode_path(default)
    layers = parse_layers(args.layers)
    region = parse_region(args.region)
    plan = make_plan(gcode, args.printer, layers=layers, until_s=args.until, region_mm=region)
    print(plan.describe())
    path = plan.write(args.out)
    print(f"plan written to {path}")
    if args.dry_run:
        return 0
    from taichi_mex.scenes.print import PrintScene
    from taichi_mex.sim.simulation import Simulation

    scene = PrintScene(gcode, args.printer, layers=layers, region_mm=region, until_s=args.until,
                       settle_s=args.settle, **preset_scene_options(preset))
    sim = Simulation(scene, run, material, out_dir=args.out)
    summary = run_simulation(sim, args.out, args.snapshot_every)
    return 130 if summary.get("interrupted") else 0


def preset_scene_options(preset: dict) -> dict:
    out = {}
    if preset.get("nozzle_height") == "one_diameter":
        out["nozzle_height"] = "one_diameter"
    if preset.get("nozzle_tip") is False:
        out["nozzle_tip_outer_diameter_mm"] = None
    return out


def default_print_scene(args=None):
    """The bundled default print and its options (what `python -m taichi_mex` runs)."""
    from taichi_mex.scenes.print import PrintScene

    args = args or print_parser().parse_args([])
    run, material, preset = build_options(args)
    gcode = bundled.gcode_path(preset.get("gcode", bundled.DEFAULT_GCODE))
    return PrintScene(gcode, args.printer, **preset_scene_options(preset)), run, material


def run_scene(argv: list[str]) -> int:
    from taichi_mex.options import apply_overrides
    from taichi_mex.scenes import load_all
    from taichi_mex.sim.simulation import Simulation

    scenes = load_all()
    if not argv or argv[0] in ("-h", "--help"):
        print("usage: python -m taichi_mex scene NAME [options] --out DIR\n\nscenes:")
        for spec in scenes.values():
            print(f"  {spec.name:14s} {spec.help}")
        return 0
    name = argv[0]
    if name not in scenes:
        raise UserInputError(f"Unknown scene '{name}'; choose one of {', '.join(scenes)}.")
    spec = scenes[name]
    p = _Parser(prog=f"python -m taichi_mex scene {name}", description=spec.help)
    p.add_argument("--out", type=Path, default=Path(f"{name}_out"), help="output folder")
    add_run_options(p)
    spec.add_arguments(p)
    args = p.parse_args(argv[1:])
    scene, run_defaults, material_overrides = spec.build(args)
    run, material, _ = build_options(args, scheme_default=run_defaults.get("scheme", "dfsph"))
    explicit = {"spacing_mm": args.spacing_mm, "scheme": args.scheme,
                "edac": args.sound_speed, "viscosity_scale": args.viscosity_scale}
    defaults = {k: v for k, v in run_defaults.items() if explicit.get(k) is None}
    run = apply_overrides(run, defaults)
    material = apply_overrides(material, material_overrides)
    sim = Simulation(scene, run, material, out_dir=args.out)
    summary = run_simulation(sim, args.out, args.snapshot_every)
    return 130 if summary.get("interrupted") else 0


def run_bench(argv: list[str]) -> int:
    import json

    from taichi_mex.app import bench

    if argv and argv[0] == "dam-break":  # not in `bench all`: PySPH takes minutes
        from taichi_mex.app.peer import main as peer_main

        return peer_main(argv[1:], parser_class=_Parser)

    p = _Parser(prog="python -m taichi_mex bench",
                description="Measure particle-steps per second (and the toolpath sampler).")
    p.add_argument("which", nargs="?", default="all",
                   choices=["all", "print", "edac", "toolpath", "dam-break"],
                   help="dam-break: ours against PySPH (optional 'peer' extra); see --help there")
    p.add_argument("--particles", type=int, default=100_000, help="size of the EDAC block")
    p.add_argument("--measure", type=_positive_float, default=None,
                   help="simulated seconds to time (default: per benchmark)")
    p.add_argument("--out", type=Path, default=None, help="also write bench.json here")
    p.add_argument("--arch", choices=["cpu", "gpu"], default="cpu", help="cpu (default) or gpu")
    args = p.parse_args(argv)
    rows = []
    if args.which == "toolpath":
        result = bench.bench_toolpath()
        bench.print_toolpath(result)
        rows.append(result)
    if args.which in ("all", "print"):
        scene, run, material = default_print_scene(print_parser().parse_args(["--arch", args.arch]))
        from taichi_mex.sim.simulation import Simulation

        sim = Simulation(scene, run, material)
        span = sim.plan.t_end_s - sim.plan.t_start_s
        r = bench.bench_scene(sim, 0.1 * span, args.measure or 0.3 * span)
        rows.append({"name": f"default print ({run.scheme})", **r})
    if args.which in ("all", "edac"):
        sim = bench.edac_block(args.particles, args.arch)
        r = bench.bench_scene(sim, 2e-4, args.measure or 2e-3)
        rows.append({"name": "EDAC tank (Wendland, h=1.3dx)", **r})
    if args.which != "toolpath":
        bench.print_table(rows)
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "bench.json").write_text(json.dumps(rows, indent=2))
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        if argv and argv[0] == "bench":
            return run_bench(argv[1:])
        if argv and argv[0] == "scene":
            return run_scene(argv[1:])
        if argv and argv[0] in ("analyse", "analyze"):
            from taichi_mex.post.analysis import main as analyse_main

            return analyse_main(argv[1:])
        if argv and argv[0] == "study":
            from taichi_mex.app.study import main as study_main

            return study_main(argv[1:])
        if argv and argv[0] == "sweep":
            from taichi_mex.app.sweep import main as sweep_main

            return sweep_main(argv[1:])
        return run_print(argv)
    except UserInputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except SimulationDiverged as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 3
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
