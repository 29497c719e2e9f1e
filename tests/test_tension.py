"""How DFSPH applies tension (k < 0): the difference form feels pressure gradients only;
how fast tension closes gaps; melt it flings is neither removed nor slowed.

A uniform negative k inside a disordered melt is no pressure gradient, so it must not move
anything; the papers' symmetric G instead pulls each particle towards its densest neighbours,
which is the tensile clumping that paired 28 % of the single bead's melt."""

import numpy as np
import pytest

from taichi_mex.options import DFSPHOptions, DFSPHStabilisers, Material, RunOptions
from taichi_mex.scenes.hydrostatic import HydrostaticScene
from taichi_mex.sim.simulation import Simulation
from taichi_mex.core.state import FLUID

DT = 1e-3  # with 1e4 Pa s at 1 mm spacing: nu dt / dx^2 = 1e4, a creeping step


def _creeping_tank(width_mm: float, height_mm: float, **stabilisers) -> Simulation:
    """A built weightless tank of 1e4 Pa s melt at 1 mm spacing (stabilisers: fields of
    DFSPHStabilisers; weightless, the tank has no speed scale of its own)."""
    dfsph = DFSPHOptions(stabilisers=DFSPHStabilisers(**stabilisers))
    sim = Simulation(HydrostaticScene(width_mm=width_mm, height_mm=height_mm, until_s=0.1),
                     RunOptions(scheme="dfsph", spacing_mm=1.0, progress=False, snapshots=False,
                                gravity_m_s2=0.0, dfsph=dfsph),
                     Material(name="creeping melt", density_kg_m3=1000.0, viscosity_pa_s=1e4))
    sim.build()
    return sim


def _kick_of_uniform_tension(form: str):
    """Velocity change of deep-interior melt under k = -1 everywhere, and grad C there."""
    sim = _creeping_tank(9, 9, tension_form=form)
    d = sim.solver.dfsph
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
    sim.solver.fluid.update()
    d.rows.update()
    kappa = np.zeros(sim.state.capacity, dtype=d.kappa.to_numpy().dtype)
    kappa[:n][fluid] = -1.0
    d.kappa.from_numpy(kappa)
    sim.state.v.fill(0.0)
    d.pressure_predictor(n, DT)

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
    assert d.creeping(DT * 10 * sim.run_opts.dfsph.stabilisers.creeping_diffusion)
    assert sim.solver._divergence_solve_wanted(DT)


@pytest.mark.parametrize("bad", ["sometimes", 1.5])
def test_divergence_solve_option_is_validated(bad):
    from taichi_mex.options import DFSPHOptions
    from taichi_mex.errors import UserInputError

    with pytest.raises(UserInputError, match="divergence_solve"):
        RunOptions(dfsph=DFSPHOptions(divergence_solve=bad)).validate()


def _contraction_speed(dt: float, closing_speed: float) -> float:
    """Fastest melt after one density solve on a creeping melt stretched 5 % upwards."""
    # the closing speed is closing_speed_factor times the speed scale; nothing else acts
    sim = _creeping_tank(7, 9, speed_scale_m_s=closing_speed, closing_speed_factor=1.0)
    d = sim.solver.dfsph
    assert d.closing_speed == closing_speed
    n = sim.state.n
    x = sim.state.x.to_numpy()
    fluid = sim.state.phase.to_numpy()[:n] == FLUID
    z = x[:n, 2][fluid]
    x[:n, 2][fluid] = z.min() + 1.05 * (z - z.min())  # stretched up through the open top
    sim.state.x.from_numpy(x)
    sim.grid.stale = True
    sim.refresh_lists()
    d.prepare(n)
    sim.solver.fluid.update()
    d.rows.update()
    sim.state.v.fill(0.0)
    assert d.creeping(dt)
    d.density_solve(dt)
    fluid = sim.state.phase.to_numpy()[:n] == FLUID
    return float(np.linalg.norm(sim.state.v.to_numpy()[:n][fluid], axis=1).max())


def test_tension_closes_gaps_no_faster_than_the_closing_speed():
    """A fixed fraction of a gap per step closes it at a speed ~ 1/dt: when melt torn by the
    nozzle cut the step, the pull grew and flung particles (the unscaled paper block blew up).
    Limited to the closing speed U, the fraction U dt / dx closes gaps at a speed set by U."""
    U = 0.01  # m/s: at dx = 1 mm, U dt / dx < tension_relaxation for both steps below
    limited = [_contraction_speed(dt, U) for dt in (1e-3, 1e-4)]
    free = [_contraction_speed(dt, 0.0) for dt in (1e-3, 1e-4)]
    assert 0.0 < limited[0] < U and 0.0 < limited[1] < U
    assert 0.5 < limited[1] / limited[0] < 2.0
    assert free[1] / free[0] > 5.0  # without the limit, ten times shorter steps pull ~10x faster
    assert free[1] > 10 * U


def test_a_creeping_step_neither_removes_nor_slows_flung_melt():
    """Until 2026-12-05 the split solve deleted isolated melt faster than 3x the speed scale
    (a droplet, counted as lost) and slowed creeping melt to 5x it: stabilisers from no paper,
    which removed 0.6-1.2 % of the paper block. Both are gone: a particle flung above the
    tank's surface at 0.5 m/s keeps its place among the melt and its speed, and the melt the
    first pressure solve kicks at the tank's walls (about 1.7 m/s in one 1e-4 s step) keeps
    its speed too; a step whose melt moves too far is redone shorter, or the run stops."""
    sim = _creeping_tank(7, 9, speed_scale_m_s=0.1, closing_speed_factor=0.0)
    n = sim.state.n
    x = sim.state.x.to_numpy()
    v = sim.state.v.to_numpy()
    fluid = np.flatnonzero(sim.state.phase.to_numpy()[:n] == FLUID)
    surface = fluid[x[fluid, 2] > x[fluid, 2].max() - 0.1 * sim.run_opts.spacing_m]
    middle = x[surface, :2].mean(axis=0)
    top = surface[np.argmin(np.linalg.norm(x[surface, :2] - middle, axis=1))]  # far from walls
    x[top, 2] += 2.5 * sim.run_opts.spacing_m  # beyond the support radius of the surface
    v[:] = 0.0
    v[top] = [0.0, 0.0, 0.5]
    sim.state.x.from_numpy(x)
    sim.state.v.from_numpy(v)
    sim.grid.stale = True
    melt_before = int(fluid.size)
    sim.lost_particles = 0  # run() starts this count
    sim.solver.step(0.0, 1e-4)
    sim.refresh_lists()
    assert sim.grid.lost_total == 0
    phase = sim.state.phase.to_numpy()[:sim.state.n]
    assert int((phase == FLUID).sum()) == melt_before
    x = sim.state.x.to_numpy()[:sim.state.n][phase == FLUID]
    speed = np.linalg.norm(sim.state.v.to_numpy()[:sim.state.n][phase == FLUID], axis=1)
    assert np.abs(x).max() < 0.1  # m: nothing parked far outside the domain
    assert speed.max() > 1.0  # m/s: the walls' kick and the droplet, neither slowed


def test_a_description_with_the_removed_ejection_or_clamp_says_what_to_do():
    """A run description written before 2026-12-05 may hold the removed stabilisers: it is
    refused with why they are gone and what to change, not with a bare 'unknown option'."""
    from taichi_mex.errors import UserInputError
    from taichi_mex.spec import RunSpec

    data = RunSpec.create("collapse").to_dict()
    data["run"]["dfsph"]["stabilisers"]["eject_speed_factor"] = 3.0
    with pytest.raises(UserInputError, match="eject_speed_factor was removed .* delete it"):
        RunSpec.from_dict(data)
