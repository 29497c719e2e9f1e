"""The run description: which scene, its options, the run options and the material.

One typed object, built from a dict and turned back into one, validated in one place. It is
the only path from the command line, the Python API, sweeps, studies and the stability
matrix to a :class:`~taichi_mex.sim.simulation.Simulation`, and every run writes it as
``config.json`` in its output folder:

    from taichi_mex.spec import RunSpec
    from taichi_mex.sim.simulation import Simulation

    spec = RunSpec.create("print", changes={"run.spacing_mm": 0.0667, "scene.until_s": 0.05})
    summary = Simulation.from_spec(spec, out_dir="run").run()
    again = RunSpec.load("run/config.json")        # the same run

Changes are dotted paths from the root: ``scene.OPTION``, ``run.FIELD``, ``run.dfsph.FIELD``,
``material.FIELD``. Flat names (``viscosity``, ``spacing_mm``, ``until`` ...) are the aliases
the option declarations list (:func:`dotted_name`).
"""

from __future__ import annotations

import difflib
import json
import types
import typing
from dataclasses import MISSING, asdict, dataclass, field, fields, is_dataclass, replace
from pathlib import Path

from taichi_mex.errors import UserInputError
from taichi_mex.options import PRESETS, Material, RunOptions, validate_fields

#: bump when a config.json written by this version cannot be read by the last one
FORMAT_VERSION = 1
FORMAT_NAME = "taichi_mex run description"


def scene_entries() -> dict:
    """name -> SceneEntry of every scene (importing a scene module registers it)."""
    from taichi_mex.scenes import (collapse, couette, dam_break, die_swell, hydrostatic,  # noqa: F401
                                   print, bore_flow, extension, shear, squeeze_film, thermal_beam)
    from taichi_mex.scenes.registry import SCENES

    return SCENES


def scene_entry(name: str):
    entries = scene_entries()
    if name not in entries:
        close = difflib.get_close_matches(name, list(entries), 1)
        raise UserInputError(f"Unknown scene '{name}'" + (f" (did you mean '{close[0]}'?)" if close else "")
                             + f"; choose one of {', '.join(entries)}.")
    return entries[name]


# ----------------------------------------------------------------------------- option walking
def option_fields(cls, prefix: str):
    """(dotted path, dataclass field) of every leaf option under a dataclass type."""
    for f in fields(cls):
        default = f.default_factory() if f.default_factory is not MISSING else f.default
        if is_dataclass(default):
            yield from option_fields(type(default), f"{prefix}{f.name}.")
        else:
            yield prefix + f.name, f


def spec_fields(scene: str):
    """Every option of a run of this scene: (dotted path, field)."""
    yield from option_fields(scene_entry(scene).options, "scene.")
    yield from option_fields(RunOptions, "run.")
    yield from option_fields(Material, "material.")


def dotted_name(name: str, scene: str) -> str | None:
    """A flat name (a field's declared alias or its own name) or a dotted path -> the dotted
    path; None when nothing matches."""
    table = {}
    for path, f in spec_fields(scene):
        table[path] = path
        for alias in f.metadata.get("names", ()):
            table.setdefault(alias, path)
    for path, f in option_fields(scene_entry(scene).options, "scene."):
        table.setdefault(path.removeprefix("scene."), path)  # a scene's own options by name
        for alias in f.metadata.get("names", ()):
            table.setdefault("scene." + alias, path)
    if name not in table and name.startswith("scene."):
        # studies written before the run description reached run options as scene.OPTION
        rest = name.removeprefix("scene.")
        if rest in table:
            return table[rest]
        ends = [path for path in table if path.endswith("." + rest) and "." in path]
        return ends[0] if len(set(ends)) == 1 else None
    return table.get(name)


def field_at(scene: str, path: str):
    for p, f in spec_fields(scene):
        if p == path:
            return f
    return None


# ----------------------------------------------------------------------------- coercion
def _coerce(value, hint, where: str):
    """A JSON/TOML value -> the field's Python type (ints where floats go, lists -> tuples);
    wrong kinds are refused with the option's name."""
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        for arg in args:
            try:
                return _coerce(value, arg, where)
            except UserInputError:
                continue
        raise UserInputError(f"Option {where} = {value!r} has the wrong type (expected "
                             f"{' or '.join(getattr(a, '__name__', str(a)) for a in args)}).")
    if hint is type(None):
        if value is None:
            return None
        raise UserInputError(f"Option {where} = {value!r} should be None.")
    if hint is bool:
        if isinstance(value, bool):
            return value
        raise UserInputError(f"Option {where} = {value!r} should be true or false.")
    if hint is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        raise UserInputError(f"Option {where} = {value!r} should be a number.")
    if hint is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        if isinstance(value, float) and value.is_integer():
            return int(value)
        raise UserInputError(f"Option {where} = {value!r} should be a whole number.")
    if hint is str:
        if isinstance(value, str):
            return value
        raise UserInputError(f"Option {where} = {value!r} should be text.")
    if hint is tuple or origin is tuple:
        if isinstance(value, (list, tuple)):
            return tuple(tuple(v) if isinstance(v, list) else v for v in value)
        raise UserInputError(f"Option {where} = {value!r} should be a list.")
    return value


#: options a run description may still hold from an earlier version, and why they are gone
_EJECTION = ("removed on 2026-12-05 with the split solve's droplet ejection and speed clamp "
             "(they deleted or slowed melt; nothing replaces them)")
_CREEPING = ("removed on 2026-12-05: it held the split solve together in a creeping melt, which "
             "now takes the coupled solve (--creeping-solve coupled, the default; the split "
             "solve refuses a creeping melt)")
REMOVED_OPTIONS = {
    **{f"run.dfsph.stabilisers.{name}": _EJECTION
       for name in ("isolated_neighbours", "eject_speed_factor", "clamp_speed_factor",
                    "clamp_alarm")},
    **{f"run.dfsph.stabilisers.{name}": _CREEPING
       for name in ("tension_form", "release_growing_only", "speed_scale_m_s",
                    "closing_speed_factor")},
    **{f"run.dfsph.{name}": _CREEPING
       for name in ("compression_check", "compression_corrections", "inlet_rows",
                    "inlet_row_min_coupling", "correction_in_pressure")},
    "run.dfsph.stabilisers.creeping_diffusion": "moved on 2026-12-05 to "
    "run.dfsph.creeping_diffusion (it says which steps are creeping, and stabilises nothing)",
    "run.dfsph.stokes_viscous_operator": "replaced on 2026-12-05 by "
    "run.dfsph.stokes_viscous_isotropic_share, the share of Morris's term in each pair term "
    "('weiler2018': 0, 'espanol_revenga2003': 0.5, 'morris1997': 1; unset: 0.1)",
}


def _build(cls, data: dict, where: str):
    """A dataclass from a (partial) dict; unknown keys refused with a suggestion."""
    if not isinstance(data, dict):
        raise UserInputError(f"{where or 'the run description'} should be a table of options, "
                             f"not {data!r}.")
    hints = typing.get_type_hints(cls)
    known = {f.name: f for f in fields(cls)}
    values = {}
    for key, value in data.items():
        if key not in known and f"{where}{key}" in REMOVED_OPTIONS:
            raise UserInputError(f"Option {where}{key} was {REMOVED_OPTIONS[where + key]}: delete "
                                 "it from the run description to run it with this version.")
        if key not in known:
            close = difflib.get_close_matches(key, known, 1)
            raise UserInputError(f"Unknown option {where}{key}" + (f" (did you mean {where}{close[0]}?)"
                                                                  if close else "")
                                 + f"; {where.rstrip('.') or cls.__name__} has "
                                 + ", ".join(known) + ".")
        f = known[key]
        default = f.default_factory() if f.default_factory is not MISSING else f.default
        if is_dataclass(default):
            values[key] = _build(type(default), value, f"{where}{key}.")
        else:
            values[key] = _coerce(value, hints[key], where + key)
    return cls(**values)


def _set(obj, parts: list[str], value, where: str, hint_owner=None):
    """A copy of a dataclass with the field at parts (nested) replaced."""
    name = parts[0]
    known = {f.name for f in fields(obj)}
    if name not in known:
        close = difflib.get_close_matches(name, known, 1)
        raise UserInputError(f"Unknown option {where}{name}" + (f" (did you mean {where}{close[0]}?)"
                                                               if close else "") + ".")
    current = getattr(obj, name)
    if len(parts) > 1:
        if not is_dataclass(current):
            raise UserInputError(f"{where}{name} is not a group of options.")
        return replace(obj, **{name: _set(current, parts[1:], value, f"{where}{name}.")})
    if is_dataclass(current):
        if isinstance(value, dict):
            return replace(obj, **{name: _merge(current, value, f"{where}{name}.")})
        raise UserInputError(f"{where}{name} is a group of options; name one of its fields.")
    hint = typing.get_type_hints(type(obj))[name]
    meta = next(f.metadata for f in fields(obj) if f.name == name)
    parse = meta.get("parse")
    if parse is not None and isinstance(value, str):
        value = parse(value)
    return replace(obj, **{name: _coerce(value, hint, where + name)})


def _merge(obj, changes: dict, where: str):
    for key, value in changes.items():
        obj = _set(obj, [key], value, where)
    return obj


# ----------------------------------------------------------------------------- the description
@dataclass
class RunSpec:
    """A whole run: ``scene`` (a registered scene name, 'print' for G-code), its typed
    ``options``, the ``run`` options, the ``material``, and the ``preset`` it started from
    (provenance only: its values are already in the other fields)."""

    scene: str = "print"
    options: object = None
    run: RunOptions = field(default_factory=RunOptions)
    material: Material = field(default_factory=Material)
    preset: str | None = None
    #: the shipped material name or TOML file the material came from (provenance only)
    material_source: str | None = None

    def __post_init__(self):
        if self.options is None:
            self.options = scene_entry(self.scene).options()

    # ------------------------------------------------------------------ building
    @classmethod
    def create(cls, scene: str = "print", preset: str | None = None,
               changes: dict | None = None, material: str | None = None) -> RunSpec:
        """The scene's defaults, then the preset, then ``material`` (a shipped name or a
        TOML file, :mod:`taichi_mex.materials`), then ``changes`` (dotted paths or flat
        names); validated. A change whose option declares ``implies`` also sets those
        options, unless ``changes`` sets them itself."""
        entry = scene_entry(scene)
        changes = dict(changes or {})
        dotted = _dotted(changes, scene)
        for path, value in list(dotted.items()):
            f = field_at(scene, path)
            for implied, implied_value in f.metadata.get("implies", {}).items():
                dotted.setdefault(implied, implied_value)
        preset_data = {}
        if preset is not None:
            if preset not in PRESETS:
                raise UserInputError(f"Unknown preset '{preset}'; choose {', '.join(sorted(PRESETS))}.")
            preset_data = PRESETS[preset]
            if preset_data.get("scene", "print") != scene:
                raise UserInputError(f"Preset '{preset}' is for {preset_data.get('scene', 'print')} "
                                     f"runs, not scene '{scene}'.")
        options = entry.options()
        options = _merge(options, preset_data.get("scene_options", {}), "scene.")
        for path, value in dotted.items():
            if path.startswith("scene."):
                options = _set(options, path.split(".")[1:], value, "scene.")
        defaults = entry.defaults(options)
        run = _merge(RunOptions(), defaults.get("run", {}), "run.")
        mat = _merge(Material(), defaults.get("material", {}), "material.")
        run = _merge(run, preset_data.get("run", {}), "run.")
        mat = _merge(mat, preset_data.get("material", {}), "material.")
        source = None
        if material is not None:
            from taichi_mex import materials

            values, _sources = materials.read(material)
            mat = _merge(mat, values, "material.")
            source = str(material)
        for path, value in dotted.items():
            root, _, rest = path.partition(".")
            if root == "run":
                run = _set(run, rest.split("."), value, "run.")
            elif root == "material":
                mat = _set(mat, rest.split("."), value, "material.")
        spec = cls(scene, options, run, mat, preset, source)
        spec.validate()
        return spec

    def with_changes(self, changes: dict) -> RunSpec:
        """A copy with dotted paths (or flat names) changed, then validated; ``implies`` is
        not applied (the description already holds what was implied)."""
        out = replace(self)
        for path, value in _dotted(changes, self.scene).items():
            root, _, rest = path.partition(".")
            target = {"scene": "options"}.get(root, root)
            setattr(out, target, _set(getattr(out, target), rest.split("."), value, root + "."))
        out.validate()
        return out

    def validate(self) -> None:
        entry = scene_entry(self.scene)
        if not isinstance(self.options, entry.options):
            raise UserInputError(f"Scene '{self.scene}' takes {entry.options.__name__}, not "
                                 f"{type(self.options).__name__}.")
        validate_fields(self.options, "scene.")
        check = getattr(self.options, "validate", None)
        if check is not None:
            check()
        self.run.validate()
        self.material.validate()

    def build_scene(self):
        """The scene object these options describe (plans G-code for prints)."""
        return scene_entry(self.scene).build(self.options)

    # ------------------------------------------------------------------ dict and file
    def to_dict(self) -> dict:
        """The description as config.json holds it (tuples as lists), so that a description
        and the file it was written to compare equal."""
        from taichi_mex import __version__

        return json.loads(json.dumps({
            "format": FORMAT_NAME, "format_version": FORMAT_VERSION, "taichi_mex": __version__,
            "scene": self.scene, "preset": self.preset, "material_source": self.material_source,
            "scene_options": asdict(self.options),
            "run": asdict(self.run), "material": asdict(self.material)}))

    @classmethod
    def from_dict(cls, data: dict) -> RunSpec:
        """The inverse of :meth:`to_dict`; missing options take their defaults (not the
        scene's: a description lists what it means), unknown ones are refused."""
        if not isinstance(data, dict):
            raise UserInputError("A run description is a table with scene, scene_options, run and "
                                 "material.")
        version = data.get("format_version", FORMAT_VERSION)
        if not isinstance(version, int) or version > FORMAT_VERSION:
            raise UserInputError(f"This run description has format version {version!r}; this "
                                 f"taichi_mex reads up to {FORMAT_VERSION}. Update taichi_mex.")
        extra = set(data) - {"format", "format_version", "taichi_mex", "scene", "preset",
                             "material_source", "scene_options", "run", "material"}
        if extra:
            raise UserInputError(f"Unknown keys in the run description: {', '.join(sorted(extra))}.")
        scene = data.get("scene", "print")
        entry = scene_entry(scene)
        spec = cls(scene, _build(entry.options, data.get("scene_options", {}), "scene."),
                   _build(RunOptions, data.get("run", {}), "run."),
                   _build(Material, data.get("material", {}), "material."), data.get("preset"),
                   data.get("material_source"))
        spec.validate()
        return spec

    def write(self, out_dir) -> Path:
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        path = out_dir / "config.json"
        path.write_text(json.dumps(self.to_dict(), indent=2) + "\n")
        return path

    @classmethod
    def load(cls, path) -> RunSpec:
        path = Path(path)
        if path.is_dir():
            path = path / "config.json"
        try:
            data = json.loads(path.read_text())
        except FileNotFoundError:
            raise UserInputError(f"No run description at {path}.") from None
        except (OSError, ValueError) as exc:
            raise UserInputError(f"{path} is not a readable run description: {exc}.") from None
        return cls.from_dict(data)


def _dotted(changes: dict, scene: str) -> dict:
    """Changes keyed by dotted paths; an unknown name is refused with a suggestion."""
    out = {}
    for key, value in changes.items():
        path = dotted_name(key, scene)
        if path is None:
            raise UserInputError(_unknown(key, scene))
        out[path] = value
    return out


def _unknown(name: str, scene: str) -> str:
    names = set()
    for path, f in spec_fields(scene):
        names.add(path)
        names.update(f.metadata.get("names", ()))
    close = difflib.get_close_matches(name, sorted(names), 1)
    return (f"Unknown option '{name}'" + (f" (did you mean '{close[0]}'?)" if close else "")
            + f" for a {scene} run; options are scene.OPTION, run.FIELD, run.dfsph.FIELD, "
            "material.FIELD or one of the flat names 'python -m taichi_mex sweep --list-params' lists.")
