"""The SPlisHSPlasH side by side on the viscous collapse (bench collapse): the scene handed to
SPlisHSPlasH is our case, the Huppert figures from its positions are our scene's own, and
the command runs without SPlisHSPlasH installed. No timing assertions."""

import json
import math

import numpy as np
import pytest

from taichi_mex.app import peer_splishsplash as pss
from taichi_mex.scenes.collapse import huppert_radius

DX_MM = 0.8


@pytest.fixture(scope="module")
def case():
    spec = pss.collapse_spec(radius_mm=4.0, height_mm=4.0, viscosity_pa_s=1.0, density_kg_m3=1000.0,
                             spacing_mm=DX_MM, until_s=0.5)
    return spec, pss.collapse_case(spec)


def test_scene_file_is_our_case(case):
    spec, c = case
    dx = DX_MM * 1e-3
    fluid, plate = c["fluid_m"], c["plate_m"]
    # our lattice cylinder: cell-centred, 5 layers of 80 points inside r < 4 mm
    assert len(fluid) == 400
    assert np.hypot(fluid[:, 0], fluid[:, 1]).max() < 4e-3
    assert fluid[:, 2].min() == pytest.approx(0.5 * dx) and fluid[:, 2].max() == pytest.approx(4.5 * dx)
    # our plate: wall_layers() layers below z = 0, wider than the cylinder
    layers = spec.run.wall_layers()
    assert np.unique(np.round(plate[:, 2] / dx, 6)).tolist() == [-k - 0.5 for k in reversed(range(layers))]
    assert c["plate_hi_m"][2] == pytest.approx(0.0) and c["plate_lo_m"][2] == pytest.approx(-layers * dx)
    assert plate[:, 0].max() > 2 * 4e-3

    s = pss.splishsplash_scene(c, dt_s=1e-4)
    conf = s["Configuration"]
    assert conf["particleRadius"] == pytest.approx(0.5 * dx)
    assert conf["gravitation"] == [0.0, 0.0, pytest.approx(-9.81)]
    assert conf["simulationMethod"] == 4 and conf["boundaryHandlingMethod"] == 0  # DFSPH, Akinci
    assert conf["timeStepSize"] == 1e-4 and conf["cflMethod"] == 0 and conf["stopAt"] == 0.5
    mat = s["Materials"][0]
    assert mat["viscosityMethod"] == 6  # Weiler et al. 2018 in SPlisHSPlasH 2.19
    assert mat["viscosity"] == pytest.approx(1e-3) and mat["viscosityBoundary"] == pytest.approx(1e-3)
    assert mat["density0"] == 1000.0
    assert s["FluidModels"][0]["particleFile"] == "fluid.pda"
    assert s["RigidBodies"][0]["particleFile"] == "plate.pda" and not s["RigidBodies"][0]["isDynamic"]
    json.dumps(s)  # a JSON file as it stands


def test_particle_and_mesh_files(case, tmp_path):
    _spec, c = case
    pss.write_pda(tmp_path / "fluid.pda", c["fluid_m"])
    lines = (tmp_path / "fluid.pda").read_text().splitlines()
    assert lines[:6] == ["ATTRIBUTES", "position", "TYPES", "V", "NUMBER_OF_PARTICLES: 400", "BEGIN DATA"]
    back = np.array([[float(v) for v in ln.split()] for ln in lines[6:]])
    assert np.allclose(back, c["fluid_m"], rtol=0, atol=1e-12)
    pss.write_box_obj(tmp_path / "plate.obj", c["plate_lo_m"], c["plate_hi_m"])
    obj = (tmp_path / "plate.obj").read_text().splitlines()
    assert sum(ln.startswith("v ") for ln in obj) == 8 and sum(ln.startswith("f ") for ln in obj) == 12


def test_huppert_from_positions_is_the_scenes_fit(case):
    """Bottom-layer particles on a ring at Huppert's radius at every sample time: the scene's
    front radius and fit, applied to the positions, give a coefficient ratio of 1."""
    spec, c = case
    dx = c["spacing_m"]
    V, nu = c["plan"].info["volume_m3"], c["nu_m2_s"]
    times = np.array(c["sample_times_s"])
    angles = np.linspace(0.0, 2 * math.pi, 200, endpoint=False)
    positions = []
    for t in times:
        r = float(huppert_radius(t, V, nu)) - 0.5 * dx  # front_radius adds half a spacing
        ring = np.stack([r * np.cos(angles), r * np.sin(angles), np.full_like(angles, 0.5 * dx)], axis=1)
        positions.append(ring.astype(np.float32))
    h = pss.huppert_from_samples(spec, c, times, positions)
    assert h["front_coefficient_ratio"] == pytest.approx(1.0, abs=2e-3)
    assert h["front_ratio_late"] == pytest.approx(1.0, abs=2e-3)
    assert h["front_exponent_late"] == pytest.approx(0.125, abs=2e-3)


def _fake_scene_run(summary: dict, rc: int = 0):
    """Stands in for the ``scene collapse`` subprocess: writes ``summary`` where it was told."""
    import subprocess

    def run(cmd, **kwargs):
        out = cmd[cmd.index("--out") + 1]
        with open(f"{out}/summary.json", "w") as fh:
            json.dump(summary, fh)
        return subprocess.CompletedProcess(cmd, rc, "", "error: the run stopped\n" if rc else "")
    return run


SUMMARY = {"particles_active": 2082, "particles_by_phase": {"fluid": 400, "plate": 1682}, "steps": 11,
           "wall_time_s": 12.5, "simulated_time_s": 0.1, "scheme": "dfsph", "front_r_m": [0.004, 0.0053],
           "front_coefficient_ratio": 0.93, "front_ratio_late": 0.9, "front_exponent_late": 0.15}


def test_bench_collapse_without_splishsplash_prints_ours(monkeypatch, capsys, tmp_path):
    """Without SPlisHSPlasH: our row from the scene's summary.json, and how to install it
    (the scene run itself is stubbed: its kernel compilation alone takes ~25 s)."""
    monkeypatch.setattr(pss, "find_splishsplash_python", lambda *a, **k: (None, "not installed (test)", {}))
    monkeypatch.setattr(pss.subprocess, "run", _fake_scene_run(SUMMARY))
    path = tmp_path / "bench.json"
    assert pss.main(["--spacing-mm", str(DX_MM), "--until", "0.1", "--json", str(path)]) == 0
    text = capsys.readouterr().out
    assert "taichi_mex" in text and "0.930" in text and "stopped" not in text
    assert "pip install '.[splishsplash]'" in text
    result = json.loads(path.read_text())
    ours = result["ours"]
    assert result["splishsplash"] is None and result["splishsplash_missing"] == "not installed (test)"
    assert ours["particles"] == 2082 and ours["fluid_particles"] == 400 and ours["steps"] == 11
    assert ours["wall_s"] == 12.5 and ours["huppert_coefficient_ratio"] == 0.93 and "stopped" not in ours


def test_bench_collapse_reports_a_stopped_run(monkeypatch, capsys):
    monkeypatch.setattr(pss.subprocess, "run", _fake_scene_run(
        {**SUMMARY, "simulated_time_s": 0.05, "error": "divergence solve did not converge at t = 0.05 s"}, rc=3))
    result = pss.bench_collapse(spacing_mm=DX_MM, until_s=0.1, splishsplash=False)
    text = capsys.readouterr().out
    assert result["ours"]["stopped"].startswith("divergence solve did not converge")
    assert "taichi_mex (stopped)" in text and "stopped at t = 0.05 s of 0.1" in text


@pytest.mark.slow
def test_bench_collapse_runs_ours(capsys, tmp_path):
    """The real thing, coarse and short, ours only (about half a minute: kernel compilation)."""
    path = tmp_path / "bench.json"
    assert pss.main(["--spacing-mm", str(DX_MM), "--until", "0.02", "--no-splishsplash",
                     "--json", str(path)]) == 0
    ours = json.loads(path.read_text())["ours"]
    assert "taichi_mex" in capsys.readouterr().out
    assert ours["fluid_particles"] == 400 and ours["particles"] > 400 and ours["steps"] >= 1
