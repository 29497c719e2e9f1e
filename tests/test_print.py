"""The print scene end to end: inlet mass bookkeeping, outputs, command line, Ctrl-C."""

import json
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ET

import h5py
import numpy as np
import pytest

from taichi_mex import bundled
from taichi_mex.app.cli import main
from taichi_mex.options import EDACOptions, Material, RunOptions
from taichi_mex.scenes.print import PrintScene
from taichi_mex.sim.simulation import MEASURED_RATE_2CORE, STARTUP_S, Simulation
from taichi_mex.spec import RunSpec

PAPER = dict(scheme="edac", spacing_mm=0.1, edac=EDACOptions(sound_speed_m_s=6.0), progress=False)
PAPER_MELT = Material(viscosity_pa_s=0.1)
SUMMARY_KEYS = {"particles_active", "deposited_volume_mm3", "commanded_volume_mm3",
                "simulated_time_s", "wall_time_s", "steps", "particle_steps_per_s",
                "density_error_mean", "density_error_max"}


@pytest.fixture(scope="module")
def paper_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper")
    scene = PrintScene(bundled.gcode_path("paper_bead"), until_s=0.36, nozzle_height="one_diameter",
                       nozzle_tip_outer_diameter_mm=None)
    sim = Simulation(scene, RunOptions(**PAPER, output_every_s=0.004), PAPER_MELT, out_dir=out)
    summary = sim.run()
    return sim, summary, out


def test_deposited_mass_follows_commanded_volume(paper_run):
    sim, s, out = paper_run
    assert SUMMARY_KEYS <= s.keys()
    slice_mm3 = sim.inlet.n_slice * (sim.run_opts.spacing_mm ** 3)
    assert s["commanded_volume_mm3"] > 5 * slice_mm3
    # the column releases whole lattice slices: at most half a slice ahead or behind
    assert abs(s["deposited_volume_mm3"] - s["commanded_volume_mm3"]) <= 0.5 * slice_mm3 + 1e-9
    assert s["particles_lost"] == 0 and s["melt_outside_domain_max"] == 0
    # and at every frame, not only at the end
    sel = sim.scene.selection
    with h5py.File(out / "particles.h5") as h5:
        for name in h5["frames"]:
            g = h5["frames"][name]
            melt = int(np.sum(g["phase"][()] <= 1))
            commanded = float(sel.volume_until([g.attrs["time_s"]])[0])
            assert abs(melt * 1e-3 - commanded) <= 0.5 * slice_mm3 + 1e-9


def test_hdf5_xdmf_and_snapshots(paper_run):
    sim, s, out = paper_run
    with h5py.File(out / "particles.h5") as h5:
        config = json.loads(h5.attrs["config"])
        assert config["run"]["scheme"] == "edac" and config["material"]["viscosity_pa_s"] == 0.1
        units = json.loads(h5.attrs["units"])
        assert units["pressure"] == "Pa" and units["position"] == "m"
        last = h5["frames"][sorted(h5["frames"])[-1]]
        for key in ("position", "velocity", "density", "pressure", "bead_id", "phase"):
            assert key in last
        assert h5["plate/position"].shape[1] == 3
        times = [h5["frames"][k].attrs["time_s"] for k in sorted(h5["frames"])]
        assert np.all(np.diff(times) > 0)
    root = ET.parse(out / "particles.xdmf").getroot()
    items = [d.text for d in root.iter("DataItem")]
    assert len(items) >= 2 * len(times)
    with h5py.File(out / "particles.h5") as h5:
        for text in items:
            assert text.split(":", 1)[1] in h5
    pngs = sorted(p.name for p in (out / "snapshots").glob("*.png"))
    assert pngs == ["final_oblique.png", "final_section.png", "final_side.png", "final_top.png"]
    assert all((out / "snapshots" / p).stat().st_size > 5000 for p in pngs)
    assert json.loads((out / "summary.json").read_text())["steps"] == s["steps"]


def test_layers_above_the_first_print_on_a_solid_substrate():
    scene = PrintScene(bundled.gcode_path("block_3x3"), layers=[2], until_s=None)
    plan = scene.plan(RunOptions(spacing_mm=0.05), Material())
    solid = [b for b in plan.blocks if b.phase == 1]
    assert len(solid) == 1
    z = solid[0].position_m[:, 2]
    assert z.min() > 0 and z.max() < 0.2e-3  # the first layer fills 0 < z < 0.2 mm
    # its volume matches the first layer's commanded volume within the lattice's resolution
    volume = len(z) * (0.05e-3) ** 3 * 1e9
    layer1 = scene.trajectory.segment_volume_mm3[scene.trajectory.layer == 1].sum()
    assert volume == pytest.approx(layer1, rel=0.1)


def test_the_nozzle_is_its_flat_tip_and_a_flank_at_its_angle_and_the_domain_holds_its_melt():
    """Above the flat tip (a slab as thick as the bore column) the nozzle's flank rises at its
    angle from the face's edge, a shell at least the slab thick along its normal, reaching
    over the highest face's reach wherever the nozzle is: melt the tip ploughs up meets it
    (with the slab alone, benchy's window lost 8 particles through the domain's top riding on
    it). The domain's top is over the flank's top at the highest face: melt on the flank rises
    with the nozzle."""
    from taichi_mex.sim.boundaries import nozzle_tip_lattice

    dx, bore, tip, slices = 0.05e-3, 0.2e-3, 0.5e-3, 4
    flat = nozzle_tip_lattice(bore, tip, dx, slices)
    assert flat[:, 2].max() < slices * dx
    for angle in (30.0, 45.0, 60.0):
        pts = nozzle_tip_lattice(bore, tip, dx, slices, angle, 1.0e-3)
        r, z = np.linalg.norm(pts[:, :2], axis=1), pts[:, 2]
        assert len(pts) > len(flat) and z.max() > 1.0e-3 - dx
        assert np.allclose(np.sort(pts[z < slices * dx], axis=0), np.sort(flat, axis=0))
        above = z > slices * dx
        surface = tip + (z[above] - slices * dx) / np.tan(np.radians(angle))
        assert np.all(r[above] < surface) and np.all(r[above] > surface - dx - slices * dx
                                                     / np.sin(np.radians(angle)))
        # each slice's outermost particle is within a spacing of the flank's surface
        for zk in np.unique(z[above]):
            k = z[above] == zk
            assert surface[k][0] - r[above][k].max() < 1.5 * dx
    opts = RunOptions(spacing_mm=0.1)
    plan = PrintScene(bundled.gcode_path("single_bead")).plan(opts, Material())
    assert plan.inlet.flank_angle_deg == 45.0
    # the bundled bead's nozzle is at z = 0.2 mm throughout: the flank reaches to within two
    # supports of the domain's top
    H = opts.resolved_kernel()[1] * opts.spacing_m
    assert plan.inlet.body_height_m == pytest.approx(plan.domain_hi_m[2] - 0.2e-3 - 2 * H, rel=1e-9)
    # the paper block lifts its nozzle from 0.4 to 1.6 mm: at its lowest the flank reaches the
    # highest face's reach, and melt on the flank, carried up with it (no-slip), stays in the
    # domain at the highest (its lifts carried 479 particles out through the top)
    block = PrintScene(bundled.gcode_path("paper_block_3x3")).plan(opts, Material())
    low, high = 0.4e-3, 1.6e-3
    assert block.inlet.body_height_m > high - low
    assert block.domain_hi_m[2] >= high + block.inlet.body_height_m + H
    flat_plan = PrintScene(bundled.gcode_path("single_bead"), nozzle_flank_angle_deg=None).plan(
        opts, Material())
    assert flat_plan.inlet.flank_angle_deg is None


def test_a_window_on_a_substrate_reports_only_its_own_melt_as_deposited(tmp_path):
    """The substrate a layer window starts on was printed before the run: deposited counts the
    melt the run released (it counted the substrate too: 3.2 mm^3 'deposited' of 0.02)."""
    opts = RunOptions(spacing_mm=0.1, progress=False, snapshots=False, output_every_s=0.01)
    start = PrintScene(bundled.gcode_path("block_3x3"), layers=[2]).plan(opts, Material()).t_start_s
    scene = PrintScene(bundled.gcode_path("block_3x3"), layers=[2], until_s=start + 0.03)
    sim = Simulation(scene, opts, Material(), out_dir=tmp_path)
    s = sim.run()
    assert sim.plan.blocks and any(b.phase == 1 for b in sim.plan.blocks)
    slice_mm3 = sim.inlet.n_slice * 0.1 ** 3
    assert s["commanded_volume_mm3"] > slice_mm3
    assert abs(s["deposited_volume_mm3"] - s["commanded_volume_mm3"]) <= 0.5 * slice_mm3 + 1e-9
    # nor is the substrate part of the bead's section: its particles carry bead id -1
    substrate = sim.state.numpy("bead_id", 1)
    assert len(substrate) and (substrate == -1).all()
    assert s.get("bead_material_area_mm2", 0.0) < 1.2 * 0.2 * 0.45  # one bead, not three below it
    # each step's fastest melt against the fastest wall particle, binned: creeping melt is
    # not flung. Melt squeezed out under the face may outrun the walls; at this spacing (two
    # particles a layer) one of 45 steps read 2.05x (1.5x when the walls' speed was
    # overstated as |v| + w, 2026-12-07), none more
    bins = s["melt_faster_than_walls_steps"]
    assert set(bins) == {"1-2x", "2-4x", ">4x"} and sum(bins.values()) <= s["steps"]
    assert bins[">4x"] == 0 and s["melt_speed_max_m_s"] > 0.0


def test_cli_run_writes_results(tmp_path, capsys):
    args = [str(bundled.gcode_path("paper_bead")), "--preset", "paper", "--resolution", "0.12",
            "--until", "0.335", "--out", str(tmp_path), "--quiet", "--no-snapshots"]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "estimate:" in out and "particles" in out and "MiB" in out
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["steps"] > 0 and not summary["interrupted"]
    assert (tmp_path / "particles.xdmf").exists() and (tmp_path / "plan.json").exists()


def test_scene_too_large_for_memory_is_refused(tmp_path, capsys):
    args = [str(bundled.gcode_path("block_3x3")), "--resolution", "0.002", "--out", str(tmp_path)]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "GiB" in err and "coarser" in err and "Traceback" not in err


@pytest.mark.slow  # tests/test_outputs.py resumes an interrupted run in the default tier
def test_ctrl_c_stops_cleanly_and_keeps_frames(tmp_path):
    cmd = [sys.executable, "-m", "taichi_mex", str(bundled.gcode_path("paper_bead")), "--preset",
           "paper", "--resolution", "0.06", "--output-every", "0.001", "--out", str(tmp_path),
           "--quiet", "--no-snapshots"]
    # a shell that starts the suite in the background leaves SIGINT ignored, and the child
    # would inherit that: give it the default disposition, as a terminal's process has
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    h5 = tmp_path / "particles.h5"
    deadline = time.time() + 240
    while time.time() < deadline:
        if h5.exists():
            try:
                with h5py.File(h5, "r", locking=False) as f:
                    if len(f["frames"]) >= 3:
                        break
            except (OSError, KeyError):
                pass
        time.sleep(0.5)
    assert proc.poll() is None, "the run ended before it could be interrupted"  # it takes minutes
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["interrupted"] is True
    with h5py.File(h5, "r") as f:
        assert len(f["frames"]) >= 3


def test_the_coupled_solve_is_estimated_at_its_own_measured_rate():
    """The coupled creeping solve has its own measured rate per melt particle-step, with the
    surface traction several times the cost without; the estimate printed before a run once
    used the split solve's rate for both and said 36 s where the draft bead took 157 s, and
    counting every particle put the unscaled paper block at 4 min where it took 19. A print
    refuses the split solve before it starts: its melt creeps."""
    from taichi_mex.errors import UserInputError

    def sim(**changes):
        return Simulation.from_spec(RunSpec.create("print", changes={
            "resolution": "draft", "run.progress": False, "run.cpu_threads": 2, **changes}))
    with pytest.raises(UserInputError, match="split solve is for inertial flows.*coupled"):
        sim(**{"run.dfsph.creeping_solve": "split"})
    coupled = sim(**{"run.dfsph.stokes_surface_traction": True})
    assert "rates measured for dfsph-coupled-traction" in coupled.describe_estimate()
    # without the surface traction (a print's default) the solve is several times cheaper
    plain = sim()
    assert (plain.run_opts.dfsph.creeping_solve, plain.run_opts.dfsph.stokes_surface_traction) == ("coupled", False)
    assert coupled.estimate["steps_estimate"] == plain.estimate["steps_estimate"]
    assert "rates measured for dfsph-coupled (" in plain.describe_estimate()
    def work(s):  # the estimate less the fixed start-up
        return s.estimate["wall_time_estimate_s"] - STARTUP_S
    # the solve's cost is in its melt rows: the melt particle-steps, the commanded volume
    # deposited by each step (the bead deposits throughout: about half the full bead's)
    e = plain.estimate
    full = e["steps_estimate"] * 0.4071e-9 / plain.run_opts.spacing_m**3
    assert 0.4 * full < e["melt_particle_steps_estimate"] < 0.6 * full
    assert work(plain) == pytest.approx(e["melt_particle_steps_estimate"]
                                        / MEASURED_RATE_2CORE["dfsph-coupled"])
    assert work(coupled) / work(plain) == pytest.approx(MEASURED_RATE_2CORE["dfsph-coupled"]
                                                        / MEASURED_RATE_2CORE["dfsph-coupled-traction"])
    # measured on 2 cores, mostly on one thread (serial_rows): no more threads, no gain assumed
    for threads in (1, 8):
        assert work(sim(**{"run.cpu_threads": threads})) == pytest.approx(work(plain))
    # its iterations a step grow with the resolution (36 / 77 GMRES a step at 3 / 6 per gap)
    fine = sim(resolution="fine")
    per_step = lambda s: work(s) / s.estimate["steps_estimate"]  # noqa: E731
    assert per_step(fine) > 6 * 2 ** 0.6 * per_step(plain)  # 8x the melt, and more a particle


def test_the_estimate_counts_the_steps_dt_factor_asks_for():
    """--dt-factor 0.5 halves every step, so the estimate counts twice the steps (it counted
    the same 586 for the draft bead at half, once and twice the step)."""
    def steps(f):
        return Simulation.from_spec(RunSpec.create("print", changes={
            "resolution": "draft", "run.progress": False, "run.dt_factor": f})).estimate["steps_estimate"]
    one = steps(1.0)
    assert steps(0.5) == pytest.approx(2 * one, abs=2)
    assert steps(2.0) == pytest.approx(one / 2, abs=2)


def test_melt_over_the_nozzles_tip_face_is_counted():
    """A print lays its melt under the nozzle's face: melt more than a spacing above the
    face's plane rides on the nozzle (strings, blobs) or stands in its way, and the run
    reports how much."""
    from taichi_mex.core.state import FLUID

    scene = PrintScene(bundled.gcode_path("single_bead"), until_s=0.32)
    sim = Simulation(scene, RunOptions(**PAPER), PAPER_MELT)
    sim.build()
    t = scene.selection.t_start_s + 0.01
    sim.inlet.advance(t)
    tip = sim.inlet.nozzle_state(t)[0]
    dx = sim.run_opts.spacing_m
    beside = tip + np.array([0.6e-3, 0.0, 0.0])  # past the 0.5 mm tip radius, by the flank
    heights = np.array([3.0, 1.5, 0.5, -1.0]) * dx  # over the face's plane
    sim.state.append(beside + np.outer(heights, [0.0, 0.0, 1.0]), FLUID, 1e-12)
    assert sim.inlet.melt_over_face() == 2
    sim._track_melt_over_face(t)
    assert sim.over_face["melt_over_face_particles"] == 2 and sim.over_face["melt_over_face_at_s"] == t
    # a nozzle without its tip carries nothing
    bare = Simulation(PrintScene(bundled.gcode_path("single_bead"), until_s=0.32,
                                 nozzle_tip_outer_diameter_mm=None), RunOptions(**PAPER), PAPER_MELT)
    bare.build()
    bare.inlet.advance(t)
    assert bare.inlet.melt_over_face() == 0


def test_the_walls_speed_is_their_fastest_particles():
    """The step's wall speed (the CFL's, and the estimate's) is the fastest nozzle or bore
    column particle's: the column slides down the bore while the tip moves across, so the
    speeds add as vectors (|v| + w made the bundled bead's steps 1.4x shorter than that)."""
    from taichi_mex.core.state import INLET, NOZZLE

    scene = PrintScene(bundled.gcode_path("single_bead"), until_s=0.32)
    sim = Simulation(scene, RunOptions(**PAPER), PAPER_MELT)
    sim.build()
    t = 0.5 * (scene.selection.t_start_s + scene.selection.t_end_s)  # mid-bead: moving, extruding
    sim.inlet.advance(t)
    _, vel, w, _ = sim.inlet.nozzle_state(t)
    assert np.linalg.norm(vel) > 1e-3 and w > 1e-3
    phase = sim.state.phase.to_numpy()[: sim.state.n]
    v = np.linalg.norm(sim.state.v.to_numpy()[: sim.state.n], axis=1)
    fastest = v[(phase == NOZZLE) | (phase == INLET)].max()
    assert sim.inlet.speed == pytest.approx(fastest, rel=1e-5)  # what boundary_speed() reads
    assert sim.inlet.speed < np.linalg.norm(vel) + w - 0.1 * w
    assert float(sim.plan.wall_speed_m_s(np.array([t]))[0]) == pytest.approx(fastest, rel=1e-5)
