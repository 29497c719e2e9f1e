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
import importlib.util
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
from dataclasses import dataclass, field, fields
from pathlib import Path

from taichi_mex import bundled
from taichi_mex.errors import SimulationDiverged, UserInputError

# --------------------------------------------------------------------------- parameters
_NUM = (int, float)


@dataclass(frozen=True)
class Param:
    help: str
    types: tuple
    group: str


PARAMETERS: dict[str, Param] = {
    # what is printed
    "gcode": Param("G-code file: a path (relative to the study file) or a bundled name "
                   "(" + ", ".join(n.removesuffix(".gcode") for n in bundled.bundled_names()) + ")",
                   (str,), "print"),
    "scene": Param("a built-in scene instead of a print ('python -m taichi_mex scene --help'); "
                   "its own options as scene.OPTION, e.g. scene.radius_mm", (str,), "print"),
    "printer": Param("pyGCodeDecode printer preset or FILE.yaml[:NAME] (default prusa_mini)",
                     (str,), "print"),
    "layers": Param("layers to simulate, '2-3' or 2 (1-based; default all)", (str, int), "print"),
    "region": Param("XY box 'XMIN:XMAX,YMIN:YMAX' in mm", (str,), "print"),
    "until": Param("stop at this print time (s)", _NUM, "print"),
    "deposit_for_s": Param("stop this long (s) after the selected deposition starts (instead of "
                           "'until'; follows the start when the speed changes)", _NUM, "print"),
    "settle": Param("simulate this long (s) after the last deposition", _NUM, "print"),
    "nozzle_height": Param("'gcode' (the nozzle at the G-code's Z) or 'one_diameter' (the seed "
                           "paper's)", (str,), "print"),
    "nozzle_tip_outer_diameter_mm": Param("flat nozzle tip around the bore (mm), or false for none "
                                          "(default 1.0)", _NUM + (bool,), "print"),
    # G-code rewrites
    "feed_rate_factor": Param("multiply every feed rate F of the G-code (nozzle speed; the "
                              "printer's limits still apply)", _NUM, "gcode"),
    "flow_factor": Param("multiply every extrusion E of the G-code (over/under-extrusion)", _NUM,
                         "gcode"),
    # generated G-code (taichi_mex.toolpath.generate)
    "pattern": Param("generate the G-code: 'bead' (one bead) or 'block' (block_layers x "
                     "block_beads parallel beads); default 'bead' when a parameter below is set",
                     (str,), "generate"),
    "layer_height_mm": Param("generated G-code: layer height (mm, default 0.2)", _NUM, "generate"),
    "line_width_mm": Param("generated G-code: extrusion width (mm, default 0.45)", _NUM, "generate"),
    "speed_mm_s": Param("generated G-code: printing speed (mm/s, default 60)", _NUM, "generate"),
    "bead_length_mm": Param("generated G-code: bead length (mm, default 3)", _NUM, "generate"),
    "block_beads": Param("generated block: beads per layer (default 3)", (int,), "generate"),
    "block_layers": Param("generated block: layers (default 3)", (int,), "generate"),
    # discretisation and solver
    "preset": Param("named parameter set from config.PRESETS (e.g. 'paper')", (str,), "run"),
    "resolution": Param("particle spacing in mm, or a named resolution preset when "
                        "config.RESOLUTION_PRESETS exists", _NUM + (str,), "run"),
    "spacing_mm": Param("particle spacing (mm)", _NUM, "run"),
    "scheme": Param("pressure scheme: edac, dfsph, static", (str,), "run"),
    "sound_speed": Param("EDAC artificial sound speed (m/s)", _NUM, "run"),
    "dt_factor": Param("multiply the stable time step (> 1 only to probe stability)", _NUM, "run"),
    "precision": Param("f32 or f64", (str,), "run"),
    "arch": Param("cpu or gpu", (str,), "run"),
    "cpu_threads": Param("CPU threads of this run (default: the worker's share of the cores)",
                         (int,), "run"),
    "output_every": Param("write an HDF5 frame every this many simulated seconds", _NUM, "run"),
    "snapshots": Param("write PNG snapshots (default true)", (bool,), "run"),
    "analysis": Param("take bead metrics from mesostructure.json, running taichi_mex.post.analysis "
                      "when the scene did not (default true)", (bool,), "run"),
    # melt
    "viscosity": Param("melt viscosity (Pa s): Newtonian unless viscosity_model says otherwise, "
                       "then the model's reference value", _NUM, "material"),
    "viscosity_model": Param("newtonian, arrhenius or cross_wlf", (str,), "material"),
    "nozzle_temperature_c": Param("melt temperature at the nozzle (degC): sets temperature-"
                                  "dependent viscosity, and the inlet temperature with heat on",
                                  _NUM, "material"),
    # heat (any of these switches heat on)
    "thermal": Param("simulate temperature (default false; true when a heat parameter is set)",
                     (bool,), "heat"),
    "plate_temperature_c": Param("build plate temperature (degC); switches heat on", _NUM, "heat"),
    "ambient_c": Param("ambient temperature (degC); switches heat on", _NUM, "heat"),
    "convection_w_m2k": Param("convective heat transfer coefficient (W/m^2/K); switches heat on",
                              _NUM, "heat"),
    "radiation_emissivity": Param("radiate with this emissivity; switches heat on", _NUM, "heat"),
}

_OPTIONAL_RUN_FIELDS = {
    "viscosity_scale": Param("creeping-flow scaling of the viscosity: a factor in (0, 1], 'auto' "
                             "or 'off'", _NUM + (str,), "run"),
}

#: dotted prefixes and the options object they reach
_DOTTED = ("run.", "material.", "scene.")
_HEAT_PARAMS = ("plate_temperature_c", "ambient_c", "convection_w_m2k", "radiation_emissivity")
_GENERATE_DEFAULTS = {"pattern": "bead", "layer_height_mm": 0.2, "line_width_mm": 0.45,
                      "speed_mm_s": 60.0, "bead_length_mm": 3.0, "block_beads": 3,
                      "block_layers": 3}


def parameters() -> dict[str, Param]:
    """The named parameters this version understands (optional ones only when present)."""
    from taichi_mex.options import RunOptions

    out = dict(PARAMETERS)
    names = {f.name for f in fields(RunOptions)}
    out.update({k: v for k, v in _OPTIONAL_RUN_FIELDS.items() if k in names})
    return out


def describe_parameters() -> str:
    groups = {"print": "what is printed", "gcode": "G-code rewrites",
              "generate": "generated G-code", "run": "discretisation and solver",
              "material": "melt", "heat": "heat"}
    lines = []
    table = parameters()
    for group, title in groups.items():
        lines.append(f"{title}:")
        for name, p in table.items():
            if p.group == group:
                lines.append(f"  {name:30s} {p.help}")
    lines.append("any other option: run.FIELD, run.edac.FIELD, run.dfsph.FIELD, run.thermal.FIELD, "
                 "material.FIELD (see taichi_mex/config.py), scene.OPTION for a built-in scene")
    return "\n".join(lines)


def _dataclass_fields(obj) -> dict:
    return {f.name: f for f in fields(obj)}


def _check_dotted(name: str, scene_options: set | None) -> str | None:
    """None when a dotted name reaches an existing option, else the reason."""
    from taichi_mex.options import Material, RunOptions

    prefix, _, rest = name.partition(".")
    if not rest:
        return "it names no option after the dot"
    if prefix == "scene":
        if scene_options is None:
            return "scene.OPTION needs 'scene = NAME'"
        if rest not in scene_options:
            close = difflib.get_close_matches(rest, scene_options, 1)
            return ("the scene has no option '" + rest + "'"
                    + (f" (did you mean scene.{close[0]}?)" if close else "")
                    + f"; it has {', '.join(sorted(scene_options))}")
        return None
    obj = RunOptions() if prefix == "run" else Material()
    parts = rest.split(".")
    for i, part in enumerate(parts):
        names = _dataclass_fields(obj)
        if part not in names:
            close = difflib.get_close_matches(part, names, 1)
            where = ".".join([prefix] + parts[:i])
            return (f"{where} has no field '{part}'"
                    + (f" (did you mean {where}.{close[0]}?)" if close else ""))
        value = getattr(obj, part)
        if i < len(parts) - 1:
            if not hasattr(value, "__dataclass_fields__"):
                return f"{prefix}.{'.'.join(parts[:i + 1])} is not a group of options"
            obj = value
        elif hasattr(value, "__dataclass_fields__"):
            return f"{name} is a group of options; name one of its fields"
    return None


def scene_option_names(scene: str) -> set:
    """Option names (argparse dests) of a built-in scene, besides the run options."""
    spec = _scene_spec(scene)
    parser = _scene_parser(spec, with_run_options=False)
    return {a.dest for a in parser._actions if a.dest not in ("help",)}


def check_names(params: dict) -> None:
    """Refuse unknown parameter names (UserInputError naming each, with a suggestion)."""
    table = parameters()
    scene_options = None
    if isinstance(params.get("scene"), str):
        scene_options = scene_option_names(params["scene"])
    problems = []
    for name in params:
        if name in table:
            continue
        if name.startswith(_DOTTED):
            reason = _check_dotted(name, scene_options)
            if reason:
                problems.append(f"'{name}': {reason}")
            continue
        close = difflib.get_close_matches(name, list(table), 1)
        problems.append(f"'{name}'" + (f" (did you mean '{close[0]}'?)" if close else ""))
    if problems:
        raise UserInputError("Unknown parameter " + "; ".join(problems) + ". 'python -m "
                             "taichi_mex sweep --list-params' lists the names.")


# --------------------------------------------------------------------------- resolving
@dataclass
class Resolved:
    """A parameter dict turned into options, before any file is written or planned."""

    params: dict
    run: object
    material: object
    #: 'print' or a built-in scene name
    scene: str = "print"
    #: print: the source G-code (None: generated), rewrite factors, scene keywords
    gcode: Path | None = None
    generate: dict | None = None
    feed_rate_factor: float = 1.0
    flow_factor: float = 1.0
    scene_kwargs: dict = field(default_factory=dict)
    deposit_for_s: float | None = None
    scene_overrides: dict = field(default_factory=dict)
    analysis: bool = True


def _check_types(params: dict) -> None:
    table = parameters()
    for name, value in params.items():
        p = table.get(name)
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


def _positive(params: dict, name: str) -> None:
    if name in params and not params[name] > 0:
        raise UserInputError(f"Parameter {name} must be positive, got {params[name]!r}.")


def resolve_gcode_name(value: str, base_dir=None) -> Path:
    """A path (relative to ``base_dir``) or a bundled name -> an existing file."""
    names = bundled.bundled_names()
    plain = value if value.endswith(".gcode") else value + ".gcode"
    path = Path(value).expanduser()
    if not path.is_absolute() and base_dir is not None:
        path = Path(base_dir) / path
    if path.is_file():
        return path.resolve()
    if "/" not in value and plain in names:
        return bundled.gcode_path(plain)
    raise UserInputError(f"G-code '{value}' is neither a file ({path}) nor a bundled name "
                         f"({', '.join(n.removesuffix('.gcode') for n in names)}).")


def _nested(dotted: dict) -> dict:
    """{'edac.cfl': 0.2, 'scheme': 'x'} -> {'edac': {'cfl': 0.2}, 'scheme': 'x'}."""
    out: dict = {}
    for key, value in dotted.items():
        node = out
        parts = key.split(".")
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = value
    return out


def resolve(params: dict, base_dir=None) -> Resolved:
    """Options, scene choice and G-code source for one run; refuses unknown names and bad
    values with UserInputError (nothing is written, nothing is planned)."""
    from taichi_mex import options as config
    from taichi_mex.options import PRESETS, Material, RunOptions, apply_overrides

    check_names(params)
    _check_types(params)
    for name in ("until", "deposit_for_s", "spacing_mm", "sound_speed", "viscosity",
                 "feed_rate_factor", "flow_factor", "output_every", "cpu_threads"):
        _positive(params, name)
    if "settle" in params and params["settle"] < 0:
        raise UserInputError(f"Parameter settle must be >= 0, got {params['settle']!r}.")
    if "until" in params and "deposit_for_s" in params:
        raise UserInputError("Give either until (a print time) or deposit_for_s (time after the "
                             "deposition starts), not both.")
    if "spacing_mm" in params and "resolution" in params:
        raise UserInputError("Give either spacing_mm or resolution, not both.")

    run = RunOptions(progress=False)
    material = Material()
    preset = {}
    if "preset" in params:
        if params["preset"] not in PRESETS:
            raise UserInputError(f"Unknown preset '{params['preset']}'; choose "
                                 f"{', '.join(sorted(PRESETS))}.")
        preset = PRESETS[params["preset"]]
        run = apply_overrides(run, preset.get("run", {}))
        material = apply_overrides(material, preset.get("material", {}))
    if "resolution" in params:
        run = _apply_resolution(run, params["resolution"], getattr(config, "RESOLUTION_PRESETS", None))

    changes: dict = {}
    for name, key in (("scheme", "scheme"), ("spacing_mm", "spacing_mm"), ("dt_factor", "dt_factor"),
                      ("precision", "precision"), ("arch", "arch"), ("cpu_threads", "cpu_threads"),
                      ("output_every", "output_every_s"), ("snapshots", "snapshots")):
        if name in params:
            changes[key] = params[name]
    if "sound_speed" in params:
        changes["edac"] = {"sound_speed_m_s": float(params["sound_speed"])}
    if "viscosity_scale" in params:
        changes["viscosity_scale"] = _viscosity_scale(params["viscosity_scale"])
    heat = {key: params[key] for key in _HEAT_PARAMS if key in params}
    if heat and params.get("thermal") is False:
        raise UserInputError(f"{', '.join(heat)} need heat, but the run sets thermal = false.")
    thermal = {"enabled": True} if heat or params.get("thermal") else {}
    for key, target in (("plate_temperature_c", "plate_temperature_c"), ("ambient_c", "ambient_c"),
                        ("convection_w_m2k", "convection_w_m2k"),
                        ("radiation_emissivity", "radiation_emissivity")):
        if key in heat:
            thermal[target] = heat[key]
    if thermal:
        changes["thermal"] = thermal
    run = apply_overrides(run, changes)

    mat: dict = {}
    if "viscosity" in params:
        mat["viscosity_pa_s"] = float(params["viscosity"])
        mat["viscosity_model"] = "newtonian"
    if "viscosity_model" in params:
        mat["viscosity_model"] = params["viscosity_model"]
    if "nozzle_temperature_c" in params:
        mat["extrusion_temperature_c"] = float(params["nozzle_temperature_c"])
    material = apply_overrides(material, mat)

    run_dotted = {k[4:]: v for k, v in params.items() if k.startswith("run.")}
    mat_dotted = {k[9:]: v for k, v in params.items() if k.startswith("material.")}
    run = apply_overrides(run, _nested(run_dotted))
    material = apply_overrides(material, _nested(mat_dotted))
    run.validate()
    material.validate()
    if run.thermal.enabled and importlib.util.find_spec("taichi_mex.physics.thermal") is None:
        raise UserInputError("Heat was asked for, but this taichi_mex has no heat model "
                             "(taichi_mex.physics.thermal).")

    res = Resolved(params=params, run=run, material=material,
                   analysis=params.get("analysis", True))
    if "scene" in params:
        return _resolve_scene(res, params)

    generate = {k: params[k] for k in _GENERATE_DEFAULTS if k in params}
    if generate and "gcode" in params:
        raise UserInputError(f"{', '.join(generate)} describe a generated G-code; drop them or "
                             f"drop gcode = {params['gcode']!r}.")
    if generate:
        from taichi_mex.toolpath.generate import check_pattern

        res.generate = {**_GENERATE_DEFAULTS, **generate}
        check_pattern(**_pattern_kwargs(res.generate, _printer_path(params.get("printer", "prusa_mini"),
                                                                    base_dir)))
    else:
        name = params.get("gcode", preset.get("gcode", bundled.DEFAULT_GCODE))
        res.gcode = resolve_gcode_name(name, base_dir)
    res.feed_rate_factor = float(params.get("feed_rate_factor", 1.0))
    res.flow_factor = float(params.get("flow_factor", 1.0))

    from taichi_mex.toolpath.trajectory import parse_layers, parse_region

    kw: dict = {"printer": _printer_path(params.get("printer", "prusa_mini"), base_dir),
                "layers": parse_layers(params["layers"]) if "layers" in params else None,
                "region_mm": parse_region(params["region"]) if "region" in params else None,
                "until_s": float(params["until"]) if "until" in params else None,
                "settle_s": float(params.get("settle", 0.0))}
    if preset.get("nozzle_height") == "one_diameter":
        kw["nozzle_height"] = "one_diameter"
    if preset.get("nozzle_tip") is False:
        kw["nozzle_tip_outer_diameter_mm"] = None
    if "nozzle_height" in params:
        if params["nozzle_height"] not in ("gcode", "one_diameter"):
            raise UserInputError(f"nozzle_height is 'gcode' or 'one_diameter', not "
                                 f"{params['nozzle_height']!r}.")
        kw["nozzle_height"] = params["nozzle_height"]
    if "nozzle_tip_outer_diameter_mm" in params:
        tip = params["nozzle_tip_outer_diameter_mm"]
        if tip is True or (not isinstance(tip, bool) and not tip > 0):
            raise UserInputError("nozzle_tip_outer_diameter_mm is a diameter in mm or false.")
        kw["nozzle_tip_outer_diameter_mm"] = None if tip is False else float(tip)
    res.scene_kwargs = kw
    res.deposit_for_s = float(params["deposit_for_s"]) if "deposit_for_s" in params else None
    return res


def _printer_path(spec: str, base_dir) -> str:
    """A printer YAML given relative to the study file, made absolute; names stay names."""
    path, sep, name = spec.partition(".yaml")
    if not sep or base_dir is None or Path(path).is_absolute():
        return spec
    return str(Path(base_dir) / path) + sep + name


def _apply_resolution(run, value, table):
    from taichi_mex.options import apply_overrides

    if not isinstance(value, str):
        return apply_overrides(run, {"spacing_mm": float(value)})
    if not table:
        raise UserInputError(f"resolution = {value!r}: this taichi_mex has no named resolution "
                             "presets; give the spacing in mm (resolution = 0.05).")
    if value not in table:
        raise UserInputError(f"Unknown resolution preset {value!r}; choose "
                             f"{', '.join(sorted(table))} or a spacing in mm.")
    entry = table[value]
    if isinstance(entry, (int, float)):
        return apply_overrides(run, {"spacing_mm": float(entry)})
    if hasattr(entry, "__dataclass_fields__"):
        entry = {f.name: getattr(entry, f.name) for f in fields(entry)}
    entry = entry.get("run", entry)
    names = _dataclass_fields(run)
    return apply_overrides(run, {k: v for k, v in entry.items() if k in names})


def _viscosity_scale(value):
    if isinstance(value, str):
        text = value.lower()
        if text == "auto":
            return "auto"
        if text in ("off", "none"):
            return 1.0
        raise UserInputError(f"viscosity_scale is a number in (0, 1], 'auto' or 'off', not {value!r}.")
    return float(value)


def _pattern_kwargs(gen: dict, printer: str) -> dict:
    beads = gen["block_beads"] if gen["pattern"] == "block" else 1
    layers = gen["block_layers"] if gen["pattern"] == "block" else 1
    return dict(pattern=gen["pattern"], layer_height_mm=gen["layer_height_mm"],
                line_width_mm=gen["line_width_mm"], speed_mm_s=gen["speed_mm_s"],
                bead_length_mm=gen["bead_length_mm"], beads=beads, layers=layers, printer=printer)


def _scene_spec(name: str):
    from taichi_mex.scenes import load_all

    scenes = load_all()
    if name == "print":
        raise UserInputError("scene = 'print' is the default; give gcode = ... instead.")
    if name not in scenes:
        raise UserInputError(f"Unknown scene '{name}'; choose one of {', '.join(scenes)}.")
    return scenes[name]


def _scene_parser(spec, with_run_options: bool = True):
    from taichi_mex.app.cli import _Parser, add_run_options

    p = _Parser(prog=f"scene {spec.name}", add_help=False)
    if with_run_options:
        add_run_options(p)
    spec.add_arguments(p)
    return p


def _resolve_scene(res: Resolved, params: dict) -> Resolved:
    spec = _scene_spec(params["scene"])
    for name in ("gcode", "printer", "layers", "region", "until", "deposit_for_s", "settle",
                 "feed_rate_factor", "flow_factor", "nozzle_height", "nozzle_tip_outer_diameter_mm",
                 *_GENERATE_DEFAULTS):
        if name in params:
            raise UserInputError(f"{name} applies to prints; scene '{spec.name}' takes "
                                 f"scene.OPTION instead (e.g. scene.until).")
    res.scene = spec.name
    res.scene_overrides = {k[6:]: v for k, v in params.items() if k.startswith("scene.")}
    return res


# --------------------------------------------------------------------------- building
@dataclass
class Job:
    scene: object
    run: object
    material: object
    gcode: Path | None = None
    notes: dict = field(default_factory=dict)


def build_job(res: Resolved, out_dir) -> Job:
    """Write the run's G-code (generated or rewritten) into ``out_dir`` and build the scene."""
    from taichi_mex.options import apply_overrides

    out_dir = Path(out_dir)
    if res.scene != "print":
        spec = _scene_spec(res.scene)
        parser = _scene_parser(spec)
        args = parser.parse_args([])
        for key, value in res.scene_overrides.items():
            setattr(args, key, value)
        scene, run_defaults, material_overrides = spec.build(args)
        run = res.run
        explicit = {"scheme", "spacing_mm", "resolution", "preset"} & set(res.params)
        defaults = {k: v for k, v in run_defaults.items()
                    if not ({k} & explicit or (k == "spacing_mm" and "resolution" in explicit))
                    and f"run.{k}" not in res.params}
        run = apply_overrides(run, defaults)
        run.validate()
        material = apply_overrides(res.material, material_overrides)
        return Job(scene, run, material, notes={"scene": res.scene})

    from taichi_mex.toolpath.generate import write_pattern, write_scaled
    from taichi_mex.scenes.print import PrintScene

    notes: dict = {}
    if res.generate is not None:
        gcode = write_pattern(out_dir / "input.gcode",
                              **_pattern_kwargs(res.generate, res.scene_kwargs["printer"]))
        notes["gcode_source"] = f"generated ({res.generate['pattern']})"
    else:
        gcode = res.gcode
        notes["gcode_source"] = str(gcode)
    if res.feed_rate_factor != 1.0 or res.flow_factor != 1.0:
        gcode = write_scaled(gcode, out_dir / "input_scaled.gcode", res.feed_rate_factor,
                             res.flow_factor)
    kw = dict(res.scene_kwargs)
    if res.deposit_for_s is not None:
        from taichi_mex.toolpath.plan import make_plan

        plan = make_plan(gcode, kw["printer"], layers=kw["layers"], region_mm=kw["region_mm"],
                         plan_whole_file=False)
        kw["until_s"] = plan.selection.t_start_s + res.deposit_for_s
        notes["deposition_start_s"] = plan.selection.t_start_s
    scene = PrintScene(gcode, **kw)
    return Job(scene, res.run, res.material, gcode=Path(gcode), notes=notes)


# --------------------------------------------------------------------------- metrics
#: columns of the results table besides the parameters: name -> meaning
METRICS = {
    "bead_width_mm": "mean bead width in the default cross-section (mesostructure.json)",
    "bead_height_mm": "mean bead height in the default cross-section",
    "bead_area_mm2": "mean bead cross-section area",
    "beads_count": "beads cut by the default cross-section",
    "neck_side_mm": "mean neck width between side-by-side beads",
    "neck_layer_mm": "mean neck width between stacked beads",
    "void_fraction": "void area / (melt + void) area in the default cross-section",
    "voids_count": "enclosed voids in the default cross-section",
    "density_error_mean": "mean |rho/rho0 - 1| of interior melt at the end",
    "density_error_max": "largest |rho/rho0 - 1| of interior melt at the end",
    "paired_fraction": "melt with a melt neighbour closer than half a spacing (SPH pairing)",
    "deposited_volume_mm3": "melt volume in the domain at the end",
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
    """Bead width/height/area, necks and voids of the default (first) cross-section."""
    if not isinstance(meso, dict):
        return {}
    sections = meso.get("sections")
    sec = sections[0] if isinstance(sections, list) and sections and isinstance(sections[0], dict) else meso
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


def key_metrics(summary: dict | None, meso: dict | None, config_notes: dict | None = None) -> dict:
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
    notes = config_notes or {}
    speed = _number(notes.get("speed_scale_m_s")) if "gcode" in notes else None  # prints only
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
    path = Path(run_dir) / JOB_FILE
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def is_finished(run_dir) -> bool:
    """Finished: job.json says done and summary.json holds no error and no interruption."""
    record = read_record(run_dir)
    if not record or record.get("status") != "done":
        return False
    try:
        summary = json.loads((Path(run_dir) / "summary.json").read_text())
    except (OSError, ValueError):
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


def run_print_job(params: dict, out_dir, *, base_dir=None) -> dict:
    """Run one job in this process and return its record (also written as ``job.json``).

    Never raises for a failed run: a refused parameter, a blow-up, an interruption or a bug
    gives ``status`` ``'failed'`` or ``'interrupted'`` with the message under ``error``.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    clear_outputs(out_dir)
    write_json_atomic(out_dir / PARAMS_FILE, {"params": params, "base_dir": base_dir})
    record = {"run": out_dir.name, "status": "running", "params": params, "started": timestamp(),
              "host": socket.gethostname(), "pid": os.getpid()}
    t0 = time.perf_counter()
    summary = meso = None
    notes: dict = {}
    try:
        res = resolve(params, base_dir)
        job = build_job(res, out_dir)
        record["job_notes"] = job.notes
        from taichi_mex.sim.simulation import Simulation

        sim = Simulation(job.scene, job.run, job.material, out_dir=out_dir)
        notes = dict(sim.plan.notes)
        record["cpu_threads"] = job.run.cpu_threads
        record["estimate"] = {k: sim.estimate[k] for k in ("particles", "steps_estimate",
                                                           "memory_bytes")}
        summary = sim.run()
        if summary.get("interrupted"):
            record.update(status="interrupted", failure="interrupted",
                          error="interrupted before the end (frames so far kept)")
        else:
            record["status"] = "done"
            if res.analysis:
                meso = _analyse(out_dir, record, job.scene)
    except UserInputError as exc:
        record.update(status="failed", failure="refused", error=str(exc))
    except SimulationDiverged as exc:
        record.update(status="failed", failure="diverged", error=str(exc))
        summary = _read_json(out_dir / "summary.json")
    except KeyboardInterrupt:
        record.update(status="interrupted", failure="interrupted", error="interrupted")
    except Exception as exc:  # noqa: BLE001 - a bug must cost this run only; keep its traceback
        lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
        record.update(status="failed", failure="error",  # the last line says what went wrong
                      error=f"{type(exc).__name__}: {lines[-1] if lines else ''}",
                      traceback=traceback.format_exc(limit=20))
    record["finished"] = timestamp()
    metrics = key_metrics(summary, meso, notes)
    metrics["wall_time_s"] = time.perf_counter() - t0
    record["metrics"] = metrics
    if summary:
        record["summary"] = {k: v for k, v in summary.items() if _number(v) is not None}
    write_json_atomic(out_dir / JOB_FILE, record)
    return record


def _read_json(path: Path):
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _analyse(out_dir: Path, record: dict, scene=None):
    """The run's mesostructure: the ``mesostructure.json`` the scene wrote itself (print
    scenes analyse their last frame), else :func:`taichi_mex.post.analysis.analyse_run` when that
    module is there. A failing analysis is noted in the record; the run stays done."""
    written = _read_json(out_dir / "mesostructure.json")
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
def run_job_isolated(params: dict, out_dir, *, base_dir=None, timeout_s: float | None = None,
                     slots_by_host: dict | None = None) -> dict:
    """Run one job in a fresh ``python -m taichi_mex.app.jobs`` process and return its record.

    Inside a Dask worker, ``cpu_threads`` defaults to this host's cores divided by the task
    slots the scheduler counts on it (``slots_by_host``), so the workers of one machine
    together use its cores once. A crash, a timeout or a killed child becomes a failed
    record; the worker itself survives.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    params = dict(params)
    if "cpu_threads" not in params:
        params["cpu_threads"] = default_threads(slots_by_host)
    clear_outputs(out_dir)
    write_json_atomic(out_dir / PARAMS_FILE, {"params": params, "base_dir": base_dir})
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
                proc.wait(timeout=60)
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
    record = run_print_job(spec["params"], run_dir, base_dir=spec.get("base_dir"))
    print(f"{record['run']}: {record['status']}" + (f" ({record.get('failure')}): {record['error']}"
                                                    if record.get("error") else ""))
    return {"done": 0, "interrupted": 130}.get(record["status"], 1)


if __name__ == "__main__":
    sys.exit(main())
