"""Checkpoints: the whole state of a run at every output frame and on Ctrl-C, so that
``python -m taichi_mex --resume DIR`` continues it to the same end.

What is kept is found, not listed: every Taichi field and every plain value (numbers, text,
containers, numpy arrays) held by the particle state, the solver and the physics modules it
owns, the inlet, the viscosity and the scene, walked down through taichi_mex objects. A module
that adds a field or a counter is therefore checkpointed without an edit here. Left out are
what the run rebuilds or never changes: the neighbour grid, kernels, the toolpath and options,
and the scratch a class names in ``checkpoint_skip`` (recomputed at the start of every use).

The file is a pickle (``checkpoint.pkl``, written atomically): resume only folders you trust.
It records the taichi_mex version and the run description, and a resume against either
changed is refused.
"""

from __future__ import annotations

import os
import pickle
from dataclasses import is_dataclass
from pathlib import Path

import numpy as np

from taichi_mex.backend import ti
from taichi_mex.errors import UserInputError

FILE = "checkpoint.pkl"
FORMAT = 1
_PLAIN = (int, float, bool, str, type(None), np.ndarray, np.generic)
#: classes whose objects are fixed for the run or rebuilt from it: never walked into
_SKIP = {"NeighbourGrid", "Kernel", "Selection", "Trajectory", "NormalisedGCode", "PrinterPreset",
         "PrintPlan", "ScenePlan", "StepHooks"}


def _plain(value) -> bool:
    if isinstance(value, _PLAIN):
        return True
    if isinstance(value, (list, tuple)):
        return all(_plain(v) for v in value)
    if isinstance(value, dict):
        return all(isinstance(k, (str, int)) and _plain(v) for k, v in value.items())
    return False


def _walk(obj, path: str, seen: set, fields: dict, values: dict) -> None:
    if id(obj) in seen:
        return
    seen.add(id(obj))
    scratch = getattr(type(obj), "checkpoint_skip", ())
    for name, value in vars(obj).items():
        if name in scratch:
            continue
        key = f"{path}.{name}"
        if isinstance(value, ti.Field):
            fields[key] = value
        elif _plain(value):
            values[key] = value
        elif (type(value).__module__.startswith("taichi_mex") and not is_dataclass(value)
              and type(value).__name__ not in _SKIP and hasattr(value, "__dict__")):
            _walk(value, key, seen, fields, values)


def _roots(sim) -> dict:
    roots = {"state": sim.state, "solver": sim.solver, "viscosity": sim.viscosity}
    for name in ("inlet", "thermal", "solidification", "probes"):
        if getattr(sim, name, None) is not None:
            roots[name] = getattr(sim, name)
    return roots


def _collect(sim) -> tuple[dict, dict]:
    fields, values = {}, {}
    seen = {id(sim.grid), id(sim.kernel), id(sim.plan)}
    for name, obj in _roots(sim).items():
        _walk(obj, name, seen, fields, values)
    # the scene's own bookkeeping (a collapse's front samples), not its plan
    for name, value in vars(sim.scene).items():
        if _plain(value):
            values[f"scene.{name}"] = value
    return fields, values


def _resolve(sim, key: str):
    """(owner object, attribute name) of a dotted key."""
    root, *parts = key.split(".")
    obj = sim.scene if root == "scene" else _roots(sim)[root]
    for part in parts[:-1]:
        obj = getattr(obj, part)
    return obj, parts[-1]


def save(sim, description: dict) -> Path:
    """Write the run's checkpoint next to its frames (atomically: a kill mid-write leaves the
    previous one)."""
    from taichi_mex import __version__

    fields, values = _collect(sim)
    n, cap = sim.state.n, sim.state.capacity
    arrays = {}
    for key, field in fields.items():
        arr = field.to_numpy()
        # particle-sized fields: only the live particles
        arrays[key] = arr[:n] if arr.ndim and arr.shape[0] == cap else arr
    data = {"format": FORMAT, "taichi_mex": __version__, "description": description,
            "capacity": cap, "n": n, "fields": arrays, "values": values,
            "run": {"time_s": sim.time_s, "steps": sim.steps, "lost_particles": sim.lost_particles,
                    "lost_by_face": sim.lost_by_face, "lost_times_s": sim.lost_times_s,
                    "outside_max": sim.outside_max, "outside_by_face": sim.outside_by_face,
                    "outside_times_s": sim.outside_times_s,
                    "over_face": sim.over_face,
                    "inlet_retired": sim._inlet_retired, "skipped": sim.skipped}}
    path = Path(sim.out_dir) / FILE
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as fh:
        pickle.dump(data, fh, protocol=pickle.HIGHEST_PROTOCOL)
    os.replace(tmp, path)
    return path


def load(out_dir) -> dict:
    """The checkpoint of a run folder; refuses a missing, foreign or incompatible one."""
    from taichi_mex import __version__

    path = Path(out_dir) / FILE
    if not path.is_file():
        raise UserInputError(f"No checkpoint in {out_dir}: a run writes {FILE} at every output "
                             "frame and on Ctrl-C; this folder holds none (not a run folder, or "
                             "a run from a taichi_mex without checkpoints).")
    try:
        with open(path, "rb") as fh:
            data = pickle.load(fh)
    except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ImportError) as exc:
        raise UserInputError(f"{path} is not a readable checkpoint ({exc}).") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise UserInputError(f"{path} is not a taichi_mex checkpoint of format {FORMAT}.")
    if data.get("taichi_mex") != __version__:
        raise UserInputError(f"{path} was written by taichi_mex {data.get('taichi_mex')}; this is "
                             f"{__version__}. Resume it with that version, or start the run again.")
    return data


def restore(sim, data: dict) -> None:
    """Put a built simulation into the checkpoint's state."""
    if data["capacity"] != sim.state.capacity:
        raise UserInputError("The checkpoint's particle capacity differs from this run's: the run "
                             "description or the code changed since it was written.")
    fields, _ = _collect(sim)
    missing = set(data["fields"]) ^ set(fields)
    if missing:
        raise UserInputError("The checkpoint does not match this run's solver state (differs in "
                             f"{', '.join(sorted(missing)[:4])}): the code or the options changed.")
    n, cap = data["n"], data["capacity"]
    for key, arr in data["fields"].items():
        field = fields[key]
        if arr.ndim and field.shape and field.shape[0] == cap and arr.shape[0] == n:
            full = field.to_numpy()
            full[:n] = arr
            arr = full
        field.from_numpy(arr)
    for key, value in data["values"].items():
        obj, name = _resolve(sim, key)
        now = getattr(obj, name, None)
        if isinstance(value, dict) and isinstance(now, dict):
            value = {**now, **value}  # a counter added since the checkpoint starts from its default
        setattr(obj, name, value)
    run = data["run"]
    sim.time_s = run["time_s"]
    sim.steps = run["steps"]
    sim.lost_particles = run["lost_particles"]
    sim.lost_by_face = run.get("lost_by_face", {})  # checkpoints before 2026-12-06 lack them
    sim.lost_times_s = run.get("lost_times_s", [])
    sim.outside_max = run.get("outside_max", 0)  # since 2026-12-07
    sim.outside_by_face = run.get("outside_by_face", {})
    sim.outside_times_s = run.get("outside_times_s", [])
    # since 2026-12-06 (later); the summary's names only (the first day's used shorter ones)
    sim.over_face.update({k: v for k, v in run.get("over_face", {}).items() if k in sim.over_face})
    sim._inlet_retired = run["inlet_retired"]
    sim.skipped = run["skipped"]
    sim.grid.stale = True
