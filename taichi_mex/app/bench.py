"""Benchmarks (``python -m taichi_mex bench NAME``): measured figures for the README."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np


from taichi_mex.bundled import pygcd_example


def bench_toolpath(gcode: Path | None = None, printer: str = "prusa_mini",
                   queries: int = 1_000_000, reference_calls: int = 20) -> dict:
    """Queries per second of the vectorised sampler vs pyGCodeDecode's ``get_values``."""
    from taichi_mex.toolpath.trajectory import load_trajectory

    gcode = Path(gcode) if gcode else pygcd_example("benchy.gcode")
    t0 = time.perf_counter()
    traj = load_trajectory(gcode, printer)
    build_s = time.perf_counter() - t0
    rng = np.random.default_rng(0)
    times = rng.uniform(0.0, traj.print_time_s, queries)
    traj.sample(times[:1000])
    t0 = time.perf_counter()
    traj.sample(times)
    ours_s = time.perf_counter() - t0

    from pyGCodeDecode import gcode_interpreter as gci

    t0 = time.perf_counter()
    sim = gci.simulation(gcode_path=gcode, machine_name=printer, verbosity_level=0)
    ref_build_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    for t in times[:reference_calls]:
        sim.get_values(float(t))
    ref_s = (time.perf_counter() - t0) / reference_calls
    return {
        "gcode": gcode.name, "segments": traj.n_segments, "print_time_s": traj.print_time_s,
        "trajectory_build_s": build_s, "pygcodedecode_build_s": ref_build_s,
        "queries": queries, "sample_s": ours_s, "queries_per_s": queries / ours_s,
        "get_values_s_per_call": ref_s, "speedup": (queries / ours_s) * ref_s,
    }


def print_toolpath(result: dict) -> None:
    r = result
    print(f"{r['gcode']}: {r['segments']} segments, print time {r['print_time_s']:.1f} s")
    print(f"  build: ours {r['trajectory_build_s']:.1f} s (pyGCodeDecode planning included), "
          f"pyGCodeDecode alone {r['pygcodedecode_build_s']:.1f} s")
    print(f"  vectorised sampler: {r['queries']} queries in {r['sample_s']:.3f} s = "
          f"{r['queries_per_s'] / 1e6:.2f} M queries/s")
    print(f"  pyGCodeDecode get_values: {1e3 * r['get_values_s_per_call']:.1f} ms per call "
          f"-> ours is {r['speedup']:.3g}x faster per query")


def bench_scene(sim, warm_s: float, measure_s: float) -> dict:
    """Run ``warm_s`` simulated seconds (compilation, first sorts), then time ``measure_s``.

    Particle-steps count every live particle (plate included), as PySPH's figures do; the
    melt-only figure is given beside it."""
    sim.run_opts.progress = False
    sim.build()
    t0 = sim.plan.t_start_s
    sim.plan.t_end_s = t0 + warm_s + measure_s
    sim.run(until_s=t0 + warm_s)
    steps0 = sim.steps
    import time as _time

    from taichi_mex.core.state import FLUID

    wall0 = _time.perf_counter()
    n_sum = 0
    melt_sum = 0
    def advance(end: float) -> int:
        # step by hand so that no output or summary work enters the timing
        t, n_sum = sim.time_s, 0
        while t < end - 1e-15:
            dt, _ = sim.solver.time_step()
            dt = min(dt * sim.run_opts.dt_factor, end - t)
            dt = sim.solver.step(t, dt)
            t += dt
            sim.time_s = t
            sim.steps += 1
            n_sum += sim.state.n
        return n_sum

    n_sum = advance(t0 + warm_s + measure_s)
    wall = _time.perf_counter() - wall0
    steps = sim.steps - steps0
    phase = sim.state.phase.to_numpy()[: sim.state.n]
    melt_sum = int((phase == FLUID).sum()) * steps
    # where the time goes: a further, profiled stretch of half the window (the profile waits
    # for the device at each phase, so it is kept out of the rate above)
    sim.timer.enabled = True
    sim.plan.t_end_s += 0.5 * measure_s
    advance(sim.plan.t_end_s)
    total = sum(sim.timer.seconds.values()) or 1.0
    split = {k: v / total for k, v in sorted(sim.timer.seconds.items(), key=lambda kv: -kv[1])}
    return {"particles": int(sim.state.n), "melt_particles": int((phase == FLUID).sum()),
            "steps": steps, "wall_s": wall, "simulated_s": measure_s,
            "particle_steps_per_s": n_sum / wall, "melt_particle_steps_per_s": melt_sum / wall,
            "wall_per_simulated_s": wall / measure_s, "phase_share": split}


def edac_block(target_particles: int = 100_000, arch: str = "cpu"):
    """A water-like column in a tank (EDAC, Wendland, h = 1.3 dx) of about N particles."""
    from taichi_mex.sim.simulation import Simulation
    from taichi_mex.spec import RunSpec

    # fluid 1 x 1 x 2 aspect; walls add ~1/3
    n_fluid = target_particles / 1.5
    side = int(round((n_fluid / 2) ** (1 / 3)))
    dx_mm = 0.25
    spec = RunSpec.create("hydrostatic", changes={
        "scene.width_mm": side * dx_mm, "scene.height_mm": 2 * side * dx_mm, "scene.until_s": 1.0,
        "run.scheme": "edac", "run.spacing_mm": dx_mm, "run.snapshots": False,
        "run.progress": False, "run.arch": arch, "material.viscosity_pa_s": 1e-3})
    return Simulation.from_spec(spec)


def print_table(rows: list[dict]) -> None:
    print(f"{'benchmark':28s} {'particles':>10s} {'steps':>7s} {'wall s':>8s} "
          f"{'M p-steps/s':>12s} {'wall s / sim s':>15s}")
    for r in rows:
        print(f"{r['name']:28s} {r['particles']:>10,d} {r['steps']:>7d} {r['wall_s']:>8.2f} "
              f"{r['particle_steps_per_s'] / 1e6:>12.3f} {r['wall_per_simulated_s']:>15.4g}")
    for r in rows:
        if r.get("phase_share"):
            print(f"{r['name']}: " + ", ".join(f"{k} {100 * v:.0f} %" for k, v in r["phase_share"].items()))
