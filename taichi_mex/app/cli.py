"""Command line: ``python -m taichi_mex [FILE.gcode] [options]`` and its sub-commands.

Every flag of a run comes from the option declarations (``opt(flag=...)`` in options.py and
the scenes' options); this module only maps them onto a :class:`~taichi_mex.spec.RunSpec`.
Every user mistake ends as one paragraph on stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

from taichi_mex import bundled, materials
from taichi_mex.app.parsing import Parser, add_spec_flags, spec_changes
from taichi_mex.errors import SimulationDiverged, UserInputError
from taichi_mex.options import PRESETS
from taichi_mex.spec import RunSpec, scene_entries

SUBCOMMANDS = ("scene", "study", "bench", "sweep", "analyse", "stability")


def print_parser() -> tuple[Parser, set]:
    p = Parser(
        prog="python -m taichi_mex",
        description="Simulate the beads a 3D printer lays down from a G-code file. Sub-commands: "
        + ", ".join(SUBCOMMANDS) + " (run 'python -m taichi_mex scene --help').",
    )
    p.add_argument("gcode", nargs="?", default=None,
                   help=f"G-code file or bundled name (default: {bundled.DEFAULT_GCODE})")
    _add_common(p)
    p.add_argument("--dry-run", action="store_true", help="plan only: print the plan and the estimate, write plan.json")
    p.add_argument("--resume", type=Path, default=None, metavar="DIR",
                   help="continue the run in DIR from its last checkpoint (written at every "
                        "output frame and on Ctrl-C) to its end; takes no other options")
    return p, add_spec_flags(p, "print")


def _add_common(p: Parser, out_default: str = "taichi_mex_out") -> None:
    p.add_argument("--out", type=Path, default=Path(out_default), help="output folder")
    p.add_argument("--config", type=Path, default=None, metavar="FILE",
                   help="re-run the run described by FILE (a run's config.json, or its folder); "
                        "other options given change that description")
    p.add_argument("--preset", choices=sorted(PRESETS), default=None,
                   help="named parameter set: 'paper' = the seed paper's EDAC baseline")
    p.add_argument("--material", default=None, metavar="NAME|FILE.toml",
                   help=f"material: {', '.join(materials.known())} (properties and sources in "
                        "taichi_mex/materials/), or your own TOML file of the same form")


def spec_from_args(args, dests: set, scene: str) -> RunSpec:
    changes = spec_changes(args, dests)
    if getattr(args, "gcode", None) is not None:
        changes["scene.gcode"] = str(bundled.resolve_gcode(args.gcode))
    if args.config is not None:
        if args.preset or args.material:
            raise UserInputError("--preset and --material cannot change a --config run; give "
                                 "single options (--viscosity ...) or start without --config.")
        spec = RunSpec.load(args.config)
        return spec.with_changes(changes) if changes else spec
    return RunSpec.create(scene, args.preset, changes, material=args.material)


def run_simulation(spec: RunSpec, out_dir: Path, sim=None, progress: bool = True,
                   scene=None) -> int:
    """Print the estimate, run with a progress bar, report where the results are."""
    from taichi_mex.app.progress import ProgressBar
    from taichi_mex.sim.simulation import Simulation

    sim = sim or Simulation.from_spec(spec, out_dir=out_dir, scene=scene)
    if sim.resumed:
        print(f"resuming {out_dir} at t = {sim.time_s:.6g} s (step {sim.steps}) of "
              f"{sim.plan.t_end_s:.6g} s")
    if spec.scene != "print":  # a print's plan has said it already
        print(material_line(spec))
    print(f"estimate: {sim.describe_estimate()}")
    creeping = sim.describe_creeping()
    if creeping:
        print(creeping)
    for warning in sim.estimate["warnings"]:
        print(f"warning: {warning}")
    bar = ProgressBar(sim.time_s, sim.plan.t_end_s) if spec.run.progress and progress else None
    summary = sim.run(reporter=bar)
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
    for warning in run_warnings(summary, spec.run):
        print(f"warning: {warning}")
    print(f"results in {out_dir}: config.json, particles.h5, particles.xdmf, summary.json"
          + (", snapshots/" if spec.run.snapshots else ""))
    return 130 if summary.get("interrupted") else 0


def material_line(spec: RunSpec) -> str:
    m = spec.material
    eta = m.zero_shear_viscosity(m.extrusion_temperature_c)
    return (f"material {m.name}" + (f" ({spec.material_source})" if spec.material_source else "")
            + f": {m.density_kg_m3:g} kg/m^3, eta0 {eta:.4g} Pa s at {m.extrusion_temperature_c:g} "
            f"degC ({m.viscosity_model}), Tg {m.glass_transition_c:g} degC")


def run_warnings(summary: dict, run) -> list[str]:
    """What went wrong in a run that still finished: lost melt, unconverged viscous solves."""
    from taichi_mex.post.report import OVER_FACE_WARN, lost_melt_where, melt_over_face_text

    out = []
    lost = summary.get("particles_lost", 0)
    if lost:
        where = lost_melt_where(summary)
        out.append(f"{lost} melt particles were dropped" + (f" ({where})" if where else "")
                   + ": their positions were not finite")
    outside = summary.get("melt_outside_domain_max", 0)
    if outside:
        where = lost_melt_where(summary, "melt_outside_domain")
        out.append(f"up to {outside} melt particles were outside the domain's box at once"
                   + (f" ({where})" if where else "") + ": kept and simulated, searched in "
                   "the box's edge cells (slower there); melt carried off on the nozzle or "
                   "the part, or a domain too small (run.margin_mm)")
    if summary.get("melt_over_face_fraction_max", 0.0) >= OVER_FACE_WARN:
        out.append(f"melt stood over the nozzle's tip face ({melt_over_face_text(summary)}): "
                   "strings and blobs the nozzle lifts and drags, or laid over the part above "
                   "the layer it prints; nothing here breaks a thread (a retraction draws no "
                   "melt back, and melt stays molten with heat off)")
    worst = summary.get("viscosity_residual_worst")
    tol = run.dfsph.viscosity_tolerance
    if worst is not None and worst > 10 * tol:
        out.append(f"the implicit viscosity solve stopped short of its tolerance in at least one "
                   f"step (worst relative residual {worst:.2g} against {tol:g}); raise "
                   f"run.dfsph.viscosity_max_iterations ({run.dfsph.viscosity_max_iterations}) "
                   "or lower the CFL factor")
    return out


def run_print(argv: list[str]) -> int:
    parser, dests = print_parser()
    args = parser.parse_args(argv)
    if args.resume is not None:
        changes = spec_changes(args, dests)
        quiet = changes.pop("run.progress", True) is False  # --quiet changes no result
        given = sorted(changes) + [f"--{k}" for k in ("config", "preset", "material", "gcode")
                                   if getattr(args, k) is not None]
        if given or args.dry_run:
            raise UserInputError(f"--resume continues a run as it was described; drop "
                                 f"{', '.join(given) or '--dry-run'} (or start a new run with --config).")
        from taichi_mex.sim.simulation import Simulation

        sim = Simulation.resume(args.resume)
        return run_simulation(sim.description(), args.resume, sim, progress=not quiet)
    spec = spec_from_args(args, dests, "print")
    if spec.scene != "print":  # --config of a scene run
        if args.dry_run:
            raise UserInputError(f"--dry-run plans prints; this description is a '{spec.scene}' scene.")
        return run_simulation(spec, args.out)
    # the run's own plan, made once: through the last selected layer (benchy's layer 3:
    # 2.4 s against 38 s for the whole file, which the run never reads)
    scene = spec.build_scene()
    plan = scene.print_plan
    print(plan.describe())
    print(material_line(spec))
    print(f"plan written to {plan.write(args.out)}")
    if args.dry_run:  # what the run would cost, before committing to it
        from taichi_mex.sim.simulation import Simulation

        print(f"estimate: {Simulation.from_spec(spec, scene=scene).describe_estimate()}")
        return 0
    return run_simulation(spec, args.out, scene=scene)


def run_scene(argv: list[str]) -> int:
    scenes = {k: v for k, v in scene_entries().items() if k != "print"}
    if not argv or argv[0] in ("-h", "--help"):
        print("usage: python -m taichi_mex scene NAME [options] --out DIR\n\nscenes:")
        for entry in scenes.values():
            print(f"  {entry.name:14s} {entry.help}")
        return 0
    name = argv[0]
    if name not in scenes:
        raise UserInputError(f"Unknown scene '{name}'; choose one of {', '.join(scenes)}.")
    p = Parser(prog=f"python -m taichi_mex scene {name}", description=scenes[name].help)
    _add_common(p, out_default=f"{name}_out")
    dests = add_spec_flags(p, name)
    args = p.parse_args(argv[1:])
    return run_simulation(spec_from_args(args, dests, name), args.out)


def run_bench(argv: list[str]) -> int:
    import json

    from taichi_mex.app import bench

    if argv and argv[0] == "dam-break":  # not in `bench all`: PySPH takes minutes
        from taichi_mex.app.peer import main as peer_main

        return peer_main(argv[1:], parser_class=Parser)
    if argv and argv[0] == "collapse":  # not in `bench all`: SPlisHSPlasH takes minutes
        from taichi_mex.app.peer_splishsplash import main as collapse_main

        return collapse_main(argv[1:], parser_class=Parser)

    p = Parser(prog="python -m taichi_mex bench",
               description="Measure particle-steps per second (and the toolpath sampler).")
    p.add_argument("which", nargs="?", default="all",
                   choices=["all", "print", "edac", "toolpath", "dam-break", "collapse"],
                   help="dam-break: ours against PySPH (optional 'peer' extra); collapse: ours "
                        "against SPlisHSPlasH (optional 'splishsplash' extra); see --help there")
    p.add_argument("--particles", type=int, default=100_000, help="size of the EDAC block")
    p.add_argument("--measure", type=float, default=None,
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
        from taichi_mex.sim.simulation import Simulation

        spec = RunSpec.create("print", changes={"run.arch": args.arch})
        sim = Simulation.from_spec(spec)
        span = sim.plan.t_end_s - sim.plan.t_start_s
        r = bench.bench_scene(sim, 0.1 * span, args.measure or 0.3 * span)
        rows.append({"name": f"default print ({spec.run.scheme})", **r})
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
    logging.basicConfig(format="warning: %(message)s", level=logging.WARNING, stream=sys.stdout)
    try:
        if argv and argv[0] == "bench":
            return run_bench(argv[1:])
        if argv and argv[0] == "scene":
            return run_scene(argv[1:])
        if argv and argv[0] in ("analyse", "analyze"):
            from taichi_mex.app.analyse import main as analyse_main

            return analyse_main(argv[1:])
        if argv and argv[0] == "study":
            from taichi_mex.app.study import main as study_main

            return study_main(argv[1:])
        if argv and argv[0] == "sweep":
            from taichi_mex.app.sweep import main as sweep_main

            return sweep_main(argv[1:])
        if argv and argv[0] == "stability":
            from taichi_mex.app.stability import main as stability_main

            return stability_main(argv[1:])
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
