"""Command line: the dry-run plan and one-paragraph errors (exit 2, no traceback)."""

import json
import subprocess
import sys

import pytest

from taichi_mex import bundled
from taichi_mex.errors import UserInputError
from taichi_mex.app.cli import main

PLAN_KEYS = {"print_time_s", "extruding_time_s", "extruded_volume_mm3", "n_layers",
             "selected_extruded_volume_mm3"}


def test_dry_run_on_bundled_default(tmp_path, capsys):
    assert main(["--dry-run", "--out", str(tmp_path)]) == 0
    plan = json.loads((tmp_path / "plan.json").read_text())
    assert PLAN_KEYS <= plan.keys()
    assert plan["gcode"].endswith(bundled.DEFAULT_GCODE)
    assert plan["selected_extruded_volume_mm3"] == pytest.approx(plan["extruded_volume_mm3"])
    out = capsys.readouterr().out
    assert "selected layers 1" in out
    assert "estimate: " in out and "steps of" in out  # the cost, before committing to the run


def test_a_print_takes_the_coupled_solve_and_either_surface_condition():
    """A print's creeping melt takes the coupled solve without the surface traction by
    default; --creeping-solve split and --surface-traction change that; a collapse takes the
    coupled solve too."""
    from taichi_mex.app.cli import print_parser, spec_from_args

    def solve(*argv):
        parser, dests = print_parser()
        d = spec_from_args(parser.parse_args(list(argv)), dests, "print").run.dfsph
        return d.creeping_solve, d.stokes_surface_traction

    assert solve() == ("coupled", False)
    assert solve("--surface-traction") == ("coupled", True)
    assert solve("--surface-traction", "--no-surface-traction") == ("coupled", False)
    assert solve("--creeping-solve", "split")[0] == "split"
    from taichi_mex.spec import RunSpec
    assert RunSpec.create("collapse").run.dfsph.creeping_solve == "coupled"


def test_the_nozzles_face_is_a_flag():
    """--nozzle-tip-mm sets the flat face's outer diameter ('none': no face); the width of a
    strand follows it (validation/strands, "The nozzle's flat face")."""
    from taichi_mex.app.cli import print_parser, spec_from_args

    def face(*argv):
        parser, dests = print_parser()
        return spec_from_args(parser.parse_args(list(argv)), dests, "print").options \
            .nozzle_tip_outer_diameter_mm

    assert face() == 1.0
    assert face("--nozzle-tip-mm", "0.6") == 0.6
    assert face("--nozzle-tip-mm", "none") is None
    with pytest.raises(UserInputError, match="neither a number"):
        face("--nozzle-tip-mm", "wide")


def test_pygcodedecode_examples_by_name(tmp_path):
    """pygcodedecode:NAME is one of pyGCodeDecode's example prints (the window benchmarks run
    its benchy); an unknown name lists the ones there are. At 0.1 mm the whole triangle
    plans 0.3 M particles in ~3.5 GiB; at the default spacing, 1.6 M and ~19 GiB, the memory
    check refused it on a machine with 22.9 GiB free."""
    assert bundled.resolve_gcode("pygcodedecode:triangle") == bundled.pygcd_example("triangle.gcode")
    assert main(["pygcodedecode:triangle", "--resolution", "0.1", "--dry-run",
                 "--out", str(tmp_path)]) == 0
    assert json.loads((tmp_path / "plan.json").read_text())["gcode"].endswith("triangle.gcode")
    with pytest.raises(UserInputError, match="pygcodedecode:benchy"):
        bundled.resolve_gcode("pygcodedecode:nosuchpart")
    with pytest.raises(UserInputError):
        bundled.resolve_gcode("pygcodedecode:../data/triangle")


def test_dry_run_selection_is_reported(tmp_path):
    gcode = bundled.gcode_path("block_3x3")
    assert main([str(gcode), "--dry-run", "--out", str(tmp_path), "--layers", "2-3",
                 "--region", "10:11.5,9:11"]) == 0
    plan = json.loads((tmp_path / "plan.json").read_text())
    assert plan["n_layers"] == 3 and plan["selected_layers"] == "2-3"
    # 2 layers x 3 beads x half of each 3 mm bead
    assert plan["selected_extruded_volume_mm3"] == pytest.approx(plan["extruded_volume_mm3"] / 3, rel=1e-6)
    assert main([str(gcode), "--dry-run", "--out", str(tmp_path), "--until", "0.5"]) == 0
    early = json.loads((tmp_path / "plan.json").read_text())
    assert 0 < early["selected_extruded_volume_mm3"] < plan["selected_extruded_volume_mm3"]


def test_dry_run_plans_through_the_last_selected_layer(tmp_path, capsys):
    """A run never reads what follows its last layer, so the plan stops there (benchy's layer
    3: 2.4 s against 38 s for the whole file) and says so; the selection is the same."""
    from taichi_mex.toolpath.plan import make_plan

    gcode = bundled.gcode_path("block_3x3")
    assert main([str(gcode), "--dry-run", "--out", str(tmp_path), "--layers", "1-2"]) == 0
    assert "planned through layer 2 of 3" in capsys.readouterr().out
    plan = json.loads((tmp_path / "plan.json").read_text())
    assert (plan["planned_through_layer"], plan["layers_in_file"], plan["n_layers"]) == (2, 3, 2)
    whole = make_plan(gcode, layers=[1, 2]).as_dict()
    assert whole["planned_through_layer"] is None and whole["layers_in_file"] == 3
    assert plan["selected_extruded_volume_mm3"] == pytest.approx(whole["selected_extruded_volume_mm3"], rel=1e-9)
    assert plan["selected_time_window_s"][0] == pytest.approx(whole["selected_time_window_s"][0], abs=1e-9)


@pytest.mark.parametrize("args, fragment", [
    (["missing.gcode"], "does not exist"),
    (["--printer", "nosuchprinter"], "Unknown printer"),
    (["--layers", "7"], "do not exist"),
    (["--layers", "x"], "Cannot read layers"),
    (["--region", "50:60,50:60"], "deposits nothing"),
    (["--until", "-1"], "must be positive"),
    (["--no-such-option"], "unrecognized arguments"),
])
def test_bad_input_is_one_paragraph(tmp_path, capsys, args, fragment):
    assert main(args + ["--dry-run", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and fragment in err
    assert "Traceback" not in err


@pytest.mark.parametrize("body, fragment", [
    ("G1 X0 Y0 Z0.2\nG2 X5 Y5 I2 J2 E1\n", "arc"),
    ("G20\nG1 X1 Y1 Z0.01 E0.1\n", "inch"),
])
def test_arc_and_inch_files_exit_2_without_traceback(tmp_path, body, fragment):
    path = tmp_path / "bad.gcode"
    path.write_text(body)
    proc = subprocess.run([sys.executable, "-m", "taichi_mex", str(path), "--dry-run",
                           "--out", str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert fragment in proc.stderr and "Traceback" not in proc.stderr


def test_run_warnings_name_lost_melt_and_unconverged_viscous_solves():
    from taichi_mex.app.cli import run_warnings
    from taichi_mex.options import RunOptions

    run = RunOptions(scheme="dfsph")
    clean = {"particles_lost": 0, "viscosity_residual_worst": 9.9e-4}
    assert run_warnings(clean, run) == []
    assert run_warnings({"particles_lost": 0}, run) == []  # EDAC: no viscous solve
    bad = run_warnings({"particles_lost": 11, "viscosity_residual_worst": 1.68}, run)
    assert len(bad) == 2
    assert bad[0].startswith("11 melt particles were dropped: their positions were not finite")
    outside = {"particles_lost": 0, "melt_outside_domain_max": 3,
               "melt_outside_domain_by_face": {"top": 2, "x_min": 1},
               "melt_outside_domain_between_s": [0.5, 1.25]}
    where = run_warnings(outside, run)
    assert where[0].startswith("up to 3 melt particles were outside the domain's box at once "
                               "(2 beyond top, 1 beyond x min, t = 0.5-1.25 s): kept")
    from taichi_mex.post.report import _health  # and the report's health table says the same
    assert "3 (2 beyond top, 1 beyond x min, t = 0.5-1.25 s)" in _health(outside)
    assert "1.7 against 0.001" in bad[1] and "viscosity_max_iterations (500)" in bad[1]
    carried = {"particles_lost": 0, "melt_over_face_fraction_max": 0.231,
               "melt_over_face_max_at_s": 1.664, "melt_over_face_fraction": 0.108,
               "melt_over_face_at_s": 2.555}
    on = run_warnings(carried, run)
    assert len(on) == 1 and on[0].startswith(
        "melt stood over the nozzle's tip face (23 % of the melt at t = 1.664 s, 11 % at "
        "t = 2.555 s)")
    assert run_warnings({**carried, "melt_over_face_fraction_max": 0.009}, run) == []
    assert "23 % of the melt at t = 1.664 s" in _health(carried)
    assert "none" in _health({**carried, "melt_over_face_fraction_max": 0.0})


def test_the_reports_law_names_the_nozzles_face():
    """The report compares sections with the slicer's rounded rectangle, names the face the
    run's melt spread under and says how far this solver's strands are from it."""
    from taichi_mex.post.report import law_note

    note = law_note(0.2, {"scene_options": {"nozzle_tip_outer_diameter_mm": 0.6}})
    assert "g = 0.2 mm" in note and "0.6 mm across" in note
    assert "a nozzle's flat face" in law_note(0.2, {"scene_options": {"nozzle_tip_outer_diameter_mm": None}})
    assert "a nozzle's flat face" in law_note(0.2, None)
    assert "This solver's strands" in note


def test_lost_and_outside_melt_are_worded_by_where_they_went():
    from taichi_mex.post.report import lost_melt_where

    lost = {"particles_lost_by_face": {"not_finite": 2}, "particles_lost_between_s": [0.5, 1.25]}
    assert lost_melt_where(lost) == "2 with a position not finite, t = 0.5-1.25 s"
    out = {"melt_outside_domain_by_face": {"top": 2, "x_min": 1}}
    assert lost_melt_where(out, "melt_outside_domain") == "2 beyond top, 1 beyond x min"
    assert lost_melt_where({}) == ""
