"""Neighbour grid: counting sort + lists against brute force, edges, skins, dropped particles."""

import numpy as np
import pytest

from taichi_mex import backend
from taichi_mex.core.state import FLUID, INLET, PLATE, SOLID, ParticleState


def _brute(x, radius):
    d = np.linalg.norm(x[:, None, :] - x[None, :, :], axis=2)
    np.fill_diagonal(d, np.inf)
    return [np.sort(np.nonzero(row < radius)[0]) for row in d]


def _build(points, phases, H, lo, hi, skin=0.0, origin=(0.0, 0.0, 0.0), solid_lists=True):
    from taichi_mex.core.grid import NeighbourGrid

    st = ParticleState(len(points) + 8, origin_m=origin)
    ids = st.add("test_id")
    for k, ph in enumerate(phases):
        st.append(points[k:k + 1], ph, 1.0)
    ids.from_numpy(np.concatenate([np.arange(len(points)), np.zeros(8)]).astype(np.float32))
    grid = NeighbourGrid(st, lo, hi, H, max_neighbours=200, skin_m=skin, solid_lists=solid_lists)
    grid.rebuild()
    return st, grid, ids


@pytest.mark.parametrize("skin", [0.0, 0.3])
def test_lists_match_brute_force_with_edges(skin):
    backend.init("cpu", "f64")
    rng = np.random.default_rng(3)
    H = 0.1
    lo, hi = np.zeros(3), np.array([0.5, 0.4, 0.3])
    pts = rng.uniform(lo, hi, size=(400, 3))
    # particles in the first and last cells, exactly on the domain faces and corners
    pts = np.concatenate([pts, [[0, 0, 0], [0.5 - 1e-9, 0.4 - 1e-9, 0.3 - 1e-9], [0.25, 0, 0.15],
                                [1e-6, 0.2, 0.3 - 1e-6], [0.49, 0.39, 0.29]]])
    st, grid, ids = _build(pts, [FLUID] * len(pts), H, lo, hi, skin=skin * H, origin=(0.2, 0.1, 0.0))
    assert st.n == len(pts)
    order = ids.to_numpy()[: st.n].astype(int)  # original index of each sorted particle
    x_sorted = st.numpy("position")
    np.testing.assert_allclose(x_sorted, pts[order], atol=1e-12)
    expect = _brute(x_sorted, H + skin * H)
    got = grid.neighbour_lists_numpy()
    for i in range(st.n):
        np.testing.assert_array_equal(got[i], expect[i])


def test_melt_and_nozzle_outside_the_box_are_kept_and_nan_dropped():
    """The grid drops no melt for where it is: melt outside the domain's box is sorted into
    the nearest cells and counted by the face it is beyond (the nozzle carries melt past a
    block's box at its last lift: 48-78 particles were dropped there, 2026-12-07); only a
    position that is not finite is dropped. The nozzle outside is kept as well, so that melt
    riding on it keeps its wall."""
    backend.init("cpu", "f32")
    H = 0.1
    lo, hi = np.zeros(3), np.ones(3) * 0.5
    pts = np.array([[0.1, 0.1, 0.1], [0.12, 0.1, 0.1], [0.9, 0.1, 0.1], [np.nan, 0, 0], [2.0, 2.0, 2.0],
                    [0.1, 0.1, 0.7], [0.1, -0.2, 0.1], [0.1, 0.2, -1e-3]])
    st, grid, ids = _build(pts, [FLUID, FLUID, FLUID, FLUID, INLET, FLUID, SOLID, FLUID], H, lo, hi)
    assert st.n == 7  # all but the NaN: six melt (four outside) and the inlet particle
    assert grid.lost_total == 1 and grid.lost_last == {"not_finite": 1}
    assert grid.outside_last == {"x_max": 1, "top": 1, "y_min": 1, "bottom": 1}
    phases = st.phase.to_numpy()[: st.n]
    assert sorted(phases.tolist()) == [FLUID] * 5 + [SOLID, INLET]


@pytest.mark.parametrize("skin", [0.0, 0.3])
def test_lists_match_brute_force_outside_the_box(skin):
    """Melt strewn up to three supports beyond every face keeps exactly its neighbours:
    clamping a cell index moves no two cells apart, so each query's reach still covers them."""
    backend.init("cpu", "f64")
    rng = np.random.default_rng(5)
    H = 0.1
    lo, hi = np.zeros(3), np.array([0.5, 0.4, 0.3])
    inside = rng.uniform(lo, hi, size=(300, 3))
    outside = rng.uniform(lo - 3 * H, hi + 3 * H, size=(300, 3))
    pts = np.concatenate([inside, outside])
    st, grid, ids = _build(pts, [FLUID] * len(pts), H, lo, hi, skin=skin * H)
    assert st.n == len(pts) and grid.lost_total == 0
    top = lo + np.asarray(grid.dims) * grid.cell  # the grid covers whole cells past hi
    beyond = np.any((outside < lo) | (outside >= top), axis=1).sum()
    assert beyond > 100 and sum(grid.outside_last.values()) == beyond
    x_sorted = st.numpy("position")
    expect = _brute(x_sorted, H + skin * H)
    got = grid.neighbour_lists_numpy()
    for i in range(st.n):
        np.testing.assert_array_equal(got[i], expect[i])


def test_idle_walls_get_no_list():
    backend.init("cpu", "f64")
    H = 0.1
    lo, hi = np.zeros(3), np.array([1.0, 0.2, 0.2])
    wall = np.stack([np.linspace(0.025, 0.975, 20), np.full(20, 0.05), np.full(20, 0.05)], axis=1)
    melt = np.array([[0.05, 0.08, 0.05]])
    pts = np.concatenate([wall, melt])
    st, grid, ids = _build(pts, [PLATE] * 20 + [FLUID], H, lo, hi)
    counts = grid.n_nbr.to_numpy()[: st.n]
    x = st.numpy("position")
    ph = st.phase.to_numpy()[: st.n]
    near = (ph == PLATE) & (np.linalg.norm(x - melt[0], axis=1) < H)
    far = (ph == PLATE) & ~near
    assert np.all(counts[near] > 0) and np.all(counts[far] == 0)


@pytest.mark.parametrize("solid_lists", [True, False])
def test_a_substrate_without_heat_is_listed_as_a_wall(solid_lists):
    """Solidified melt conducts heat (its own list everywhere); without heat it is a wall:
    listed only where melt sees it, with the same list, and the melt's lists unchanged."""
    backend.init("cpu", "f64")
    H = 0.1
    lo, hi = np.zeros(3), np.array([1.0, 0.2, 0.2])
    substrate = np.stack([np.linspace(0.025, 0.975, 20), np.full(20, 0.05), np.full(20, 0.05)], axis=1)
    melt = np.array([[0.05, 0.08, 0.05], [0.09, 0.08, 0.06]])
    pts = np.concatenate([substrate, melt])
    st, grid, ids = _build(pts, [SOLID] * 20 + [FLUID] * 2, H, lo, hi, solid_lists=solid_lists)
    x = st.numpy("position")
    ph = st.phase.to_numpy()[: st.n]
    got = grid.neighbour_lists_numpy()
    expect = _brute(x, H)
    near = np.array([(ph[i] == SOLID) and (np.linalg.norm(x[ph == FLUID] - x[i], axis=1) < H).any()
                     for i in range(st.n)])
    for i in range(st.n):
        listed = ph[i] == FLUID or near[i] or solid_lists
        np.testing.assert_array_equal(got[i], expect[i] if listed else [])
    assert (~near & (ph == SOLID)).sum() > 10  # most of the substrate is out of reach


def test_field_lengths_come_in_eight_sizes_an_octave_so_nearby_runs_share_kernels():
    """Taichi compiles field shapes into its kernels: particle capacities and grid cell
    arrays are rounded up to one of eight lengths an octave, never short and at most 12.5 %
    long, so that the bundled bead to print times 0.343 and 0.344 s (other particle counts,
    another grid) get the same shapes."""
    from taichi_mex import bundled
    from taichi_mex.options import Material, RunOptions
    from taichi_mex.core.state import shape_bucket
    from taichi_mex.scenes.print import PrintScene
    from taichi_mex.sim.simulation import Simulation

    for n in range(1, 5000):
        b = shape_bucket(n)
        assert n <= b <= 1.125 * n
    assert len({shape_bucket(n) for n in range(4097, 8193)}) == 8
    shapes = []
    for until in (0.343, 0.344):
        sim = Simulation(PrintScene(bundled.gcode_path("single_bead"), until_s=until),
                         RunOptions(spacing_mm=0.0667, progress=False, snapshots=False), Material())
        e = sim.estimate
        shapes.append((e["capacity"], e["melt_capacity"], shape_bucket(e["grid_cells"]), e["particles"]))
    assert shapes[0][:3] == shapes[1][:3] and shapes[0][3] != shapes[1][3]
