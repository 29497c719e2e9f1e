"""Uniaxial extension (scenes/extension.py): the end pieces move exactly as the uniaxial field
moves them, and the coupled solve starts the melt between them with that field. The run over
a strain of 0.5 against R0 exp(-e t / 2): validation/extension."""

import math

import numpy as np
import pytest

from taichi_mex.core.state import FLUID, NOZZLE
from taichi_mex.scenes.extension import extension_field
from taichi_mex.sim.simulation import Simulation
from taichi_mex.spec import RunSpec

RATE = 1.0  # 1/s, the scene's default


def _filament(**changes):
    spec = RunSpec.create("extension", changes={"radius_mm": 0.5, "length_mm": 4.0,
                                                "run.progress": False, **changes})
    sim = Simulation.from_spec(spec)
    sim.build()
    return sim


def test_end_pieces_follow_the_uniaxial_field_exactly():
    sim = _filament()
    before = sim.state.numpy("position", NOZZLE)
    sim.move_boundaries(0.3)
    after = sim.state.numpy("position", NOZZLE)
    scale = np.array([math.exp(0.3 * RATE), math.exp(-0.15 * RATE), math.exp(-0.15 * RATE)])
    # stored relative to the domain's centre in the state's f32: a few 1e-11 m of rounding
    assert np.abs(np.sort(after, axis=0) - np.sort(before * scale, axis=0)).max() < 1e-9
    v = sim.state.numpy("velocity", NOZZLE)
    assert np.abs(v - extension_field(after, RATE)).max() < 1e-7
    assert sim.boundary_speed() == sim.scene.wall_speed() > 0.0


def test_the_estimate_counts_the_scenes_own_largest_step():
    """The scene allows steps of 0.01 / rate; the estimate printed before a run uses the
    same bounds as the solver (it once used the option's 1 ms and said 500 steps where the
    run took 75; now 95, from the CFL bound on the end pieces' speed)."""
    sim = Simulation.from_spec(RunSpec.create("extension", changes={"run.progress": False}))
    e = sim.estimate
    assert e["dt_limits_s"]["max"] == pytest.approx(0.01 / RATE)
    assert e["steps_estimate"] == math.ceil(e["simulated_time_s"] / min(e["dt_limits_s"].values()))
    assert 75 / 2 <= e["steps_estimate"] <= 2 * 75


def test_melt_starts_with_the_uniaxial_field_and_trouton_tension():
    """One coupled solve with the end pieces moving: the melt between them takes the uniaxial
    field (measured at 5 particles per radius: median axial and radial rates 1.0 % above e and
    -e / 2), and the interior's pressure is the tension -mu e that leaves the side
    traction-free (measured 1.011 mu e with the strain-energy form; 1.03-1.09 with the explicit
    correction before it, 1.8-2.6 mu e without the surface's traction)."""
    sim = _filament()
    res = sim.solver.quasi_static()
    assert res.converged
    x = sim.state.numpy("position", FLUID)
    v = sim.state.numpy("velocity", FLUID)
    r = np.hypot(x[:, 1], x[:, 2])
    away = np.abs(x[:, 0]) > 0.5 * sim.run_opts.spacing_m
    axial = v[away, 0] / (RATE * x[away, 0])
    radial = (x[:, 1] * v[:, 1] + x[:, 2] * v[:, 2]) / (-0.5 * RATE * r**2)
    assert abs(np.median(axial) - 1.0) < 0.03
    assert abs(np.median(radial) - 1.0) < 0.03
    k = sim.solver.dfsph.kappa.to_numpy()[: sim.state.n][sim.state.numpy("phase") == FLUID]
    inside = (r < 0.3e-3) & (np.abs(x[:, 0]) < 1.2e-3)
    p = np.median(k[inside]) * sim.material.density_kg_m3
    assert 0.9 < p / (-sim.material.viscosity_pa_s * RATE) < 1.15


@pytest.mark.slow  # ~2 min: 60 coupled steps; validation/extension has the figures
def test_divergence_free_steps_keep_the_filament_on_trouton():
    """Stretched to a Hencky strain of 0.3 with divergence-free steps (no density source), at
    4 particles per radius: the mid radius within 1 % of R0 exp(-e t / 2) (measured 0.4 %; the
    issue asks 3 %; with the kernel-sum source it is 1.2 % off at 0.3 and 3.7 % at 0.4,
    validation/extension)."""
    spec = RunSpec.create("extension", changes={"spacing_mm": 0.125, "strain": 0.3,
                                                "run.dfsph.stokes_density_source": "none",
                                                "run.progress": False, "run.snapshots": False})
    sim = Simulation.from_spec(spec)
    out = sim.run()
    assert out["particles_lost"] == 0 and out["melt_outside_domain_max"] == 0
    assert abs(out["mid_radius_error_max"]) < 0.01

