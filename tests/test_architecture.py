"""The layers: no import cycles (imports inside functions count), no argparse or print below
the command line, post-processing without Taichi, every option declared with a check, and
one declaration reaching the command line, the sweeps and config.json."""

import ast
import json
import subprocess
import sys
from dataclasses import field, make_dataclass
from pathlib import Path

import pytest

import taichi_mex
from taichi_mex.options import Material, Positive, RunOptions, opt, unchecked_fields

PACKAGE = Path(taichi_mex.__file__).resolve().parent
#: the command-line layer: the only modules that parse arguments or print
APP = ("app/", "__main__.py")


def _modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        rel = path.relative_to(PACKAGE).with_suffix("")
        parts = [p for p in rel.parts if p != "__init__"]
        out[".".join(["taichi_mex", *parts])] = path
    return out


def _imports(path: Path, module: str, modules: dict) -> set[str]:
    """Every taichi_mex module this file imports, anywhere in it."""
    tree = ast.parse(path.read_text())
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(tree):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1] + ([base] if base else []))
            names = [base] + [f"{base}.{a.name}" for a in node.names]
        for name in names:
            while name and name not in modules:
                name = name.rpartition(".")[0]
            if name and name != module and name != "taichi_mex":
                found.add(name)
    return found


def test_no_import_cycles_counting_imports_inside_functions():
    modules = _modules()
    graph = {m: _imports(p, m, modules) for m, p in modules.items()}
    cycles = []
    state: dict[str, int] = {}

    def visit(node, stack):
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                cycles.append(stack[stack.index(nxt):] + [nxt])
            elif nxt not in state:
                visit(nxt, stack)
        stack.pop()
        state[node] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [])
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


#: Python numbers that change during a run, per object: the live particles and melt rows
LIVE_COUNTS = {"n", "previous_dt", "vmax", "rebuilds", "stale", "released_count",
               "slices_spawned", "speed", "steps", "time_s", "inner_energy"}


def test_no_kernel_reads_a_count_that_changes_during_a_run():
    """Taichi compiles a Python number a kernel reads (self.state.n, say) into the kernel as a
    constant of its first compilation: later launches read that value, not the live one. The
    coupled solve's setup read state.n so, and listed only the walls sorted below the first
    solve's particle count in every later solve (the die swell's surface iteration settled
    on that; 2026-12-06). Such values go to a kernel as arguments."""
    found = []
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if not (isinstance(node, ast.FunctionDef) and any(
                    isinstance(d, ast.Attribute) and d.attr in ("kernel", "func")
                    for d in node.decorator_list)):
                continue
            for sub in ast.walk(node):
                if isinstance(sub, ast.Attribute) and sub.attr in LIVE_COUNTS:
                    base = sub.value
                    while isinstance(base, ast.Attribute):
                        base = base.value
                    if isinstance(base, ast.Name) and base.id == "self":
                        found.append(f"{path.relative_to(PACKAGE)}:{sub.lineno} {node.name}: "
                                     f"{ast.unparse(sub)}")
    assert not found, found


def test_only_the_command_line_parses_arguments_or_prints():
    offenders = []
    for module, path in _modules().items():
        rel = path.relative_to(PACKAGE).as_posix()
        if rel.startswith(APP):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                names = [a.name for a in node.names] + [getattr(node, "module", None) or ""]
                if "argparse" in names:
                    offenders.append(f"{rel}:{node.lineno} imports argparse")
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "print":
                offenders.append(f"{rel}:{node.lineno} prints")
    assert not offenders, "\n".join(offenders)


def test_post_processing_does_not_load_taichi():
    code = ("import sys, taichi_mex.post.analysis, taichi_mex.spec, taichi_mex.options; "
            "print(sorted(m for m in sys.modules if m == 'taichi' or m.startswith('taichi.')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


def test_every_option_has_a_check_and_a_help():
    from taichi_mex.spec import scene_entries

    classes = [RunOptions, Material] + [e.options for e in scene_entries().values()]
    for cls in classes:
        assert unchecked_fields(cls) == [], cls.__name__
    from taichi_mex.spec import option_fields

    for cls in classes:
        for path, f in option_fields(cls, ""):
            assert f.metadata.get("help"), f"{cls.__name__}.{path} has no help"


def test_every_help_page_prints_its_option_help_as_written():
    """argparse formats help text with %; an option's prose ('+6 % at ...') must come out
    verbatim, not as a dump of the argument's internals."""
    import argparse

    from taichi_mex.app.parsing import add_spec_flags
    from taichi_mex.spec import scene_entries

    for scene in scene_entries():
        parser = argparse.ArgumentParser(prog="test")
        add_spec_flags(parser, scene)
        page = parser.format_help()
        assert "option_strings" not in page, scene
    parser = argparse.ArgumentParser(prog="test")
    add_spec_flags(parser, "print")
    assert "+6 % at a Hencky strain" in " ".join(parser.format_help().split())


def test_one_declaration_reaches_the_command_line_sweeps_and_config(tmp_path, monkeypatch):
    """Add one option to a scene's options class: its flag, its sweep name and its place in
    config.json follow without any other edit."""
    from taichi_mex.app import jobs
    from taichi_mex.app.parsing import Parser, add_spec_flags, spec_changes
    from taichi_mex.scenes import collapse
    from taichi_mex.scenes.registry import SCENES, SceneEntry
    from taichi_mex.spec import RunSpec

    base = collapse.CollapseOptions
    grown = make_dataclass("GrownCollapseOptions", [(
        "tilt_deg", float, opt(0.0, help="plate tilt (degrees)", check=Positive(),
                               flag="--tilt", names=("tilt",)))], bases=(base,))
    old = SCENES["collapse"]
    monkeypatch.setitem(SCENES, "collapse", SceneEntry(
        "collapse", old.help, grown, lambda o: collapse.CollapseScene(), old.defaults))
    p = Parser(prog="test")
    dests = add_spec_flags(p, "collapse")
    changes = spec_changes(p.parse_args(["--tilt", "2.5"]), dests)
    assert changes == {"scene.tilt_deg": 2.5}
    spec = RunSpec.create("collapse", changes=changes)
    assert jobs.resolve({"scene": "collapse", "tilt": 1.5}).spec.options.tilt_deg == 1.5
    spec.write(tmp_path)
    data = json.loads((tmp_path / "config.json").read_text())
    assert data["scene_options"]["tilt_deg"] == 2.5
    assert RunSpec.load(tmp_path) == spec
    with pytest.raises(taichi_mex.errors.UserInputError, match="tilt_deg"):
        RunSpec.create("collapse", changes={"tilt": -1.0})


def test_readme_is_a_guide_with_the_two_commands():
    text = (PACKAGE.parent / "README.md").read_text()
    assert len(text) < 15_000
    assert "pip install . && python -m taichi_mex --out run" in text
    assert "pip install '.[test]' && python -m pytest" in text


def test_old_module_paths_still_import_and_say_where_they_moved():
    code = ("import sys, warnings; warnings.simplefilter('always'); "
            "import taichi_mex.analysis as a, taichi_mex.config as c; "
            "print(hasattr(a, 'analyse_run'), hasattr(c, 'RunOptions'), 'taichi' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.stdout.strip() == "True True False", out.stderr
    assert "taichi_mex.analysis moved to taichi_mex.post.analysis" in out.stderr


def test_every_validation_case_has_its_table_and_its_pictures_are_shown():
    """Each case of validation/regenerate.py rewrites a table its README marks, and each
    picture a case keeps exists and is shown by some page."""
    import importlib.util

    root = PACKAGE.parent
    spec = importlib.util.spec_from_file_location("regenerate", root / "validation" / "regenerate.py")
    regenerate = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(regenerate)
    pages = "\n".join(p.read_text() for p in [root / "README.md", *root.glob("validation/*/README.md")])
    for name, case in regenerate.CASES.items():
        text = (root / "validation" / (case.folder or name) / "README.md").read_text()
        tag = f":{case.tag}" if case.tag else ""
        assert f"<!-- table:begin{tag} -->" in text and f"<!-- table:end{tag} -->" in text, name
        for _, _, dest in case.figures:
            assert (root / dest).is_file(), (name, dest)
            assert Path(dest).name in pages, (name, dest)
