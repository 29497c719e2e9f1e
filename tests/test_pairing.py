"""The pairing probe: SPH's tensile clumping, which summation density does not see."""

import numpy as np

from taichi_mex.options import Material, RunOptions
from taichi_mex.scenes.hydrostatic import HydrostaticScene
from taichi_mex.sim.simulation import Simulation
from taichi_mex.core.state import FLUID


def test_paired_fraction_counts_close_pairs_and_nothing_on_a_lattice():
    sim = Simulation(HydrostaticScene(width_mm=6, height_mm=6, until_s=0.1),
                     RunOptions(scheme="dfsph", spacing_mm=1.0, progress=False, snapshots=False),
                     Material(name="test fluid", density_kg_m3=1000.0, viscosity_pa_s=1.0))
    sim.build()
    sim.refresh_lists()
    assert sim.paired_fraction() == 0.0  # the initial lattice: nearest neighbour = dx

    dx = sim.run_opts.spacing_m
    n = sim.state.n
    x = sim.state.x.to_numpy()
    phase = sim.state.phase.to_numpy()[:n]
    fluid = np.nonzero(phase == FLUID)[0]
    # pull a few particles, far apart from each other, to 0.3 dx above the one below them
    movers = []
    for i in fluid:
        below = fluid[np.all(np.isclose(x[fluid], x[i] - [0.0, 0.0, dx], atol=1e-3 * dx), axis=1)]
        if len(below) and all(np.linalg.norm(x[i] - x[m]) > 4 * dx for m in movers):
            movers.append(i)
            x[i] = x[below[0]] + [0.0, 0.0, 0.3 * dx]
        if len(movers) == 5:
            break
    assert len(movers) == 5
    sim.state.x.from_numpy(x)
    sim.grid.stale = True
    sim.refresh_lists()
    assert sim.paired_fraction() == 2 * 5 / len(fluid)  # each pair counts both partners
    assert sim.paired_fraction(closer_than_dx=0.2) == 0.0
