"""What a user sees and keeps: the report, the animation, probes, materials by name, resume.

The simulation cases here are in the validation tier (tests/conftest.py); the probe and the
bad-input checks are unit tests."""

import json
import pickle
import re

import numpy as np
import pytest

from taichi_mex import materials
from taichi_mex.app.cli import main
from taichi_mex.post.probes import shepard
from taichi_mex.spec import RunSpec

#: a short, coarse bead: 0.1 mm spacing (2 particles across the 0.2 mm layer), 60 ms of it
SHORT = {"run.spacing_mm": 0.1, "scene.until_s": 0.37, "run.progress": False}


def _run(spec, out):
    from taichi_mex.sim.simulation import Simulation

    sim = Simulation.from_spec(spec, out_dir=out)
    return sim, sim.run()


def test_probe_on_a_lattice_returns_the_known_field():
    """Shepard weights reproduce a linear field at a lattice node (symmetric neighbourhood)
    and a constant everywhere; a probe with no particle in reach is NaN with a count of 0."""
    from taichi_mex.core.kernels import Kernel

    dx = 1e-4
    g = np.arange(-5, 6) * dx
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    pos = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    field = 200.0 + 3e4 * pos[:, 0] - 1e4 * pos[:, 2]
    K = Kernel("cubic", 2 * dx)
    points = np.array([[0.0, 0.0, 0.0], [dx, -dx, 2 * dx], [1.0, 1.0, 1.0]])
    value, count = shepard(points, pos, field, K.W_np, K.H)
    assert value[0] == pytest.approx(200.0, abs=1e-9)
    assert value[1] == pytest.approx(200.0 + 3e4 * dx - 1e4 * 2 * dx, abs=1e-9)
    assert np.isnan(value[2]) and count[2] == 0 and count[0] > 20
    const, _ = shepard(points[:2] + 0.3 * dx, pos, np.full(len(pos), 7.5), K.W_np, K.H)
    assert np.allclose(const, 7.5)


@pytest.mark.parametrize("args, fragment", [
    (["--material", "nylon"], "Unknown material 'nylon'; known: abs, petg, pla"),
    (["--material", "missing.toml"], "does not exist"),
    (["--field", "colour"], "snapshot_field = 'colour'"),
    (["--field", "temperature"], "need heat"),
    (["--probe", "1,2"], "X,Y,Z in mm"),
    (["--probe", "500,0,0"], "outside the simulated domain"),
    (["--resume", "nowhere"], "not a taichi_mex run folder"),
    (["--resume", "."], "not a taichi_mex run folder"),
])
def test_bad_input_gets_one_line(tmp_path, capsys, args, fragment):
    assert main(args + ["--out", str(tmp_path / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and fragment in err and "Traceback" not in err


def test_resume_refuses_a_changed_configuration(tmp_path, capsys):
    out = tmp_path / "run"
    spec = RunSpec.create("print", changes={**SHORT, "scene.until_s": 0.315, "run.snapshots": False})
    _run(spec, out)
    config = json.loads((out / "config.json").read_text())
    config["scene_options"]["until_s"] = 0.4  # the run is not at its (new) end
    (out / "config.json").write_text(json.dumps(config))
    assert main(["--resume", str(out)]) == 2
    assert "differs from the run its checkpoint belongs to" in capsys.readouterr().err
    assert main(["--resume", str(out), "--viscosity", "5"]) == 2
    assert "drop material.viscosity_pa_s" in capsys.readouterr().err


def test_report_animation_and_probes_reference_the_runs_figures(tmp_path):
    out = tmp_path / "run"
    spec = RunSpec.create("print", changes={**SHORT, "run.animation": True, "run.animation_frames": 6,
                                            "run.probes_mm": ((10.5, 10.0, 0.1),)})
    sim, summary = _run(spec, out)
    page = (out / "report.html").read_text()
    # self-contained: every picture inline, nothing fetched
    assert not re.search(r"(src|href)=['\"](?!data:|runs/)", page)
    assert f"{summary['deposited_volume_mm3']:.4g}" in page and f"{summary['steps']:,}" in page
    assert page.count("data:image/png;base64,") >= 5  # snapshots, section, probes plot
    assert "rounded-rectangle width" in page and "config.json" in page
    video = out / "animation.mp4"
    assert video.is_file() and video.stat().st_size > 5000
    rows = (out / "probes.csv").read_text().splitlines()
    assert rows[0].startswith("time_s,probe,x_mm,y_mm,z_mm,particles")
    assert len(rows) > 100 and (out / "probes.png").is_file()
    for view in ("side", "top", "oblique", "section"):
        assert (out / "snapshots" / f"final_{view}.png").stat().st_size > 10_000


def test_resume_after_ctrl_c_reaches_the_uninterrupted_end(tmp_path):
    from taichi_mex.post.output import read_frames
    from taichi_mex.sim.simulation import Simulation

    spec = RunSpec.create("print", changes={**SHORT, "run.snapshots": False})
    _, whole = _run(spec, tmp_path / "whole")
    sim = Simulation.from_spec(spec, out_dir=tmp_path / "cut")
    sim.build()
    step = sim.solver.step
    calls = []

    def ctrl_c_at_step_90(t, dt):  # Ctrl-C, at a fixed step so that the test cannot flake
        calls.append(t)
        if len(calls) == 90:
            raise KeyboardInterrupt
        return step(t, dt)

    sim.solver.step = ctrl_c_at_step_90
    assert sim.run()["interrupted"]
    # a counter the code gained after the checkpoint was written starts from its default
    ck = tmp_path / "cut" / "checkpoint.pkl"
    data = pickle.loads(ck.read_bytes())
    del data["values"]["solver.totals"]["stokes_free_steps"]
    ck.write_bytes(pickle.dumps(data))
    resumed = Simulation.resume(tmp_path / "cut")
    assert resumed.steps == 89
    end = resumed.run()
    assert end["deposited_volume_mm3"] == pytest.approx(whole["deposited_volume_mm3"], rel=1e-12)
    assert end["particles_active"] == whole["particles_active"]
    frames = {name: read_frames(tmp_path / name / "particles.h5")[-1] for name in ("whole", "cut")}
    melt = {k: f["position"][np.isin(f["phase"], (0, 1))] for k, f in frames.items()}
    # to the bit: every loop sums in a fixed order and the checkpoint holds the whole state
    # (benchy's window, cut at t = 181.46 s and resumed, matched its uninterrupted frame at
    # 183.92 s to the bit as well, 2026-12-04)
    assert np.array_equal(melt["whole"], melt["cut"])
    for key in ("bead_width_p99_mm", "bead_height_p99_mm"):
        assert end[key] == whole[key]


def test_a_blow_up_keeps_the_state_it_stopped_in(tmp_path):
    """A run stopped by the speed limit writes the state that broke it as its last frame:
    the frame before it can be seconds of print earlier, and the flung particle is the
    thing to look at."""
    from taichi_mex.errors import SimulationDiverged
    from taichi_mex.post.output import read_frames

    spec = RunSpec.create("print", changes={**SHORT, "run.snapshots": False,
                                            "run.max_speed_m_s": 0.005})
    with pytest.raises(SimulationDiverged, match=r"blew up at t = ([0-9.e-]+) s") as err:
        _run(spec, tmp_path)
    t_stop = float(re.search(r"blew up at t = ([0-9.e-]+) s", str(err.value)).group(1))
    last = read_frames(tmp_path / "particles.h5")[-1]
    assert last["time_s"] == pytest.approx(t_stop, rel=1e-5)
    fast = np.linalg.norm(last["velocity"][np.isin(last["phase"], (0, 1))], axis=1).max()
    assert fast > 0.005


@pytest.mark.parametrize("name", [n if n == "pla" else pytest.param(n, marks=pytest.mark.slow)
                                  for n in materials.known()])  # PLA is every other test's melt
def test_every_material_loads_and_runs_a_short_bead(tmp_path, name):
    values, sources = materials.read(name)
    assert set(values) - {"name"} <= set(sources), "every property needs a source"
    spec = RunSpec.create("print", changes={**SHORT, "scene.until_s": 0.33, "run.snapshots": False},
                          material=name)
    assert spec.material.name.lower() == name and spec.material_source == name
    _, summary = _run(spec, tmp_path / name)
    assert summary["deposited_volume_mm3"] > 0 and "error" not in summary
    config = json.loads((tmp_path / name / "config.json").read_text())
    assert config["material"]["name"].lower() == name and config["material_source"] == name


def test_config_json_re_runs_the_same_run(tmp_path, capsys):
    """python -m taichi_mex --config DIR/config.json --out DIR2 gives the same particles,
    steps and deposited volume."""
    first = tmp_path / "first"
    args = ["--resolution", "0.1", "--until", "0.34", "--no-snapshots", "--quiet"]
    assert main(args + ["--out", str(first)]) == 0
    assert main(["--config", str(first / "config.json"), "--out", str(tmp_path / "again")]) == 0
    a, b = (json.loads((tmp_path / d / "summary.json").read_text()) for d in ("first", "again"))
    for key in ("particles_active", "steps", "deposited_volume_mm3"):
        assert a[key] == b[key]
    assert json.loads((tmp_path / "again" / "config.json").read_text()) == \
        json.loads((first / "config.json").read_text())


def test_a_users_material_file(tmp_path):
    path = tmp_path / "mine.toml"
    path.write_text('name = "my PLA"\ndensity_kg_m3 = 1100.0\nviscosity_pa_s = 3000.0\n'
                    '[sources]\ndensity_kg_m3 = "my lab, 2026"\n')
    spec = RunSpec.create("print", material=str(path))
    assert spec.material.name == "my PLA" and spec.material.density_kg_m3 == 1100.0
    assert spec.material.glass_transition_c == 60.0  # the rest: the defaults
    path.write_text('name = "bad"\ndensity_kg_m3 = -1.0\n')
    with pytest.raises(Exception, match="density_kg_m3"):
        RunSpec.create("print", material=str(path))
    path.write_text('name = "typo"\ndensitty_kg_m3 = 1.0\n')
    with pytest.raises(Exception, match="did you mean material.density_kg_m3"):
        RunSpec.create("print", material=str(path))
