"""One run of a parameter study, described by a flat parameter dict; no Dask needed.

    from taichi_mex.app.jobs import run_print_job
    record = run_print_job({"gcode": "paper_bead", "preset": "paper", "spacing_mm": 0.12,
                            "deposit_for_s": 0.005, "viscosity": 0.2}, "runs/a")
    record["status"], record["metrics"]["bead_width_mm"]

:data:`PARAMETERS` lists the names a study may use (``python -m taichi_mex sweep
--list-params`` prints them); options of :class:`~taichi_mex.options.RunOptions` and
:class:`~taichi_mex.options.Material` not named there are reached as ``run.FIELD``,
``run.edac.FIELD``, ``material.FIELD`` and so on. A run folder gets ``params.json``,
the simulation's own outputs (``particles.h5``, ``snapshots/``, ``summary.json``),
``mesostructure.json`` when :mod:`taichi_mex.post.analysis` is available, and last
``job.json``: status, error message and the key metrics. ``job.json`` with status
``done`` is what marks a run finished.

Taichi keeps global state per process, so a study runs each job in a fresh Python process
(:func:`run_job_isolated`, which calls ``python -m taichi_mex.app.jobs RUN_DIR``); a crash or a
runaway run then costs that job, never the worker that launched it.
"""

from __future__ import annotations

import contextlib
import difflib
import json
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

from taichi_mex import bundled
from taichi_mex.errors import SimulationDiverged, UserInputError
from taichi_mex.post.output import read_json
from taichi_mex.spec import RunSpec, dotted_name, scene_entry, spec_fields

# --------------------------------------------------------------------------- parameters
_NUM = (int, float)


@dataclass(frozen=True)
class Param:
    help: str
    types: tuple
    group: str


#: what a job does besides the run description: which scene, G-code rewrites and generation,
#: when to stop relative to the deposition, the analysis. Every other parameter is an option
#: of the run description (taichi_mex.spec), by its flat name or dotted path.
JOB_PARAMETERS: dict[str, Param] = {
    "scene": Param("a built-in scene instead of a print ('python -m taichi_mex scene --help'); "
                   "its own options as scene.OPTION, e.g. scene.radius_mm", (str,), "print"),
    "preset": Param("named parameter set from options.PRESETS (e.g. 'paper')", (str,), "run"),
    "material": Param("a shipped material (pla, abs, petg) or a TOML file (relative to the "
                      "study file) with Material's fields", (str,), "material"),
    "deposit_for_s": Param("stop this long (s) after the selected deposition starts (instead of "
                           "'until'; follows the start when the speed changes)", _NUM, "print"),
    "feed_rate_factor": Param("multiply every feed rate F of the G-code (nozzle speed; the "
                              "printer's limits still apply)", _NUM, "gcode"),
    "flow_factor": Param("multiply every extrusion E of the G-code (over/under-extrusion)", _NUM,
                         "gcode"),
    "pattern": Param("generate the G-code: 'bead' (one bead) or 'block' (block_layers x "
                     "block_beads parallel beads); default 'bead' when a parameter below is set",
                     (str,), "generate"),
    "layer_height_mm": Param("generated G-code: layer height (mm, default 0.2)", _NUM, "generate"),
    "line_width_mm": Param("generated G-code: extrusion width (mm, default 0.45)", _NUM, "generate"),
    "speed_mm_s": Param("generated G-code: printing speed (mm/s, default 60)", _NUM, "generate"),
    "bead_length_mm": Param("generated G-code: bead length (mm, default 3)", _NUM, "generate"),
    "block_beads": Param("generated block: beads per layer (default 3)", (int,), "generate"),
    "block_layers": Param("generated block: layers (default 3)", (int,), "generate"),
    "analysis": Param("take bead metrics from mesostructure.json, running the analysis "
                      "when the scene did not (default true)", (bool,), "run"),
}
_GENERATE_DEFAULTS = {"pattern": "bead", "layer_height_mm": 0.2, "line_width_mm": 0.45,
                      "speed_mm_s": 60.0, "bead_length_mm": 3.0, "block_beads": 3,
                      "block_layers": 3}
_PRINT_ONLY = ("deposit_for_s", "feed_rate_factor", "flow_factor", *_GENERATE_DEFAULTS)


def parameters() -> dict[str, Param]:
    """The flat names a study may use: the job's own, then every option's declared names."""
    out = dict(JOB_PARAMETERS)
    groups = {"scene.": "print", "run.thermal.": "heat", "run.": "run", "material.": "material"}
    for path, f in spec_fields("print"):
        for name in f.metadata.get("names", ()):
            group = next(g for prefix, g in groups.items() if path.startswith(prefix))
            out.setdefault(name, Param(f"{f.metadata['help']} [{path}]", (), group))
    return out


def describe_parameters() -> str:
    groups = {"print": "what is printed", "gcode": "G-code rewrites",
              "generate": "generated G-code", "run": "discretisation and solver",
              "material": "melt", "heat": "heat (any of these switches heat on)"}
    lines = []
    table = parameters()
    for group, title in groups.items():
        lines.append(f"{title}:")
        for name, p in table.items():
            if p.group == group:
                lines.append(f"  {name:30s} {p.help}")
    lines.append("any other option: run.FIELD, run.edac.FIELD, run.dfsph.FIELD, run.thermal.FIELD, "
                 "material.FIELD (see taichi_mex/options.py), scene.OPTION for a scene's own options")
    return "\n".join(lines)


def check_names(params: dict) -> None:
    """Refuse unknown parameter names (UserInputError naming each, with a suggestion)."""
    scene = params.get("scene", "print")
    if not isinstance(scene, str):
        raise UserInputError(f"Parameter scene = {scene!r} should be a scene name.")
    scene_entry(scene)
    problems = []
    for name in params:
        if name in JOB_PARAMETERS or dotted_name(name, scene) is not None:
            continue
        problems.append(_name_problem(name, scene))
    if problems:
        raise UserInputError("Unknown parameter " + "; ".join(problems) + ". 'python -m "
                             "taichi_mex sweep --list-params' lists the names.")


def _name_problem(name: str, scene: str) -> str:
    prefix, _, rest = name.partition(".")
    if prefix in ("run", "material", "scene") and rest:
        paths = [p for p, _ in spec_fields(scene)]
        groups = {p.rsplit(".", 1)[0] for p in paths if p.count(".") > 1}
        if name in groups:
            return f"'{name}': {name} is a group of options; name one of its fields"
        parent = name.rsplit(".", 1)[0]
        siblings = [p for p in paths if p.rsplit(".", 1)[0] == parent]
        close = difflib.get_close_matches(name, siblings, 1, cutoff=0.5)
        return (f"'{name}': no such option" + (f" (did you mean {close[0]}?)" if close else "")
                + (f"; {parent} has {', '.join(s.rsplit('.', 1)[1] for s in siblings)}"
                   if siblings else ""))
    names = list(JOB_PARAMETERS) + [n for _, f in spec_fields(scene) for n in f.metadata.get("names", ())]
    close = difflib.get_close_matches(name, names, 1)
    return f"'{name}'" + (f" (did you mean '{close[0]}'?)" if close else "")


# --------------------------------------------------------------------------- resolving
@dataclass
class Resolved:
    """A parameter dict turned into a run description and the job's own steps, before any
    file is written or planned."""

    params: dict
    spec: RunSpec
    #: generated G-code parameters (None: the description's G-code file)
    generate: dict | None = None
    feed_rate_factor: float = 1.0
    flow_factor: float = 1.0
    deposit_for_s: float | None = None
    analysis: bool = True


def _check_job_types(params: dict) -> None:
    for name, value in params.items():
        p = JOB_PARAMETERS.get(name)
        if p is None:
            continue
        ok = isinstance(value, p.types) and not (isinstance(value, bool) and bool not in p.types)
        if isinstance(value, float) and not math.isfinite(value):
            ok = False
        if not ok:
            words = {"int": "a whole number" if float not in p.types else "a number",
                     "float": "a number", "str": "text", "bool": "true or false"}
            kinds = " or ".join(dict.fromkeys(words[t.__name__] for t in p.types))
            raise UserInputError(f"Parameter {name} = {value!r} should be {kinds}.")
        if p.types == _NUM and not value > 0:
            raise UserInputError(f"Parameter {name} must be positive, got {value!r}.")


def _heat_switches(scene: str) -> set:
    """Flat names and paths of options that switch heat on."""
    out = set()
    for path, f in spec_fields(scene):
        if f.metadata.get("implies", {}).get("run.thermal.enabled"):
            out.add(path)
            out.update(f.metadata.get("names", ()))
    return out


def resolve(params: dict, base_dir=None) -> Resolved:
    """The run description and the job's own steps for one run; refuses unknown names and bad
    values with UserInputError (nothing is written, nothing is planned)."""
    check_names(params)
    _check_job_types(params)
    scene = params.get("scene", "print")
    paths = {name: dotted_name(name, scene) for name in params if name not in JOB_PARAMETERS}
    given = {}
    for name, path in paths.items():
        if path in given:
            raise UserInputError(f"Give either {given[path]} or {name}, not both (both set {path}).")
        given[path] = name
    if "until" in params and "deposit_for_s" in params:
        raise UserInputError("Give either until (a print time) or deposit_for_s (time after the "
                             "deposition starts), not both.")
    heat = sorted(n for n in params if n in _heat_switches(scene))
    if heat and params.get("thermal", params.get("run.thermal.enabled")) is False:
        raise UserInputError(f"{', '.join(heat)} need heat, but the run sets thermal = false.")
    if scene != "print":
        for name in _PRINT_ONLY:
            if name in params:
                raise UserInputError(f"{name} applies to prints; scene '{scene}' takes "
                                     f"scene.OPTION instead (e.g. scene.until).")
    changes = {paths[n]: v for n, v in params.items() if n not in JOB_PARAMETERS}
    generate = {k: params[k] for k in _GENERATE_DEFAULTS if k in params}
    if scene == "print":
        if generate and "scene.gcode" in changes:
            raise UserInputError(f"{', '.join(generate)} describe a generated G-code; drop them or "
                                 f"drop gcode = {params.get('gcode')!r}.")
        if "scene.gcode" in changes:
            changes["scene.gcode"] = str(bundled.resolve_gcode(changes["scene.gcode"], base_dir))
        if "scene.printer" in changes:
            changes["scene.printer"] = _printer_path(changes["scene.printer"], base_dir)
    changes.setdefault("run.progress", False)
    material = params.get("material")
    if material is not None and str(material).lower().endswith(".toml") and base_dir is not None \
            and not Path(material).is_absolute():
        material = str(Path(base_dir) / material)
    spec = RunSpec.create(scene, params.get("preset"), changes, material=material)
    res = Resolved(params=params, spec=spec, analysis=params.get("analysis", True),
                   feed_rate_factor=float(params.get("feed_rate_factor", 1.0)),
                   flow_factor=float(params.get("flow_factor", 1.0)),
                   deposit_for_s=float(params["deposit_for_s"]) if "deposit_for_s" in params else None)
    if generate:
        from taichi_mex.toolpath.generate import check_pattern

        res.generate = {**_GENERATE_DEFAULTS, **generate}
        check_pattern(**_pattern_kwargs(res.generate, spec.options.printer))
    return res


def _printer_path(spec: str, base_dir) -> str:
    """A printer YAML given relative to the study file, made absolute; names stay names."""
    path, sep, name = spec.partition(".yaml")
    if not sep or base_dir is None or Path(path).is_absolute():
        return spec
    return str(Path(base_dir) / path) + sep + name


def _pattern_kwargs(gen: dict, printer: str) -> dict:
    beads = gen["block_beads"] if gen["pattern"] == "block" else 1
    layers = gen["block_layers"] if gen["pattern"] == "block" else 1
    return dict(pattern=gen["pattern"], layer_height_mm=gen["layer_height_mm"],
                line_width_mm=gen["line_width_mm"], speed_mm_s=gen["speed_mm_s"],
                bead_length_mm=gen["bead_length_mm"], beads=beads, layers=layers, printer=printer)


# --------------------------------------------------------------------------- building
@dataclass
class Job:
    spec: RunSpec
    notes: dict = field(default_factory=dict)


def build_job(res: Resolved, out_dir) -> Job:
    """Write the run's G-code (generated or rewritten) into ``out_dir`` and complete the run
    description with it (and with the stop time that deposit_for_s asks for)."""
    spec = res.spec
    if spec.scene != "print":
        return Job(spec, notes={"scene": spec.scene})
    from taichi_mex.toolpath.generate import write_pattern, write_scaled
    from taichi_mex.toolpath.plan import make_plan
    from taichi_mex.toolpath.trajectory import parse_layers, parse_region

    out_dir = Path(out_dir)
    notes: dict = {}
    o = spec.options
    if res.generate is not None:
        gcode = write_pattern(out_dir / "input.gcode", **_pattern_kwargs(res.generate, o.printer))
        notes["gcode_source"] = f"generated ({res.generate['pattern']})"
    else:
        gcode = bundled.resolve_gcode(o.gcode)
        notes["gcode_source"] = str(gcode)
    if res.feed_rate_factor != 1.0 or res.flow_factor != 1.0:
        gcode = write_scaled(gcode, out_dir / "input_scaled.gcode", res.feed_rate_factor,
                             res.flow_factor)
    changes = {"scene.gcode": str(Path(gcode).resolve())}
    if res.deposit_for_s is not None:
        plan = make_plan(gcode, o.printer, layers=parse_layers(o.layers),
                         region_mm=parse_region(o.region), plan_whole_file=False)
        changes["scene.until_s"] = plan.selection.t_start_s + res.deposit_for_s
        notes["deposition_start_s"] = plan.selection.t_start_s
    return Job(spec.with_changes(changes), notes=notes)


# --------------------------------------------------------------------------- metrics
#: columns of the results table besides the parameters: name -> meaning
METRICS = {
    "bead_width_mm": "mean bead width over the sections of the melt's middle half "
                     "(mesostructure.json along_middle; the default section where absent)",
    "bead_height_mm": "mean bead height over the same sections",
    "bead_area_mm2": "mean bead cross-section area over the same sections",
    "beads_count": "beads cut by the default cross-section",
    "neck_side_mm": "mean neck width between side-by-side beads",
    "neck_layer_mm": "mean neck width between stacked beads",
    "void_fraction": "void area / (melt + void) area, mean over the same sections",
    "voids_count": "enclosed voids in the default cross-section",
    "density_error_mean": "mean |rho/rho0 - 1| of interior melt at the end",
    "density_error_max": "largest |rho/rho0 - 1| of interior melt at the end",
    "paired_fraction": "melt with a melt neighbour closer than half a spacing (SPH pairing)",
    "deposited_volume_mm3": "melt volume in the domain at the end (solid blocks the run starts with, such as a window's substrate, not counted)",
    "commanded_volume_mm3": "volume the G-code commanded by the end",
    "cooling_time_s": "time until the slowest bead was all below the glass transition (heat on; "
                      "empty without heat or while a bead is still above it)",
    "max_nozzle_speed_mm_s": "fastest nozzle speed in the simulated window (after the printer's limits)",
    "particles": "active particles at the end",
    "steps": "time steps",
    "simulated_time_s": "simulated time",
    "sim_wall_time_s": "wall time of the time loop (compilation included)",
    "wall_time_s": "wall time of the whole job: setup, simulation, outputs, analysis",
}


def _number(value):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value) if math.isfinite(value) else None


def mesostructure_metrics(meso: dict | None) -> dict:
    """Bead width/height/area and void fraction over the bead's middle (mean of the sections
    there) where measured, else of the default (first) cross-section; necks and counts of
    the default section."""
    if not isinstance(meso, dict):
        return {}
    from taichi_mex.post.analysis import headline_section

    sec = headline_section(meso)
    pick = {"bead_width_mm": ("mean_width_mm", "bead_width_mm", "width_mm"),
            "bead_height_mm": ("mean_height_mm", "bead_height_mm", "height_mm"),
            "bead_area_mm2": ("mean_area_mm2", "bead_area_mm2", "area_mm2"),
            "beads_count": ("beads_count",),
            "neck_side_mm": ("mean_neck_side_mm",),
            "neck_layer_mm": ("mean_neck_layer_mm",),
            "void_fraction": ("void_fraction",),
            "voids_count": ("voids_count",)}
    out = {}
    for metric, keys in pick.items():
        for key in keys:
            value = _number(sec.get(key))
            if value is not None:
                out[metric] = value
                break
    if "beads_count" not in out and isinstance(sec.get("beads"), list):
        out["beads_count"] = float(len(sec["beads"]))
    return out


#: summary keys that hold a cooling time, most specific first (physics/thermal.py reports
#: the time until the slowest fully cooled bead was below the glass transition)
_COOLING_KEYS = ("cooling_time_s", "bead_cooling_below_tg_max_s")


def _cooling_time(*sources) -> float | None:
    for source in sources:
        if not isinstance(source, dict):
            continue
        for key in _COOLING_KEYS + tuple(sorted(k for k in source if k.startswith("cooling_time"))):
            if _number(source.get(key)) is not None:
                return _number(source[key])
    return None


def key_metrics(summary: dict | None, meso: dict | None, nozzle_speed_m_s: float | None = None) -> dict:
    s = summary or {}
    out = {
        "density_error_mean": _number(s.get("density_error_mean")),
        "density_error_max": _number(s.get("density_error_max")),
        "paired_fraction": _number(s.get("paired_fraction")),
        "deposited_volume_mm3": _number(s.get("deposited_volume_mm3")),
        "commanded_volume_mm3": _number(s.get("commanded_volume_mm3")),
        "cooling_time_s": _cooling_time(s, meso),
        "particles": _number(s.get("particles_active")),
        "steps": _number(s.get("steps")),
        "simulated_time_s": _number(s.get("simulated_time_s")),
        "sim_wall_time_s": _number(s.get("wall_time_s")),
    }
    speed = _number(nozzle_speed_m_s)
    out["max_nozzle_speed_mm_s"] = None if speed is None else 1e3 * speed
    out.update(mesostructure_metrics(meso))
    for name in ("bead_width_mm", "bead_height_mm", "bead_area_mm2", "void_fraction"):
        if out.get(name) is None:  # the simulation may copy them into its summary
            out[name] = _number(s.get(name))
    return {k: v for k, v in out.items() if v is not None}


# --------------------------------------------------------------------------- running
JOB_FILE = "job.json"
PARAMS_FILE = "params.json"
#: what a job writes (log.txt belongs to whoever started the job process, and is kept)
_OUTPUTS = ("particles.h5", "particles.xdmf", "summary.json", "mesostructure.json", JOB_FILE,
            "input.gcode", "input_scaled.gcode")
_OUTPUT_DIRS = ("snapshots", "sections")


def write_json_atomic(path: Path, data) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, default=_json_default))
    os.replace(tmp, path)


def _json_default(obj):
    if isinstance(obj, Path):
        return str(obj)
    try:
        return float(obj)
    except (TypeError, ValueError):
        return str(obj)


def read_record(run_dir) -> dict | None:
    return read_json(Path(run_dir) / JOB_FILE)


def is_finished(run_dir) -> bool:
    """Finished: job.json says done and summary.json holds no error and no interruption."""
    record = read_record(run_dir)
    if not record or record.get("status") != "done":
        return False
    summary = read_json(Path(run_dir) / "summary.json")
    if summary is None:
        return False
    return "error" not in summary and not summary.get("interrupted")


def clear_outputs(run_dir: Path) -> None:
    """Remove what an earlier, unfinished attempt left (never anything else)."""
    import shutil

    for name in _OUTPUTS:
        with contextlib.suppress(FileNotFoundError):
            (run_dir / name).unlink()
    for name in _OUTPUT_DIRS:
        shutil.rmtree(run_dir / name, ignore_errors=True)


def timestamp() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S%z")


@contextlib.contextmanager
def sigint_deferred():
    """Hold Ctrl-C back until the block ends, then act on it as the handler before would
    have (KeyboardInterrupt for Python's own). Taichi's import catches whatever interrupts the
    loading of its library and raises ImportError ('initialization failed'): a sweep's
    Ctrl-C that fell in that moment recorded the run as failed, not interrupted (a CI run,
    2026-12-03). Python runs signal handlers in the main thread only; elsewhere the block
    runs as it is."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if caught:
        if callable(previous):
            previous(signal.SIGINT, None)
        elif previous == signal.SIG_DFL:
            os.kill(os.getpid(), signal.SIGINT)


@contextlib.contextmanager
def sigint_watched():
    """Yield a list that records every Ctrl-C the block receives, each raising
    KeyboardInterrupt as Python's own handler does. A library may catch that exception and
    raise its own: Taichi's kernel decorator, reading a method's annotations when a sweep's
    Ctrl-C fell, raised 'kernels parameters must be type annotated' and the run was recorded
    as failed (a suite run, 2026-12-04). A job that received Ctrl-C is interrupted, whatever
    error it ended with. Outside the main thread nothing is recorded."""
    caught: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield caught
        return

    def handler(signum, frame):
        caught.append(signum)
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield caught
    finally:
        signal.signal(signal.SIGINT, previous)


def run_print_job(params: dict, out_dir, *, base_dir=None, batch: str | None = None) -> dict:
    """Run one job in this process and return its record (also written as ``job.json``).

    Never raises for a failed run: a refused parameter, a blow-up, an interruption or a bug
    gives ``status`` ``'failed'`` or ``'interrupted'`` with the message under ``error``.
    ``batch``: the sweep that started it, kept in params.json (see run_job_isolated).
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    clear_outputs(out_dir)
    write_json_atomic(out_dir / PARAMS_FILE, {"params": params, "base_dir": base_dir, "batch": batch})
    record = {"run": out_dir.name, "status": "running", "params": params, "started": timestamp(),
              "host": socket.gethostname(), "pid": os.getpid()}
    t0 = time.perf_counter()
    summary = meso = None
    nozzle_speed = None
    with sigint_watched() as interrupts:
        try:
            with sigint_deferred():
                import taichi_mex.backend  # noqa: F401 - Taichi's import, which Ctrl-C would tear
            res = resolve(params, base_dir)
            job = build_job(res, out_dir)
            record["job_notes"] = job.notes
            from taichi_mex.sim.simulation import Simulation

            sim = Simulation.from_spec(job.spec, out_dir=out_dir)
            if job.spec.scene == "print":
                nozzle_speed = sim.plan.speed_scale_m_s
            record["cpu_threads"] = job.spec.run.cpu_threads
            record["estimate"] = {k: sim.estimate[k] for k in ("particles", "steps_estimate",
                                                               "memory_bytes")}
            summary = sim.run()
            if summary.get("interrupted"):
                record.update(status="interrupted", failure="interrupted",
                              error="interrupted before the end (frames so far kept)")
            else:
                record["status"] = "done"
                if res.analysis:
                    meso = _analyse(out_dir, record, sim.scene)
        except UserInputError as exc:
            record.update(status="failed", failure="refused", error=str(exc))
        except SimulationDiverged as exc:
            record.update(status="failed", failure="diverged", error=str(exc))
            summary = read_json(out_dir / "summary.json")
        except KeyboardInterrupt:
            record.update(status="interrupted", failure="interrupted", error="interrupted")
        except Exception as exc:  # noqa: BLE001 - a bug must cost this run only; keep its traceback
            lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
            if interrupts:  # a library turned the KeyboardInterrupt into its own error
                record.update(status="interrupted", failure="interrupted", error="interrupted")
            else:
                record.update(status="failed", failure="error",  # its last line says what
                              error=f"{type(exc).__name__}: {lines[-1] if lines else ''}",
                              traceback=traceback.format_exc(limit=20))
    record["finished"] = timestamp()
    metrics = key_metrics(summary, meso, nozzle_speed)
    metrics["wall_time_s"] = time.perf_counter() - t0
    record["metrics"] = metrics
    if summary:
        record["summary"] = {k: v for k, v in summary.items() if _number(v) is not None}
    write_json_atomic(out_dir / JOB_FILE, record)
    return record


def _analyse(out_dir: Path, record: dict, scene=None):
    """The run's mesostructure: the ``mesostructure.json`` the scene wrote itself (print
    scenes analyse their last frame), else :func:`taichi_mex.post.analysis.analyse_run` when that
    module is there. A failing analysis is noted in the record; the run stays done."""
    written = read_json(out_dir / "mesostructure.json")
    if written is not None:
        return written
    if hasattr(scene, "write_outputs"):
        record["analysis"] = "the run wrote no mesostructure.json (its log says why)"
        return None
    try:
        from taichi_mex.post.analysis import analyse_run
    except ImportError:
        record["analysis"] = "unavailable (no taichi_mex.post.analysis)"
        return None
    try:
        return analyse_run(out_dir)
    except Exception as exc:  # noqa: BLE001 - the simulation's outputs stand without it
        record["analysis"] = f"failed: {type(exc).__name__}: {exc}"
        return None


# --------------------------------------------------------------------------- isolation
#: how long a job process is given to stop after Ctrl-C (it ends its step, writes its frames
#: and its record) before it is killed, or before a sweep writes its table without it
STOP_GRACE_S = 60.0


def run_job_isolated(params: dict, out_dir, *, base_dir=None, timeout_s: float | None = None,
                     slots_by_host: dict | None = None, batch: str | None = None) -> dict:
    """Run one job in a fresh ``python -m taichi_mex.app.jobs`` process and return its record.

    Inside a Dask worker, ``cpu_threads`` defaults to this host's cores divided by the task
    slots the scheduler counts on it (``slots_by_host``), so the workers of one machine
    together use its cores once. A crash, a timeout or a killed child becomes a failed
    record; the worker itself survives. ``batch`` (the sweep's) goes into params.json, so that
    the sweep knows which runs it started.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    params = dict(params)
    if "cpu_threads" not in params:
        params["cpu_threads"] = default_threads(slots_by_host)
    clear_outputs(out_dir)
    write_json_atomic(out_dir / PARAMS_FILE, {"params": params, "base_dir": base_dir, "batch": batch})
    t0 = time.perf_counter()
    env = dict(os.environ, TAICHI_MEX_PARENT_PID=str(os.getpid()))
    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):  # numpy's share
        env.setdefault(name, str(params["cpu_threads"]))
    with open(out_dir / "log.txt", "w") as log:
        proc = subprocess.Popen([sys.executable, "-m", "taichi_mex.app.jobs", str(out_dir)],
                                stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                env=env)
        timed_out = False
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            timed_out = True
            proc.send_signal(signal.SIGINT)  # the simulation stops after its step, keeps frames
            try:
                proc.wait(timeout=STOP_GRACE_S)
            except subprocess.TimeoutExpired:
                proc.kill()
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    record = read_record(out_dir)
    if timed_out:
        record = record or {"run": out_dir.name, "params": params}
        record.update(status="failed", failure="timeout",
                      error=f"stopped after the run's time limit of {timeout_s:g} s")
        record.setdefault("metrics", {})["wall_time_s"] = time.perf_counter() - t0
        write_json_atomic(out_dir / JOB_FILE, record)
    elif record is None or record.get("status") == "running":
        tail = _tail(out_dir / "log.txt")
        code = proc.returncode
        how = f"signal {-code}" if code is not None and code < 0 else f"exit code {code}"
        record = {"run": out_dir.name, "params": params, "status": "failed", "failure": "crashed",
                  "error": f"the job process ended with {how} before writing its record"
                           + (f"; last output: {tail}" if tail else ""),
                  "metrics": {"wall_time_s": time.perf_counter() - t0}}
        write_json_atomic(out_dir / JOB_FILE, record)
    return record


def _tail(path: Path, lines: int = 5) -> str:
    try:
        text = path.read_text(errors="replace").strip().splitlines()
    except OSError:
        return ""
    return " | ".join(text[-lines:])[-600:]


def available_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def default_threads(slots_by_host: dict | None = None) -> int:
    """This host's cores over the job slots on it (1 slot outside Dask)."""
    slots = 1
    try:
        from distributed import get_worker

        worker = get_worker()
        slots = max(1, int(getattr(worker.state, "nthreads", 1)))
        if slots_by_host:
            host = worker.address.rsplit(":", 1)[0].split("://")[-1]
            slots = max(slots, int(slots_by_host.get(host, slots)))
    except (ImportError, ValueError, AttributeError):
        pass
    return max(1, available_cores() // slots)


def _watch_parent(parent_pid: int) -> None:
    """Interrupt this job (it then stops cleanly) if the process that started it dies."""
    import _thread

    def watch():
        while True:
            time.sleep(1.0)
            if os.getppid() != parent_pid:
                _thread.interrupt_main()
                return

    threading.Thread(target=watch, daemon=True).start()


def main(argv: list[str] | None = None) -> int:
    """``python -m taichi_mex.app.jobs RUN_DIR``: run the job described by RUN_DIR/params.json."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if len(argv) != 1:
        print("usage: python -m taichi_mex.app.jobs RUN_DIR (with RUN_DIR/params.json)", file=sys.stderr)
        return 2
    run_dir = Path(argv[0])
    # a Dask worker may have started us with Ctrl-C ignored; the simulation handles it itself
    signal.signal(signal.SIGINT, signal.default_int_handler)
    spec = json.loads((run_dir / PARAMS_FILE).read_text())
    parent = os.environ.get("TAICHI_MEX_PARENT_PID")
    if parent and parent.isdigit():
        _watch_parent(int(parent))
    record = run_print_job(spec["params"], run_dir, base_dir=spec.get("base_dir"),
                           batch=spec.get("batch"))
    print(f"{record['run']}: {record['status']}" + (f" ({record.get('failure')}): {record['error']}"
                                                    if record.get("error") else ""))
    return {"done": 0, "interrupted": 130}.get(record["status"], 1)


if __name__ == "__main__":
    sys.exit(main())
