"""Side by side with SPlisHSPlasH on the viscous collapse (Huppert 1982): time to solution.

    python -m taichi_mex bench collapse [--spacing-mm MM] [--until S] [--no-splishsplash] [--json FILE]

One command runs both codes on the same case, one after the other on this machine:

* ours: ``python -m taichi_mex scene collapse`` (DFSPH with the implicit viscous solve,
  ``taichi_mex/scenes/collapse.py``) in a subprocess; its wall time is the time loop's as
  ``summary.json`` gives it (``wall_time_s``, Taichi's kernel compilation included), its
  Huppert figures are the scene's own (``front_coefficient_ratio``: K^(1/8) of the late
  fit r^8 = K (t - t0) over Huppert's coefficient);
* SPlisHSPlasH (``pysplishsplash``, the optional ``splishsplash`` extra): DFSPH, the
  implicit viscosity of Weiler et al. 2018 (on the fluid and, with the same coefficient, at
  the boundary: a no-slip plate), Akinci et al. 2012 boundary particles, the cubic spline
  (SPlisHSPlasH's 3D default, support 4 r = 2 dx like ours), particle radius r = spacing / 2.
  It gets exactly our particles: the fluid cylinder and the plate lattice of our scene's plan
  are written as partio (``.pda``) files that its scene file loads, so both codes start from
  the same particles and the same plate. Its run is a subprocess too; the worker there
  imports nothing of ours, records the fluid positions at our scene's sample times, and this
  process computes the front radius and the Huppert fit from them with the scene's own
  ``front_radius`` and ``analyse``.

SPlisHSPlasH steps with a fixed dt (default 1e-4 s: an earlier 3 s run at 0.2 mm was stable
there and unstable with larger steps); ours picks its own steps. Wall time is the time loop
only (ours: compilation included; SPlisHSPlasH: its boundary setup included); CPU s is the
whole subprocess (start-up, imports, compilation), and "other processes" is the CPU time the
rest of the machine used meanwhile (from /proc/stat): the figures are comparable when that
is near zero.

The issue's case is ``--radius-mm 4 --height-mm 4 --viscosity 1 --density 1000
--spacing-mm 0.2 --until 3`` (about 20 min for each code on 2 cores, validation/peer); the default here
is a coarser, shorter one that takes a few minutes for both codes together.

The pysplishsplash 2.19 wheel bundles libGL/libGLX/libOpenGL/libGLdispatch/libGLU copies that
crash (segfault) on import beside the system's Mesa/libglvnd. The worker therefore runs with
the system's copies put in their place without touching site-packages: a temporary folder of
links named like the bundled files (pointing at the system libraries), on LD_LIBRARY_PATH and
preloaded by those names (LD_PRELOAD), so the loader binds the wheel's references to them.
:func:`gl_workaround_env` builds it; ``--print-gl-workaround`` prints the shell lines.
"""

from __future__ import annotations

import argparse
import glob
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: the issue's case (the full one) and the default, shorter case of the command
ISSUE_CASE = {"radius_mm": 4.0, "height_mm": 4.0, "viscosity_pa_s": 1.0, "density_kg_m3": 1000.0,
              "spacing_mm": 0.2, "until_s": 3.0}
DEFAULT_SPACING_MM = 0.4
DEFAULT_UNTIL_S = 0.5
DEFAULT_DT_S = 1e-4
PYTHON_ENV = "TAICHI_MEX_SPLISHSPLASH_PYTHON"
INSTALL_HINT = "pip install '.[splishsplash]' (pysplishsplash 2.19.0, a binary wheel)"
_RESULT_TAG = "SPLISHSPLASH_RESULT "
#: bundled GL libraries of the wheel (pysplishsplash.libs/) and their system sonames
_GL_LIBS = {"libGLdispatch": "libGLdispatch.so.0", "libOpenGL": "libOpenGL.so.0",
            "libGLX": "libGLX.so.0", "libGLU": "libGLU.so.1", "libGL": "libGL.so.1"}


def busy_cpu_s() -> float:
    from taichi_mex.app.peer import busy_cpu_s as busy

    return busy()


def _children_cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


# ---------------------------------------------------------------------------- the case
def collapse_spec(radius_mm: float, height_mm: float, viscosity_pa_s: float, density_kg_m3: float,
                  spacing_mm: float, until_s: float, threads: int | None = None):
    """Our run description of the case (the scene's defaults otherwise)."""
    from taichi_mex.spec import RunSpec

    return RunSpec.create("collapse", changes={
        "scene.radius_mm": radius_mm, "scene.height_mm": height_mm, "scene.until_s": until_s,
        "run.spacing_mm": spacing_mm, "run.cpu_threads": threads,
        "material.viscosity_pa_s": viscosity_pa_s, "material.density_kg_m3": density_kg_m3})


def collapse_case(spec) -> dict:
    """The particles and numbers both codes run: our scene's plan (fluid cylinder, plate
    lattice), its sample times, and SPlisHSPlasH's parameters derived from them."""
    from taichi_mex.core.state import FLUID, PLATE

    scene = spec.build_scene()
    plan = scene.plan(spec.run, spec.material)
    fluid = [b.position_m for b in plan.blocks if b.phase == FLUID][0]
    plate = [b.position_m for b in plan.blocks if b.phase == PLATE][0]
    dx = spec.run.spacing_m
    return {
        "scene": scene, "plan": plan, "fluid_m": fluid, "plate_m": plate,
        "spacing_m": dx, "particle_radius_m": 0.5 * dx, "until_s": float(spec.options.until_s),
        "sample_times_s": [float(t) for t in scene.sample_times],
        "density_kg_m3": float(spec.material.density_kg_m3),
        "nu_m2_s": float(spec.material.viscosity_pa_s / spec.material.density_kg_m3),
        "gravity_m_s2": float(spec.run.gravity_m_s2),
        "plate_lo_m": plate.min(axis=0) - 0.5 * dx, "plate_hi_m": plate.max(axis=0) + 0.5 * dx,
    }


def splishsplash_scene(case: dict, dt_s: float, fluid_file: str = "fluid.pda",
                       plate_file: str = "plate.pda", plate_mesh: str = "plate.obj") -> dict:
    """SPlisHSPlasH's scene file (JSON) for the case. Enum values are SPlisHSPlasH 2.19's
    (simulationMethod 4 DFSPH, boundaryHandlingMethod 0 Akinci 2012, viscosityMethod 6
    Weiler 2018); the worker checks them by name after loading and sets the viscosity
    coefficients itself (the no-GUI start does not apply the material's to the viscosity
    object)."""
    nu = case["nu_m2_s"]
    return {
        "Configuration": {
            "particleRadius": case["particle_radius_m"], "sim2D": False,
            "gravitation": [0.0, 0.0, -case["gravity_m_s2"]],  # z up, as ours
            "simulationMethod": 4, "boundaryHandlingMethod": 0,
            "timeStepSize": dt_s, "cflMethod": 0,  # fixed step: larger ones went unstable
            "stopAt": case["until_s"], "pause": False,
            "enableDivergenceSolver": True,
            "enablePartioExport": False, "enableVTKExport": False, "enableRigidBodyExport": False,
            "enableStateExport": False,
        },
        "Materials": [{"id": "Fluid", "density0": case["density_kg_m3"], "viscosityMethod": 6,
                       "viscosity": nu, "viscosityBoundary": nu}],
        "FluidModels": [{"id": "Fluid", "particleFile": fluid_file}],
        # the plate: our lattice as Akinci boundary particles; the mesh (the plate's box) is
        # only what SPlisHSPlasH's loader wants beside them
        "RigidBodies": [{"geometryFile": plate_mesh, "particleFile": plate_file,
                         "isDynamic": False, "isWall": False}],
    }


def write_pda(path, points) -> None:
    """Partio's ASCII particle format, positions only (SPlisHSPlasH reads it through partio)."""
    with open(path, "w") as fh:
        fh.write(f"ATTRIBUTES\nposition\nTYPES\nV\nNUMBER_OF_PARTICLES: {len(points)}\nBEGIN DATA\n")
        fh.writelines(f"{x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in points)


def write_box_obj(path, lo, hi) -> None:
    """An axis-aligned box as a closed triangle mesh (outward normals)."""
    v = [(x, y, z) for z in (lo[2], hi[2]) for y in (lo[1], hi[1]) for x in (lo[0], hi[0])]
    quads = [(1, 3, 4, 2), (5, 6, 8, 7), (1, 2, 6, 5), (3, 7, 8, 4), (1, 5, 7, 3), (2, 4, 8, 6)]
    lines = [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in v]
    for a, b, c, d in quads:
        lines += [f"f {a} {b} {c}", f"f {a} {c} {d}"]
    Path(path).write_text("\n".join(lines) + "\n")


# ---------------------------------------------------------------------------- GL workaround
def _bundled_libs_dir(python: str) -> str | None:
    """The wheel's pysplishsplash.libs/ of ``python`` (found without importing it)."""
    code = ("import importlib.util, os; s = importlib.util.find_spec('pysplishsplash'); "
            "print(os.path.join(os.path.dirname(s.origin), 'pysplishsplash.libs') if s and s.origin else '')")
    try:
        out = subprocess.run([python, "-c", code], capture_output=True, text=True, timeout=60).stdout.strip()
    except (OSError, subprocess.TimeoutExpired):
        return None
    return out if out and os.path.isdir(out) else None


def _system_lib(soname: str) -> str | None:
    """Path of a system library by soname (ldconfig's cache, then the usual folders)."""
    try:
        cache = subprocess.run(["ldconfig", "-p"], capture_output=True, text=True, timeout=30).stdout
    except (OSError, subprocess.TimeoutExpired):
        cache = ""
    for line in cache.splitlines():  # "\tlibGL.so.1 (libc6,x86-64) => /usr/lib/.../libGL.so.1"
        name, _, path = line.strip().partition(" => ")
        if name.split(" ")[0] == soname and os.path.exists(path.strip()):
            return path.strip()
    for folder in ("/usr/lib/x86_64-linux-gnu", "/usr/lib64", "/lib/x86_64-linux-gnu", "/usr/lib",
                   "/usr/lib/aarch64-linux-gnu"):
        path = os.path.join(folder, soname)
        if os.path.exists(path):
            return path
    return None


def gl_workaround_env(python: str, shim_dir: str) -> tuple[dict, list[str]]:
    """(environment additions, notes): links in ``shim_dir`` named like the wheel's bundled
    GL libraries, pointing at the system's, on LD_LIBRARY_PATH and in LD_PRELOAD by those
    names. Empty when the wheel bundles none or the system lacks them (notes say which)."""
    libs = _bundled_libs_dir(python)
    if libs is None:
        return {}, ["no pysplishsplash.libs folder found"]
    names, notes = [], []
    # libGLdispatch first: the others depend on it
    for path in sorted(glob.glob(os.path.join(libs, "lib*GL*.so*")),
                       key=lambda p: (0 if "GLdispatch" in p else 1, p)):
        bundled = os.path.basename(path)
        stem = bundled.split("-")[0]
        soname = _GL_LIBS.get(stem)
        system = _system_lib(soname) if soname else None
        if system is None:
            notes.append(f"{bundled}: no system {soname or stem} found, the bundled copy stays")
            continue
        link = os.path.join(shim_dir, bundled)
        if not os.path.lexists(link):
            os.symlink(system, link)
        names.append(bundled)
    if not names:
        return {}, notes
    env = {"LD_LIBRARY_PATH": os.pathsep.join(p for p in (shim_dir, os.environ.get("LD_LIBRARY_PATH")) if p),
           "LD_PRELOAD": " ".join(names + ([os.environ["LD_PRELOAD"]] if os.environ.get("LD_PRELOAD") else []))}
    return env, notes


def gl_workaround_shell(python: str, shim_dir: str = "$HOME/.cache/splishsplash-gl") -> str:
    """The workaround as shell lines a user can run by hand."""
    libs = _bundled_libs_dir(python) or "SITE_PACKAGES/pysplishsplash.libs"
    lines = [f"mkdir -p {shim_dir}"]
    names = []
    for path in sorted(glob.glob(os.path.join(libs, "lib*GL*.so*")),
                       key=lambda p: (0 if "GLdispatch" in p else 1, p)):
        bundled = os.path.basename(path)
        soname = _GL_LIBS.get(bundled.split("-")[0])
        system = _system_lib(soname) if soname else None
        if system:
            lines.append(f"ln -sf {system} {shim_dir}/{bundled}")
            names.append(bundled)
    lines.append(f"export LD_LIBRARY_PATH={shim_dir}${{LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}}")
    lines.append(f"export LD_PRELOAD=\"{' '.join(names)}\"")
    return "\n".join(lines)


def find_splishsplash_python(explicit: str | None, shim_dir: str) -> tuple[str | None, str, dict]:
    """(interpreter, pysplishsplash version, worker environment) or (None, why not, {}).
    Each candidate is tried plainly, then, when the plain import dies (the wheel's bundled GL
    libraries), with the system's in their place (:func:`gl_workaround_env`)."""
    candidates = [explicit] if explicit else [sys.executable, os.environ.get(PYTHON_ENV)]
    code = "import importlib.metadata as m, pysplishsplash; print(m.version('pysplishsplash'))"
    reasons = []
    for python in candidates:
        if not python:
            continue
        extra: dict = {}
        for attempt in ("plain", "system GL"):
            if attempt == "system GL":
                extra, notes = gl_workaround_env(python, shim_dir)
                if not extra:
                    reasons.append(f"{python}: importing pysplishsplash died and the GL workaround "
                                   f"cannot be set up ({'; '.join(notes)})")
                    break
            try:
                proc = subprocess.run([python, "-c", code], capture_output=True, text=True, timeout=120,
                                      env={**os.environ, **extra})
            except (OSError, subprocess.TimeoutExpired) as exc:
                reasons.append(f"{python}: {exc}")
                break
            if proc.returncode == 0:
                return python, proc.stdout.strip(), extra
            if "No module named" in proc.stderr:
                reasons.append(f"{python}: pysplishsplash is not installed")
                break
            why = (f"killed by signal {-proc.returncode}" if proc.returncode < 0
                   else (proc.stderr.strip().splitlines() or [f"exit {proc.returncode}"])[-1])
            if attempt == "system GL":
                reasons.append(f"{python}: importing pysplishsplash failed ({why}), also with the system "
                               "GL libraries in place of the wheel's:\n" + gl_workaround_shell(python))
    return None, "; ".join(reasons) or "no interpreter given", {}


# ---------------------------------------------------------------------------- ours
def run_ours(case_args: dict, threads: int | None, timeout_s: float, echo=print) -> dict:
    """``scene collapse`` in a subprocess; its summary.json's figures."""
    with tempfile.TemporaryDirectory(prefix="collapse_ours_") as out:
        cmd = [sys.executable, "-m", "taichi_mex", "scene", "collapse",
               "--radius-mm", str(case_args["radius_mm"]), "--height-mm", str(case_args["height_mm"]),
               "--viscosity", str(case_args["viscosity_pa_s"]), "--density", str(case_args["density_kg_m3"]),
               "--spacing-mm", str(case_args["spacing_mm"]), "--until", str(case_args["until_s"]),
               "--no-snapshots", "--quiet", "--out", out]
        if threads:
            cmd += ["--threads", str(threads)]
        echo("  " + " ".join(["python", *("TMP" if a == out else a for a in cmd[1:])]))
        busy0, cpu0, wall0 = busy_cpu_s(), _children_cpu_s(), time.perf_counter()
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
            rc, text = proc.returncode, proc.stdout + proc.stderr
        except subprocess.TimeoutExpired as exc:
            rc, text = None, f"stopped after {timeout_s:g} s ({exc})"
        process_wall = time.perf_counter() - wall0
        cpu = _children_cpu_s() - cpu0
        others = busy_cpu_s() - busy0 - cpu
        path = Path(out) / "summary.json"
        s = json.loads(path.read_text()) if path.exists() else {}
    r = {"code": "taichi_mex", "particles": s.get("particles_active"),
         "fluid_particles": (s.get("particles_by_phase") or {}).get("fluid"),
         "steps": s.get("steps"), "wall_s": s.get("wall_time_s"), "process_wall_s": process_wall,
         "cpu_s": cpu, "others_cpu_s": others, "simulated_s": s.get("simulated_time_s"),
         "until_s": case_args["until_s"], "scheme": s.get("scheme"),
         "huppert_coefficient_ratio": s.get("front_coefficient_ratio"),
         "huppert_radius_ratio_late": s.get("front_ratio_late"),
         "growth_exponent_late": s.get("front_exponent_late"),
         "front_r_end_m": (s.get("front_r_m") or [None])[-1], "exit_code": rc,
         "stokes_iterations_per_step": s.get("stokes_iterations_per_step"),
         "stokes_inner_iterations_per_step": s.get("stokes_inner_iterations_per_step"),
         "stokes_inner_operator_solves": s.get("stokes_inner_operator_solves")}
    if isinstance(s.get("error"), str):  # a run that stopped (blow-up, unconverged solve)
        r["stopped"] = s["error"]
    elif rc != 0 or not s:
        lines = [ln for ln in text.splitlines() if ln.strip()]
        errors = [ln for ln in lines if ln.startswith("error")]
        r["stopped"] = (errors or lines or [f"exit code {rc}"])[-1]
    return r


# ---------------------------------------------------------------------------- SPlisHSPlasH
class _Positions:
    """The bits of a Simulation that CollapseScene.front_radius and analyse read."""

    def __init__(self, spec, plan, x, t):
        self.run_opts, self.material, self.plan = spec.run, spec.material, plan
        self.time_s = t
        self._x = x
        self.state = self

    def numpy(self, name, phase=None):
        assert name == "position"
        return self._x


def huppert_from_samples(spec, case: dict, times, positions) -> dict:
    """The scene's own front radius and Huppert fit on positions sampled at ``times``."""
    scene, plan = case["scene"], case["plan"]
    scene.front = []
    for t, x in zip(times, positions):
        scene.front.append((float(t), scene.front_radius(_Positions(spec, plan, x, t))))
    return scene.analyse(_Positions(spec, plan, positions[-1], float(times[-1])))


def run_splishsplash(spec, case: dict, python: str, env_extra: dict, dt_s: float,
                     threads: int | None, timeout_s: float, echo=print) -> dict:
    """SPlisHSPlasH on the case in a worker subprocess; our Huppert figures from its positions."""
    import numpy as np

    n_threads = threads or os.cpu_count() or 1
    with tempfile.TemporaryDirectory(prefix="collapse_splishsplash_") as work:
        write_pda(os.path.join(work, "fluid.pda"), case["fluid_m"])
        write_pda(os.path.join(work, "plate.pda"), case["plate_m"])
        write_box_obj(os.path.join(work, "plate.obj"), case["plate_lo_m"], case["plate_hi_m"])
        scene_file = os.path.join(work, "collapse.json")
        Path(scene_file).write_text(json.dumps(splishsplash_scene(case, dt_s), indent=1))
        cfg = {"scene_file": scene_file, "output_dir": os.path.join(work, "out"),
               "until_s": case["until_s"], "dt_s": dt_s, "nu_m2_s": case["nu_m2_s"],
               "sample_times_s": case["sample_times_s"], "samples_file": os.path.join(work, "samples.npz"),
               "expected_fluid": int(len(case["fluid_m"])), "expected_boundary": int(len(case["plate_m"]))}
        env = {**os.environ, **env_extra, "OMP_NUM_THREADS": str(n_threads)}
        busy0, cpu0, wall0 = busy_cpu_s(), _children_cpu_s(), time.perf_counter()
        try:
            proc = subprocess.run([python, os.path.abspath(__file__), "--splishsplash-worker", json.dumps(cfg)],
                                  capture_output=True, text=True, env=env, cwd=work, timeout=timeout_s)
            rc, out = proc.returncode, proc.stdout + proc.stderr
        except subprocess.TimeoutExpired as exc:
            rc, out = None, exc.stdout.decode(errors="replace") if isinstance(exc.stdout, bytes) else (exc.stdout or "")
        process_wall = time.perf_counter() - wall0
        cpu = _children_cpu_s() - cpu0
        others = busy_cpu_s() - busy0 - cpu
        result = None
        for line in reversed(out.splitlines()):
            if line.startswith(_RESULT_TAG):
                result = json.loads(line[len(_RESULT_TAG):])
                break
        samples = None
        if os.path.exists(cfg["samples_file"]):
            with np.load(cfg["samples_file"]) as z:
                samples = (z["t"], [z[f"x{k}"] for k in range(len(z["t"]))])
    if result is None:
        tail = " / ".join(ln.strip() for ln in out.splitlines()[-6:] if ln.strip())
        why = (f"stopped after its time limit of {timeout_s:g} s" if rc is None else
               f"crashed (signal {-rc})" if rc < 0 else f"failed (exit {rc})")
        return {"code": "SPlisHSPlasH", "particles": len(case["fluid_m"]) + len(case["plate_m"]),
                "fluid_particles": len(case["fluid_m"]), "steps": None, "wall_s": None,
                "until_s": case["until_s"],
                "process_wall_s": process_wall, "cpu_s": cpu, "others_cpu_s": others,
                "threads": n_threads, "stopped": f"the SPlisHSPlasH run {why}: {tail}"}
    r = {**result, "process_wall_s": process_wall, "cpu_s": cpu, "others_cpu_s": others,
         "threads": n_threads}
    if samples is not None and len(samples[0]):
        h = huppert_from_samples(spec, case, *samples)
        r.update(huppert_coefficient_ratio=h["front_coefficient_ratio"],
                 huppert_radius_ratio_late=h["front_ratio_late"],
                 growth_exponent_late=h["front_exponent_late"], front_r_end_m=h["front_r_m"][-1])
    if not result.get("finite", True):
        r["stopped"] = f"SPlisHSPlasH's particles left the finite range at t = {result.get('simulated_s'):g} s"
    return r


def _splishsplash_worker(cfg: dict) -> None:
    """Runs under an interpreter with pysplishsplash; imports nothing of taichi_mex."""
    import importlib.metadata

    import numpy as np
    import pysplishsplash as sph

    base = sph.Exec.SimulatorBase()
    until = float(cfg["until_s"])
    dt = float(cfg["dt_s"])
    # stop half a step early: SPlisHSPlasH stops once the time passes stopAt
    base.init(sceneFile=cfg["scene_file"], programName="taichi_mex bench collapse", useCache=False,
              outputDir=cfg["output_dir"], initialPause=False, useGui=False, stopAt=until - 0.5 * dt)
    base.initSimulation()
    sim = sph.Simulation.getCurrent()
    fm = sim.getFluidModel(0)
    # check what the scene file selected by name, and set the viscosity coefficients (the
    # no-GUI start leaves the viscosity object's at its defaults)
    names = {"viscosity": {e.id: e.name for e in fm.getEnumValues(fm.VISCOSITY_METHOD)}[fm.getViscosityMethod()],
             "boundary": str(sim.getBoundaryHandlingMethod()), "method": int(sim.getSimulationMethod())}
    if "Weiler" not in names["viscosity"] or "Akinci" not in names["boundary"] or names["method"] != 4:
        raise SystemExit(f"unexpected SPlisHSPlasH setup: {names}")
    visco = fm.getViscosityBase()
    visco.setValueFloat(visco.VISCOSITY_COEFFICIENT, float(cfg["nu_m2_s"]))
    visco.setValueFloat(visco.VISCOSITY_COEFFICIENT_BOUNDARY, float(cfg["nu_m2_s"]))
    tm = sph.TimeManager.getCurrent()
    n = fm.numActiveParticles()
    if n != cfg["expected_fluid"]:
        raise SystemExit(f"SPlisHSPlasH loaded {n} fluid particles, expected {cfg['expected_fluid']}")

    def positions():
        return np.frombuffer(fm.getFieldBuffer("position"), dtype=np.float32).reshape(-1, 3)[:n].copy()

    sample_times = list(cfg["sample_times_s"])
    times, xs = [], []
    state = {"steps": 0, "next": 0, "bad": False}

    def after_step():  # SPlisHSPlasH calls this after each step
        state["steps"] += 1
        t = tm.getTime()
        crossed = False
        while state["next"] < len(sample_times) and t >= sample_times[state["next"]] - 1e-12:
            state["next"] += 1
            crossed = True
        if crossed:
            x = positions()
            times.append(t)
            xs.append(x)
            if not np.isfinite(x).all() or np.abs(x).max() > 1.0:  # blown up: stop there
                state["bad"] = True
                base.setValueFloat(base.STOP_AT, t * 0.5)

    base.setTimeStepCB(after_step)
    t0 = time.perf_counter()
    cpu0 = time.process_time()
    base.runSimulation()  # the boundary setup (deferred init), then the steps to stopAt
    wall = time.perf_counter() - t0
    cpu = time.process_time() - cpu0
    t_end = tm.getTime()
    if not times or times[-1] < t_end - 1e-12:
        times.append(t_end)
        xs.append(positions())
    np.savez(cfg["samples_file"], t=np.array(times), **{f"x{k}": x for k, x in enumerate(xs)})
    n_boundary = sum(sim.getBoundaryModel(i).numberOfParticles() for i in range(sim.numberOfBoundaryModels()))
    result = {"code": f"SPlisHSPlasH {importlib.metadata.version('pysplishsplash')}",
              "particles": int(n + n_boundary), "fluid_particles": int(n), "boundary_particles": int(n_boundary),
              "steps": state["steps"], "wall_s": wall, "worker_cpu_s": cpu, "simulated_s": t_end,
              "until_s": until, "dt_s": dt, "finite": not state["bad"],
              "viscosity_method": names["viscosity"], "boundary_method": names["boundary"],
              "viscosity_coefficient": visco.getValueFloat(visco.VISCOSITY_COEFFICIENT),
              "viscosity_coefficient_boundary": visco.getValueFloat(visco.VISCOSITY_COEFFICIENT_BOUNDARY)}
    print(_RESULT_TAG + json.dumps(result), flush=True)


# ---------------------------------------------------------------------------- both
def bench_collapse(radius_mm: float = 4.0, height_mm: float = 4.0, viscosity_pa_s: float = 1.0,
                   density_kg_m3: float = 1000.0, spacing_mm: float = DEFAULT_SPACING_MM,
                   until_s: float = DEFAULT_UNTIL_S, splishsplash: bool = True, dt_s: float = DEFAULT_DT_S,
                   threads: int | None = None, splishsplash_python: str | None = None,
                   timeout_s: float = 3 * 3600.0, echo=print) -> dict:
    """Ours, then SPlisHSPlasH when it can be imported; prints the table."""
    case_args = {"radius_mm": radius_mm, "height_mm": height_mm, "viscosity_pa_s": viscosity_pa_s,
                 "density_kg_m3": density_kg_m3, "spacing_mm": spacing_mm, "until_s": until_s}
    spec = collapse_spec(**case_args, threads=threads)
    case = collapse_case(spec)
    echo(f"viscous collapse: R {radius_mm:g} mm, H {height_mm:g} mm, {viscosity_pa_s:g} Pa s, "
         f"{density_kg_m3:g} kg/m^3, spacing {spacing_mm:g} mm, to t = {until_s:g} s "
         f"({len(case['fluid_m']):,} fluid + {len(case['plate_m']):,} plate particles)")
    echo("running ours ...")
    ours = run_ours(case_args, threads, timeout_s, echo)
    ours["threads"] = threads or os.cpu_count()
    result = {"case": case_args, "ours": ours, "splishsplash": None, "ratio": None}
    if splishsplash:
        with tempfile.TemporaryDirectory(prefix="splishsplash_gl_") as shim:
            python, version, env_extra = find_splishsplash_python(splishsplash_python, shim)
            if python is None:
                result["splishsplash_missing"] = version
            else:
                echo(f"running SPlisHSPlasH {version} (DFSPH, Weiler 2018, Akinci 2012, dt {dt_s:g} s) "
                     f"under {python}" + (" with the system GL libraries" if env_extra else "") + " ...")
                peer = run_splishsplash(spec, case, python, env_extra, dt_s, threads, timeout_s, echo)
                result["splishsplash"] = peer
                if ours.get("wall_s") and peer.get("wall_s") and "stopped" not in ours and "stopped" not in peer:
                    result["ratio"] = peer["wall_s"] / ours["wall_s"]
                    peer["ratio"] = result["ratio"]
    print_table(result, echo)
    if result.get("splishsplash_missing"):
        echo(f"SPlisHSPlasH is not importable ({result['splishsplash_missing']}); only our figures are "
             f"given. Install it with {INSTALL_HINT}, or point --splishsplash-python / {PYTHON_ENV} at "
             "an interpreter that has it.")
    return result


def _fmt(v, f="{:.3f}"):
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f.format(v)


def print_table(result: dict, echo=print) -> None:
    rows = [result["ours"]] + ([result["splishsplash"]] if result.get("splishsplash") else [])
    echo(f"{'code':22s} {'particles':>10s} {'steps':>7s} {'wall s':>8s} {'CPU s':>8s} {'others CPU s':>12s} "
         f"{'Huppert K^1/8':>13s} {'r/r_H late':>10s} {'SPlisHSPlasH/ours time':>22s}")
    for r in rows:
        ratio = _fmt(r.get("ratio"), "{:.1f}x") if r is not result["ours"] else ""
        echo(f"{r['code'] + (' (stopped)' if 'stopped' in r else ''):22s} {_fmt(r.get('particles'), '{:,d}'):>10s} "
             f"{_fmt(r.get('steps'), '{:d}'):>7s} {_fmt(r.get('wall_s'), '{:.1f}'):>8s} {_fmt(r.get('cpu_s'), '{:.1f}'):>8s} "
             f"{_fmt(r.get('others_cpu_s'), '{:.1f}'):>12s} {_fmt(r.get('huppert_coefficient_ratio')):>13s} "
             f"{_fmt(r.get('huppert_radius_ratio_late')):>10s} {ratio:>22s}")
    for r in rows:
        if "stopped" in r:
            echo(f"{r['code']} stopped at t = {_fmt(r.get('simulated_s'), '{:g}')} s of {r.get('until_s', '?')}: "
                 f"{r['stopped']}")
    for r in rows:
        # a neighbour holding a core slows OpenMP's loops (each waits for its slowest thread)
        # far more than the core it takes: such a row is not a comparable figure
        wall = r.get("process_wall_s") or 0.0
        if wall and r.get("others_cpu_s", 0.0) > max(1.0, 0.1 * wall):
            echo(f"note: other processes used {r['others_cpu_s']:.0f} CPU-s during {r['code']}'s "
                 f"{wall:.0f} s: its time is not a quiet machine's")
    ours = result["ours"]
    h = ours.get("huppert_coefficient_ratio")
    if result.get("ratio"):
        echo(f"ours is {result['ratio']:.1f}x faster (target >= 5x); our Huppert coefficient ratio "
             f"{_fmt(h)} (target within 5 % of 1)")
    echo("wall s: the time loop (ours with Taichi's compilation); CPU s: the whole subprocess; "
         "Huppert: K^(1/8) of r^8 = K (t - t0) over the second half, over Huppert's coefficient "
         "(a short run's current is still thick: read it as a check, not as Huppert's law)")


def parser(prog: str = "python -m taichi_mex bench collapse",
           parser_class=argparse.ArgumentParser) -> argparse.ArgumentParser:
    p = parser_class(prog=prog, description=__doc__.split("\n\n")[0],
                     epilog="The issue's full case (about 20 min for each code on 2 cores): "
                            "--spacing-mm 0.2 --until 3")
    p.add_argument("--radius-mm", type=float, default=4.0, help="cylinder radius in mm (default 4)")
    p.add_argument("--height-mm", type=float, default=4.0, help="cylinder height in mm (default 4)")
    p.add_argument("--viscosity", type=float, default=1.0, help="dynamic viscosity in Pa s (default 1)")
    p.add_argument("--density", type=float, default=1000.0, help="density in kg/m^3 (default 1000)")
    p.add_argument("--spacing-mm", type=float, default=DEFAULT_SPACING_MM,
                   help=f"particle spacing in mm, SPlisHSPlasH's radius is half (default {DEFAULT_SPACING_MM:g})")
    p.add_argument("--until", type=float, default=DEFAULT_UNTIL_S,
                   help=f"simulated time in s (default {DEFAULT_UNTIL_S:g}; the issue's case: 3)")
    p.add_argument("--splishsplash-dt", type=float, default=DEFAULT_DT_S,
                   help=f"SPlisHSPlasH's fixed time step in s (default {DEFAULT_DT_S:g})")
    p.add_argument("--no-splishsplash", dest="splishsplash", action="store_false", help="run ours only")
    p.add_argument("--threads", type=int, default=None, help="threads for both codes (default: all cores)")
    p.add_argument("--splishsplash-python", default=None,
                   help=f"interpreter with pysplishsplash (default: this one, then ${PYTHON_ENV})")
    p.add_argument("--timeout", type=float, default=3 * 3600.0,
                   help="wall-clock limit per code in s (default 10800)")
    p.add_argument("--print-gl-workaround", action="store_true",
                   help="print the shell lines that put the system's GL libraries in place of the "
                        "wheel's for a manual run, and exit")
    p.add_argument("--json", default=None, help="also write the figures to this file")
    return p


def main(argv: list[str] | None = None, parser_class=argparse.ArgumentParser) -> int:
    from taichi_mex.errors import UserInputError

    args = parser(parser_class=parser_class).parse_args(argv)
    if args.print_gl_workaround:
        print(gl_workaround_shell(args.splishsplash_python or sys.executable))
        return 0
    for name in ("radius_mm", "height_mm", "viscosity", "density", "spacing_mm", "until",
                 "splishsplash_dt", "timeout"):
        if not getattr(args, name) > 0:
            raise UserInputError(f"--{name.replace('_', '-')} must be positive.")
    if args.threads is not None and args.threads < 1:
        raise UserInputError("--threads must be at least 1.")
    result = bench_collapse(args.radius_mm, args.height_mm, args.viscosity, args.density,
                            args.spacing_mm, args.until, args.splishsplash, args.splishsplash_dt,
                            args.threads, args.splishsplash_python, args.timeout)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(result, fh, indent=2, default=float)
    return 0


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--splishsplash-worker":
        _splishsplash_worker(json.loads(sys.argv[2]))
    else:
        print("run: python -m taichi_mex bench collapse (or taichi_mex.app.peer_splishsplash.main)",
              file=sys.stderr)
        sys.exit(2)
