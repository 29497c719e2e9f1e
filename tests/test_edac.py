"""EDAC baseline: hydrostatic column, and a blow-up stopped with a clear message."""

import json

import numpy as np
import pytest

from taichi_mex.options import EDACOptions, Material, RunOptions
from taichi_mex.errors import SimulationDiverged
from taichi_mex.post.output import read_frames
from taichi_mex.scenes.hydrostatic import HydrostaticScene
from taichi_mex.sim.simulation import Simulation

WATER = Material(name="test fluid", density_kg_m3=1000.0, viscosity_pa_s=1.0)


def _run_opts(**kw):
    # c = 10 sqrt(2 g H) for a 12 mm column: Mach ~0.1
    base = dict(scheme="edac", spacing_mm=1.0, edac=EDACOptions(sound_speed_m_s=4.9),
                progress=False, snapshots=False)
    base.update(kw)
    return RunOptions(**base)


@pytest.mark.slow  # ~1.5 min; the EDAC baseline keeps the dam break and the sweep in the default run
def test_hydrostatic_column_settles_to_rho_g_h(tmp_path):
    """Slab-mean pressure at depth matches rho g (H - z) within 5 % of rho g H, its slope
    rho g within 10 %; nothing leaks."""
    sim = Simulation(HydrostaticScene(width_mm=6, height_mm=12, until_s=0.2), _run_opts(), WATER,
                     out_dir=tmp_path)
    s = sim.run()
    assert s["pressure_gradient_rel_error"] < 0.10
    assert s["pressure_error_rel_max"] < 0.05
    assert s["pressure_error_rel_mean"] < 0.035
    assert s["deepest_slab_pressure_pa"] == pytest.approx(s["deepest_slab_expected_pa"], rel=0.05)
    assert s["particles_lost"] == 0 and s["melt_outside_domain_max"] == 0 and s["min_fluid_z_m"] > 0.0
    frames = read_frames(tmp_path / "particles.h5")
    assert len(frames) >= 10
    for f in frames:
        assert np.isfinite(f["position"]).all() and np.isfinite(f["pressure"]).all()


def test_blow_up_stops_with_time_and_cause_and_keeps_frames(tmp_path):
    sim = Simulation(HydrostaticScene(width_mm=6, height_mm=12, until_s=0.2),
                     _run_opts(dt_factor=6.0, output_every_s=0.005), WATER, out_dir=tmp_path)
    with pytest.raises(SimulationDiverged, match=r"blew up at t = [0-9.e-]+ s.*dt_factor = 6"):
        sim.run()
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert "blew up" in summary["error"]
    frames = read_frames(tmp_path / "particles.h5")
    assert len(frames) >= 2 and frames[0]["time_s"] == 0.0
