"""Side by side with PySPH (the seed paper's framework) on PySPH's own 3D dam break with EDAC.

    python -m taichi_mex bench dam-break [--steps N] [--no-pysph] [--pysph-runs both|openmp|single]

Both codes run the same case one after the other on this machine, in one command: ours,
then PySPH with OpenMP on the same threads, then PySPH on one core. The geometry of
``pysph.examples._db_geometry.DamBreak3DGeometry`` (dx = 0.02 m, nboundary_layers = 1:
80,703 fluid + 60,836 tank + 1,512 obstacle = 143,051 particles), EDAC with pb = 0, nu = 0,
h = 1.3 dx, Wendland C2 (PySPH's WendlandQuintic, support 2h), c0 = 10 sqrt(2 g 0.55),
gravity -9.81 m/s^2 in z.

* ours: :class:`taichi_mex.scenes.dam_break.DamBreak3DScene`, a few warm-up steps first
  (Taichi compiles each kernel on its first call), then N steps timed;
* PySPH: its ``EDACScheme`` with its default PEC integrator through an ``Application``
  subclass, run in a subprocess (so its OpenMP threads and compilation stay out of our
  process); the code generation and Cython build happen in ``setup`` and are not timed; we
  time ``solver.solve()`` for N steps with output disabled, which is what PySPH prints as
  "Run took" (it includes one extra acceleration evaluation before the first step).

Time step: PySPH steps with the fixed dt = 0.125 h / c0 that its EDAC examples use
(dam_break_2d); ours uses dt = 0.125 h / (c0 + |v|max), the same value while |v| << c0
(100 steps from rest: |v| < 0.1 m/s against c0 = 32.8 m/s).

Particle-steps per second count every particle (fluid, tank, obstacle) in both codes, as
the PySPH figures quoted in issue 6 do. Each run also records the CPU time that other
processes used while it was timed (from /proc/stat, Linux): on a shared machine a busy
neighbour slows PySPH's OpenMP loops (each waits for its slower thread) more than it slows
ours, and the figures are comparable only when that is near zero.

After the timed steps ours runs a further stretch with the phase timer on (it waits for
the device at each phase boundary, so it is kept out of the rate) and prints where a step's
time goes.

PySPH is optional (``pip install '.[peer]'``, a ~4 minute Cython build). The worker runs
under this interpreter when it can import pysph, else under ``--pysph-python PATH`` (or the
environment variable ``TAICHI_MEX_PYSPH_PYTHON``), e.g. a separate virtualenv that holds
PySPH only: the worker part of this file imports nothing of ours.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time

DX_M = 0.02
HDX = 1.3
RHO0 = 1000.0
G = 9.81
FLUID_HEIGHT_M = 0.55
C0 = 10.0 * math.sqrt(2.0 * G * FLUID_HEIGHT_M)
#: PySPH's EDAC examples: fixed dt = 0.125 h / c0
DT_FACTOR = 0.125
_RESULT_TAG = "PEER_RESULT "
PYTHON_ENV = "TAICHI_MEX_PYSPH_PYTHON"


def pysph_dt(dx_m: float = DX_M) -> float:
    return DT_FACTOR * HDX * dx_m / C0


def busy_cpu_s() -> float:
    """CPU seconds all processes on this machine have used since boot (nan off Linux)."""
    try:
        with open("/proc/stat") as fh:
            fields = [int(v) for v in fh.readline().split()[1:]]
    except (OSError, ValueError):
        return math.nan
    idle = fields[3] + fields[4]  # idle, iowait
    return (sum(fields[:8]) - idle) / os.sysconf("SC_CLK_TCK")


# ---------------------------------------------------------------------------- ours
def bench_ours(steps: int = 100, dx_m: float = DX_M, threads: int | None = None,
               precision: str = "f32", arch: str = "cpu", warm_steps: int = 3) -> dict:
    """Our dam break: ``warm_steps`` untimed steps (kernel compilation), then ``steps`` timed."""
    from taichi_mex.backend import ti
    from taichi_mex.sim.simulation import Simulation
    from taichi_mex.spec import RunSpec

    spec = RunSpec.create("dam-break", changes={
        "scene.dx_m": dx_m, "scene.until_s": 1.0, "run.progress": False, "run.snapshots": False,
        "run.cpu_threads": threads, "run.precision": precision, "run.arch": arch})
    sim = Simulation.from_spec(spec)
    t_build = time.perf_counter()
    sim.build()
    # warm-up through the ordinary run loop: compiles every kernel on the path, incl. a re-sort
    sim.run(until_s=warm_steps * pysph_dt(dx_m))
    warm_s = time.perf_counter() - t_build
    solver = sim.solver
    dts = []

    def advance(k: int) -> int:
        particle_steps = 0
        for _ in range(k):  # by hand: no output, summary or monitor work in the timing
            dt, _limits = solver.time_step()
            dt = solver.step(sim.time_s, dt)
            sim.time_s += dt
            sim.steps += 1
            particle_steps += sim.state.n
            dts.append(dt)
        ti.sync()
        return particle_steps

    rebuilds0 = sim.grid.rebuilds
    busy0 = busy_cpu_s()
    wall0 = time.perf_counter()
    cpu0 = time.process_time()
    particle_steps = advance(steps)
    wall = time.perf_counter() - wall0
    cpu = time.process_time() - cpu0
    others = busy_cpu_s() - busy0 - cpu
    rebuilds = sim.grid.rebuilds - rebuilds0
    speed = solver.max_speed()
    sim.timer.enabled = True
    advance(max(steps // 2, 1))
    total = sum(sim.timer.seconds.values()) or 1.0
    split = {k: v / total for k, v in sorted(sim.timer.seconds.items(), key=lambda kv: -kv[1])}
    out = {
        "code": "taichi_mex", "particles": int(sim.state.n), **sim.scene.counts,
        "steps": steps, "wall_s": wall, "cpu_s": cpu, "particle_steps_per_s": particle_steps / wall,
        "dt_first_s": dts[0], "dt_last_s": dts[steps - 1], "neighbour_rebuilds": rebuilds,
        "max_speed_m_s": speed, "finite": bool(math.isfinite(speed)),
        "warmup_s": warm_s, "arch": sim.arch_used, "precision": precision,
        "threads": threads or os.cpu_count(), "others_cpu_s": others, "phase_share": split,
    }
    ti.reset()  # free the fields (and the CPU thread pool) before PySPH runs
    return out


# ---------------------------------------------------------------------------- PySPH
def find_pysph_python(explicit: str | None = None) -> tuple[str | None, str]:
    """(interpreter that imports pysph, its version) or (None, why not)."""
    candidates = [explicit] if explicit else [sys.executable, os.environ.get(PYTHON_ENV)]
    reasons = []
    for python in candidates:
        if not python:
            continue
        try:
            proc = subprocess.run([python, "-c", "import pysph; print(pysph.__version__)"],
                                  capture_output=True, text=True, timeout=120)
        except (OSError, subprocess.TimeoutExpired) as exc:
            reasons.append(f"{python}: {exc}")
            continue
        if proc.returncode == 0:
            return python, proc.stdout.strip()
        reasons.append(f"{python}: cannot import pysph")
    return None, "; ".join(reasons) or "no interpreter given"


def bench_pysph(steps: int = 100, dx_m: float = DX_M, openmp: bool = True,
                threads: int | None = None, python: str | None = None,
                timeout_s: float = 3600.0) -> dict:
    """PySPH's dam break with EDACScheme for ``steps`` steps, in a subprocess."""
    python = python or sys.executable
    cfg = {"steps": steps, "dx": dx_m, "openmp": openmp}
    n_threads = (threads or os.cpu_count() or 1) if openmp else 1
    env = {**os.environ, "OMP_NUM_THREADS": str(n_threads)}
    with tempfile.TemporaryDirectory(prefix="pysph_dam_break_") as work:
        cfg["output_dir"] = work
        proc = subprocess.run([python, os.path.abspath(__file__), "--pysph-worker", json.dumps(cfg)],
                              capture_output=True, text=True, env=env, cwd=work, timeout=timeout_s)
    for line in reversed(proc.stdout.splitlines()):
        if line.startswith(_RESULT_TAG):
            return {**json.loads(line[len(_RESULT_TAG):]), "threads": n_threads}
    tail = "\n".join((proc.stdout + proc.stderr).splitlines()[-30:])
    raise RuntimeError(f"the PySPH run failed (exit {proc.returncode}):\n{tail}")


def _pysph_worker(cfg: dict) -> None:
    """Runs under an interpreter with PySPH; imports nothing of taichi_mex."""
    from pysph.base.kernels import WendlandQuintic
    from pysph.examples._db_geometry import DamBreak3DGeometry
    from pysph.solver.application import Application
    from pysph.sph.wc.edac import EDACScheme

    dx = float(cfg["dx"])
    steps = int(cfg["steps"])
    h = HDX * dx
    dt = pysph_dt(dx)

    class DamBreak3DEDAC(Application):
        def initialize(self):
            self.geom = DamBreak3DGeometry(dx=dx, nboundary_layers=1, hdx=HDX, rho0=RHO0)

        def create_scheme(self):
            return EDACScheme(fluids=["fluid"], solids=["boundary", "obstacle"], dim=3, c0=C0,
                              nu=0.0, rho0=RHO0, h=h, pb=0.0, gz=-G)

        def configure_scheme(self):
            # tf only bounds the run; --max-steps stops it
            self.scheme.configure_solver(kernel=WendlandQuintic(dim=3), dt=dt,
                                         tf=10 * (steps + 1) * dt, adaptive_timestep=False)

        def create_particles(self):
            particles = self.geom.create_particles()
            self.scheme.setup_properties(particles)
            return particles

    app = DamBreak3DEDAC(fname="dam_break_3d_edac", output_dir=cfg["output_dir"])
    argv = ["--max-steps", str(steps), "--disable-output",
            "--openmp" if cfg["openmp"] else "--no-openmp"]
    t0 = time.perf_counter()
    app.setup(argv)  # code generation and Cython compilation happen here
    setup_s = time.perf_counter() - t0
    busy0 = busy_cpu_s()
    t0 = time.perf_counter()
    cpu0 = time.process_time()
    app.solver.solve(False)  # what Application.solve times as "Run took"
    run_s = time.perf_counter() - t0
    cpu_s = time.process_time() - cpu0
    others = busy_cpu_s() - busy0 - cpu_s
    counts = {pa.name: int(pa.get_number_of_particles()) for pa in app.particles}
    total = sum(counts.values())
    done = int(app.solver.count)
    import numpy as np

    fluid = [pa for pa in app.particles if pa.name == "fluid"][0]
    speed = float(np.sqrt(fluid.u**2 + fluid.v**2 + fluid.w**2).max())
    import pysph

    result = {"code": f"PySPH {pysph.__version__}", "particles": total, **counts, "steps": done,
              "wall_s": run_s, "cpu_s": cpu_s, "particle_steps_per_s": total * done / run_s, "dt_s": dt,
              "setup_s": setup_s, "openmp": bool(cfg["openmp"]), "max_speed_m_s": speed,
              "others_cpu_s": others,
              "finite": bool(np.isfinite(speed))}
    print(_RESULT_TAG + json.dumps(result), flush=True)


# ---------------------------------------------------------------------------- both
def bench_dam_break(steps: int = 100, pysph: bool = True, pysph_runs: str = "both",
                    dx_m: float = DX_M, threads: int | None = None, precision: str = "f32",
                    pysph_python: str | None = None, arch: str = "cpu", echo=print) -> dict:
    """Ours, then PySPH (when it can be imported) with OpenMP and on one core (pysph_runs:
    'both', 'openmp' or 'single'); prints the figures and ours / each of PySPH's."""
    echo(f"dam break 3D (PySPH's DamBreak3DGeometry, dx = {dx_m:g} m, EDAC), {steps} steps")
    ours = bench_ours(steps, dx_m, threads, precision, arch)
    echo(_line(ours))
    echo("  where our step's time goes: "
         + ", ".join(f"{k} {100 * v:.0f} %" for k, v in ours["phase_share"].items()))
    result = {"ours": ours, "pysph": None, "ratio": None}
    if not pysph:
        return result
    python, version = find_pysph_python(pysph_python)
    if python is None:
        echo(f"PySPH is not importable ({version}); only our figure is given. Install it with "
             f"pip install '.[peer]' (a few minutes of Cython build), or point --pysph-python / "
             f"{PYTHON_ENV} at an interpreter that has it.")
        result["pysph_missing"] = version
        return result
    modes = {"both": (True, False), "openmp": (True,), "single": (False,)}[pysph_runs]
    result["pysph"], result["ratio"] = [], {}
    for openmp in modes:
        echo(f"running PySPH {version} ({'OpenMP' if openmp else 'one core'}) under {python} ...")
        peer = bench_pysph(steps, dx_m, openmp, threads, python)
        peer["ratio"] = ours["particle_steps_per_s"] / peer["particle_steps_per_s"]
        echo(_line(peer))
        if peer["particles"] != ours["particles"]:
            echo(f"note: particle counts differ ({ours['particles']:,} ours, {peer['particles']:,} "
                 "PySPH): PySPH's float comparisons put some lattice points on a face differently "
                 "at this dx")
        result["pysph"].append(peer)
        result["ratio"]["openmp" if openmp else "single"] = peer["ratio"]
    echo("ours / PySPH: " + "; ".join(
        f"{'OpenMP, ' + str(r['threads']) + ' threads' if r['openmp'] else 'one core'} {r['ratio']:.1f}x"
        for r in result["pysph"]))
    return result


def _line(r: dict) -> str:
    extra = ""
    if r["code"] == "taichi_mex":
        extra = f"{r['arch']} {r['precision']}, {r['threads']} threads"
    else:
        extra = f"{'OpenMP, ' + str(r['threads']) + ' threads' if r['openmp'] else 'one core'}, f64"
    return (f"  {r['code']:12s} {r['particles']:>9,d} particles x {r['steps']} steps in "
            f"{r['wall_s']:7.2f} s = {r['particle_steps_per_s'] / 1e6:6.3f} M particle-steps/s "
            f"({extra}; {r['cpu_s']:.1f} CPU-s; other processes {r['others_cpu_s']:.1f} CPU-s)")


def parser(prog: str = "python -m taichi_mex bench dam-break",
           parser_class=argparse.ArgumentParser) -> argparse.ArgumentParser:
    """The options; pass cli's parser class to have errors reported as UserInputError."""
    p = parser_class(prog=prog, description=__doc__.split("\n\n")[0])
    p.add_argument("--steps", type=int, default=100, help="timed steps (default 100)")
    p.add_argument("--dx", type=float, default=DX_M, help="particle spacing in m (default 0.02)")
    p.add_argument("--no-pysph", dest="pysph", action="store_false", help="run ours only")
    p.add_argument("--pysph-runs", choices=["both", "openmp", "single"], default="both",
                   help="PySPH with OpenMP on --threads, on one core, or both (default)")
    p.add_argument("--threads", type=int, default=None,
                   help="threads for both codes (default: all cores)")
    p.add_argument("--precision", choices=["f32", "f64"], default="f32",
                   help="our precision (PySPH runs in f64)")
    p.add_argument("--arch", choices=["cpu", "gpu"], default="cpu",
                   help="where ours runs (default cpu, PySPH's figure is a CPU one either way)")
    p.add_argument("--pysph-python", default=None,
                   help=f"interpreter with PySPH (default: this one, then ${PYTHON_ENV})")
    p.add_argument("--json", default=None, help="also write the figures to this file")
    return p


def main(argv: list[str] | None = None, parser_class=argparse.ArgumentParser) -> int:
    from taichi_mex.errors import UserInputError

    args = parser(parser_class=parser_class).parse_args(argv)
    if args.steps < 1 or not args.dx > 0:
        raise UserInputError("--steps must be at least 1 and --dx positive.")
    result = bench_dam_break(args.steps, args.pysph, args.pysph_runs, args.dx, args.threads,
                             args.precision, args.pysph_python, args.arch)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(result, fh, indent=2)
    return 0


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--pysph-worker":
        _pysph_worker(json.loads(sys.argv[2]))
    else:
        print("run: python -m taichi_mex bench dam-break (or taichi_mex.app.peer.main)", file=sys.stderr)
        sys.exit(2)
