"""Toolpath: the vectorised sampler against pyGCodeDecode, volume bookkeeping, pitfalls."""

import math

import numpy as np
import pytest
from conftest import pygcd_example

from taichi_mex import bundled
from taichi_mex.errors import GCodeError, UserInputError
from taichi_mex.toolpath.trajectory import load_printer, load_trajectory, parse_layers, parse_region

A_175 = math.pi * 1.75**2 / 4  # filament cross-section (mm^2) of prusa_mini
HEAD = "G21\nG90\nM82\nG92 E0\n"


def _pygcd_simulation(path, printer="prusa_mini"):
    from pyGCodeDecode import gcode_interpreter as gci

    return gci.simulation(gcode_path=path, machine_name=printer, verbosity_level=0)


@pytest.mark.parametrize("source", [pygcd_example("triangle.gcode"), bundled.gcode_path("corner")])
def test_sampler_matches_get_values(source):
    """Our arrays reproduce pyGCodeDecode's own get_values at random times (1e-6 mm)."""
    traj = load_trajectory(source, "prusa_mini")
    sim = _pygcd_simulation(source)
    rng = np.random.default_rng(7)
    times = np.sort(rng.uniform(0.0, traj.print_time_s * 0.999, 60))
    ours = traj.sample(times)
    for k, t in enumerate(times):
        vel, pos = sim.get_values(float(t))
        np.testing.assert_allclose(ours.position_mm[k], pos[:3], atol=1e-6)
        np.testing.assert_allclose(ours.e_mm[k], pos[3], atol=1e-6)
        np.testing.assert_allclose(ours.velocity_mm_s[k], vel[:3], atol=1e-6)
        np.testing.assert_allclose(ours.e_rate_mm_s[k], vel[3], atol=1e-6)
    assert traj.print_time_s == pytest.approx(float(sim.blocklist[-1].get_segments()[-1].t_end))


def test_volume_bookkeeping_hand_computed(write_gcode):
    """Travel, retraction, E-only prime and two beads: only the beads count."""
    text = HEAD + (
        "G1 X10 Y10 Z0.2 F6000\n"  # travel
        "G1 X20 E0.5 F1800\n"  # bead 1: 0.5 mm filament
        "G1 E-0.3 F2400\n"  # retraction
        "G1 X30 F6000\n"  # travel
        "G1 E0.5 F2400\n"  # prime (E-only): back to 0.5 + 0
        "G1 X30 Y20 E1.25 F1800\n"  # bead 2: 0.75 mm filament
    )
    traj = load_trajectory(write_gcode(text))
    assert traj.extruded_volume_mm3 == pytest.approx((0.5 + 0.75) * A_175, rel=1e-9)
    intervals = traj.extruding_intervals()
    assert len(intervals) == 2
    assert traj.extruding_time_s == pytest.approx(float(np.sum(intervals[:, 1] - intervals[:, 0])))
    # the bead-2 interval is the move from (30,10) to (30,20): both ends at x = 30
    s = traj.sample(intervals[1])
    np.testing.assert_allclose(s.position_mm[:, 0], [30, 30], atol=1e-9)
    np.testing.assert_allclose(s.position_mm[:, 1], [10, 20], atol=1e-9)
    # cumulative volume is monotone and reaches the total at the end
    v = traj.extruded_volume_until(np.linspace(0, traj.print_time_s, 200))
    assert np.all(np.diff(v) >= -1e-12)
    assert v[-1] == pytest.approx(traj.extruded_volume_mm3, rel=1e-12)


def test_volume_of_bundled_single_bead_matches_header_flow():
    """5 mm x (0.45 x 0.2 rounded rectangle) = 0.40708 mm^3, to the G-code's 5 digits."""
    traj = load_trajectory(bundled.gcode_path("single_bead"))
    area = (0.45 - 0.2) * 0.2 + math.pi * 0.2**2 / 4
    assert traj.extruded_volume_mm3 == pytest.approx(5 * area, rel=1e-4)
    assert traj.n_layers == 1 and traj.layer_z_mm[1] == pytest.approx(0.2)


def test_g92_nonzero_e_is_corrected(write_gcode):
    """pyGCodeDecode offsets 'G92 E5' with the wrong sign; we plan it right."""
    text = HEAD + "G1 X0 Y0 Z0.2 F6000\nG92 E5\nG1 X10 E6 F1800\nG92 E2\nG1 X20 E2.5\n"
    path = write_gcode(text)
    traj = load_trajectory(path)
    assert traj.extruded_volume_mm3 == pytest.approx(1.5 * A_175, rel=1e-9)
    raw = _pygcd_simulation(path)
    e_raw_end = raw.blocklist[-1].get_segments()[-1].pos_end.get_vec(withExtrusion=True)[3]
    assert abs(e_raw_end - 1.5) > 1.0  # the pitfall this test guards against is real


def test_g92_xyz_offset_moves_physically(write_gcode):
    text = HEAD + "G1 X10 Y10 Z0.2 F6000\nG92 X0 Y0\nG1 X5 E0.2 F1800\n"
    traj = load_trajectory(write_gcode(text))
    s = traj.sample([traj.print_time_s])
    np.testing.assert_allclose(s.position_mm[0], [15, 10, 0.2], atol=1e-9)


def test_lowercase_and_zero_padded_commands(write_gcode):
    upper = load_trajectory(write_gcode(HEAD + "G1 X0 Y0 Z0.2 F6000\nG1 X10 E0.4 F1800\n", "a.gcode"))
    lower = load_trajectory(write_gcode(HEAD.lower() + "g01 x0 y0 z0.2 f6000\ng1 x10 e0.4 f1800\n", "b.gcode"))
    assert lower.extruded_volume_mm3 == pytest.approx(upper.extruded_volume_mm3, rel=1e-12)
    assert lower.print_time_s == pytest.approx(upper.print_time_s, rel=1e-12)


def test_free_text_commands_do_not_move(write_gcode):
    text = HEAD + "G1 X0 Y0 Z0.2 F6000\nM117 G1 X99 E99\nG1 X10 E0.4 F1800\n"
    traj = load_trajectory(write_gcode(text))
    assert traj.extruded_volume_mm3 == pytest.approx(0.4 * A_175, rel=1e-12)
    assert traj.gcode.ignored_commands["M117"] == 1


def test_flow_factor_m221(write_gcode):
    text = "G21\nG90\nM83\nM221 S90\nG1 X0 Y0 Z0.2 F6000\nG1 X10 E1.0 F1800\n"
    traj = load_trajectory(write_gcode(text))
    assert traj.extruded_volume_mm3 == pytest.approx(0.9 * A_175, rel=1e-12)


@pytest.mark.parametrize("line", ["G2 X10 Y10 I5 J0 E1", "G03 X10 Y10 R5 E1"])
def test_arcs_are_refused(write_gcode, line):
    with pytest.raises(GCodeError, match="arc"):
        load_trajectory(write_gcode(HEAD + "G1 X0 Y0 Z0.2\n" + line + "\n"))


def test_inches_are_refused(write_gcode):
    with pytest.raises(GCodeError, match="inch"):
        load_trajectory(write_gcode("G20\nG90\nG1 X1 Y1 Z0.01 E0.1\n"))


@pytest.mark.parametrize("text, fragment", [
    ("G1 X1.2.3 E1\n", "line 1"),
    ("G1 X10 Q5 E1\n", "Malformed G1"),
    ("; only a comment\n", "never moves"),
    ("G1 X10 Y10 F3000\n", "never extrudes"),
    ("G1 X10 F0\n", "not positive"),
])
def test_malformed_files(write_gcode, text, fragment):
    with pytest.raises(GCodeError, match=fragment):
        load_trajectory(write_gcode(text))


def test_binary_and_missing_files(tmp_path):
    binary = tmp_path / "x.bgcode"
    binary.write_bytes(b"GCDE\x00\x01\xff\xfe" * 10)
    with pytest.raises(GCodeError, match="binary"):
        load_trajectory(binary)
    with pytest.raises(GCodeError, match="does not exist"):
        load_trajectory(tmp_path / "missing.gcode")


def test_sampling_past_the_end_is_a_clear_error():
    traj = load_trajectory(bundled.gcode_path("single_bead"))
    with pytest.raises(UserInputError, match="outside the print"):
        traj.sample([traj.print_time_s + 1.0])
    end = traj.sample([traj.print_time_s + 1.0], clip=True)
    np.testing.assert_allclose(end.position_mm, traj.sample([traj.print_time_s]).position_mm)


TWO_LAYERS = "G1 X0 Y0 Z0.2 F6000\n{c1}\nG1 X10 E0.4 F1800\nG1 Z0.4\n{c2}\nG1 X0 E0.4\n"


@pytest.mark.parametrize("c1, c2", [
    (";LAYER_CHANGE", ";LAYER_CHANGE"),  # PrusaSlicer
    (";LAYER:0", ";LAYER:1"),  # Cura
    ("; layer 1, Z = 0.200", "; layer 2, Z = 0.400"),  # Simplify3D
    ("; nothing", "; nothing"),  # no cues: Z of extruding moves
])
def test_layer_detection(write_gcode, c1, c2):
    traj = load_trajectory(write_gcode("G21\nG90\nM83\n" + TWO_LAYERS.format(c1=c1, c2=c2)))
    assert traj.n_layers == 2
    np.testing.assert_allclose(traj.layer_z_mm[1:], [0.2, 0.4])
    sel = traj.select(layers=[2])
    assert sel.volume_mm3 == pytest.approx(0.4 * A_175, rel=1e-12)


def test_layer_cue_lookalikes_are_not_layers(write_gcode):
    text = "G21\nG90\nM83\n;BEFORE_LAYER_CHANGE\n;LAYER_COUNT:5\n" + TWO_LAYERS.format(
        c1="; layer 1 bead 1", c2=";AFTER_LAYER_CHANGE")
    traj = load_trajectory(write_gcode(text))
    assert traj.n_layers == 2  # found by Z, not by the look-alike comments
    assert not traj.gcode.has_layer_cues


def test_selection_region_layers_and_window():
    traj = load_trajectory(bundled.gcode_path("block_3x3"))
    bead = traj.extruded_volume_mm3 / 9
    sel = traj.select(layers=[2, 3], region_mm=(10.0, 12.0, 9.0, 10.5))  # 2 of 3 beads, 2/3 of each
    assert sel.volume_mm3 == pytest.approx(2 * 2 * bead * 2 / 3, rel=1e-6)
    t_mid = 0.5 * (sel.t_start_s + sel.t_end_s)
    v = sel.volume_until([sel.t_start_s, t_mid, sel.t_end_s])
    assert v[0] == pytest.approx(0.0, abs=1e-12) and v[2] == pytest.approx(sel.volume_mm3, rel=1e-12)
    first_layer = traj.select(time_window_s=(0.0, traj.sample([0]).time_s[0] + 1e9))
    assert first_layer.volume_mm3 == pytest.approx(traj.extruded_volume_mm3, rel=1e-12)
    with pytest.raises(UserInputError, match="deposits nothing"):
        traj.select(region_mm=(50, 60, 50, 60))
    with pytest.raises(UserInputError, match="do not exist"):
        traj.select(layers=[4])


def test_volumetric_preset_reads_e_as_volume(write_gcode):
    traj = load_trajectory(write_gcode(HEAD + "G1 X0 Y0 Z0.2 F6000\nG1 X10 E2.0 F1800\n"), "ultimaker_2plus")
    assert load_printer("ultimaker_2plus").volumetric_extrusion
    assert traj.extruded_volume_mm3 == pytest.approx(2.0, rel=1e-9)


def test_user_preset_file(tmp_path, write_gcode):
    preset = tmp_path / "printer.yaml"
    preset.write_text("slowbot:\n  nozzle_diam: 0.6\n  filament_diam: 1.75\n  p_vel: 20\n  p_acc: 100\n"
                      "  jerk: 5\n  vX: 50\n  vY: 50\n  vZ: 5\n  vE: 20\n  firmware: prusa\n")
    gc = write_gcode(HEAD + "G1 X0 Y0 Z0.2 F6000\nG1 X10 E0.4 F1800\n")
    slow = load_trajectory(gc, str(preset))
    fast = load_trajectory(gc, "prusa_mini")
    assert slow.printer.nozzle_diameter_mm == 0.6
    assert slow.print_time_s > fast.print_time_s  # 50 mm/s axis limit and 100 mm/s^2
    with pytest.raises(UserInputError, match="Unknown printer"):
        load_printer(f"{preset}:other")
    bad = tmp_path / "bad.yaml"
    bad.write_text("x:\n  p_vel: -1\n")
    with pytest.raises(UserInputError, match="lacks"):
        load_printer(str(bad))


def test_parse_selection_text():
    assert parse_layers("1,4-5") == [1, 4, 5]
    assert parse_region("10:20,5:15") == (10, 20, 5, 15)
    for bad in ("3-1", "a"):
        with pytest.raises(UserInputError):
            parse_layers(bad)
    with pytest.raises(UserInputError):
        parse_region("1:2")


def test_real_prusaslicer_file_from_pygcd():
    """A real PrusaSlicer file (relative E, M221, many firmware commands) plans end to end."""
    traj = load_trajectory(pygcd_example("cubhelix.gcode"), last_layer=3)
    assert traj.n_layers == 3
    assert traj.gcode.flow_factors[0] == 0.95  # 'M221 S95' in its start G-code
    assert 0 < traj.extruded_volume_mm3 < 200
