"""How DFSPH applies tension (k < 0): the difference form feels pressure gradients only.

A uniform negative k inside a disordered melt is no pressure gradient, so it must not move
anything; the papers' symmetric G instead pulls each particle towards its densest neighbours,
which is the tensile clumping that paired 28 % of the single bead's melt."""

import numpy as np
import pytest

from taichi_mex.config import Material, RunOptions
from taichi_mex.scenes.hydrostatic import HydrostaticScene
from taichi_mex.simulation import Simulation
from taichi_mex.state import FLUID

DT = 1e-3  # with 1e4 Pa s at 1 mm spacing: nu dt / dx^2 = 1e4, a creeping step


def _kick_of_uniform_tension(form: str):
    """Velocity change of deep-interior melt under k = -1 everywhere, and grad C there."""
    sim = Simulation(HydrostaticScene(width_mm=9, height_mm=9, until_s=0.1),
                     RunOptions(scheme="dfsph", spacing_mm=1.0, progress=False, snapshots=False,
                                gravity_m_s2=0.0),
                     Material(name="creeping melt", density_kg_m3=1000.0, viscosity_pa_s=1e4))
    sim.build()
    d = sim.solver.dfsph
    d.tension_form = form
    dx = sim.run_opts.spacing_m
    n = sim.state.n
    x = sim.state.x.to_numpy()
    fluid = sim.state.phase.to_numpy()[:n] == FLUID
    rng = np.random.default_rng(3)
    x[:n][fluid] += rng.normal(0.0, 0.12 * dx, size=(int(fluid.sum()), 3))
    sim.state.x.from_numpy(x)
    sim.grid.stale = True
    sim.refresh_lists()  # re-sorts: read the phases again
    fluid = sim.state.phase.to_numpy()[:n] == FLUID
    d.prepare(n)
    nf = sim.solver.fluid.update()
    kappa = np.zeros(sim.state.capacity, dtype=d.kappa.to_numpy().dtype)
    kappa[:n][fluid] = -1.0
    d.kappa.from_numpy(kappa)
    sim.state.v.fill(0.0)
    d.pressure_predictor(n, nf, DT)

    x = sim.state.x.to_numpy()[:n]
    surface = d.surface.to_numpy()[:n] == 1
    tensed = fluid & ~surface
    # deep interior: every neighbour within the support is melt under the same tension
    dist = np.linalg.norm(x[:, None, :] - x[None, :, :], axis=2)
    near = (dist < sim.kernel.H) & (dist > 0)
    deep = tensed & np.all(~near | tensed[None, :], axis=1)
    v = sim.state.v.to_numpy()[:n]
    grad_c = d.grad_c.to_numpy()[:n]
    return v[deep], grad_c[deep]


def test_uniform_tension_moves_nothing_in_the_difference_form():
    v_sym, grad_sym = _kick_of_uniform_tension("symmetric")
    v_diff, _ = _kick_of_uniform_tension("difference")
    assert len(v_sym) >= 8 and len(v_diff) == len(v_sym)
    speed_sym = np.linalg.norm(v_sym, axis=1)
    assert speed_sym.mean() > 0  # the disorder gives the symmetric form a kick to work with
    # the symmetric form pulls towards higher particle density: clumping
    towards_denser = np.einsum("ij,ij->i", v_sym, grad_sym) > 0
    assert towards_denser.mean() > 0.9
    # the difference form: no gradient, no motion (to float round-off of the k_i terms)
    assert np.linalg.norm(v_diff, axis=1).max() < 1e-4 * speed_sym.mean()


def test_the_difference_form_is_refused_outside_creeping_steps():
    """Water-like steps (nu dt / dx^2 < creeping_diffusion) keep the momentum-conserving G."""
    sim = Simulation(HydrostaticScene(width_mm=6, height_mm=6, until_s=0.1),
                     RunOptions(scheme="dfsph", spacing_mm=1.0, progress=False, snapshots=False),
                     Material(name="water-like", density_kg_m3=1000.0, viscosity_pa_s=1.0))
    sim.build()
    d = sim.solver.dfsph
    assert not d.creeping(DT)  # nu dt / dx^2 = 1
    assert d.creeping(DT * 10 * d.creeping_diffusion)
    assert sim.solver._divergence_solve_wanted(DT)


@pytest.mark.parametrize("bad", ["sometimes", 1.5])
def test_divergence_solve_option_is_validated(bad):
    from taichi_mex.config import DFSPHOptions
    from taichi_mex.errors import UserInputError

    with pytest.raises(UserInputError, match="divergence_solve"):
        RunOptions(dfsph=DFSPHOptions(divergence_solve=bad)).validate()
