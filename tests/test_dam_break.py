"""PySPH's 3D dam break (peer benchmark scene): exact particle counts, a short run, the
benchmark command without PySPH."""

import json

import numpy as np
import pytest

from taichi_mex.app import peer
from taichi_mex.options import Material, RunOptions, apply_overrides
from taichi_mex.scenes import dam_break
from taichi_mex.core.state import FLUID, PLATE

COARSE_DX_M = 0.08


def _plan(dx_m):
    run = apply_overrides(RunOptions(), dam_break.run_options(dx_m))
    material = apply_overrides(Material(), dam_break.material())
    scene = dam_break.DamBreak3DScene()
    return scene, scene.plan(run, material)


def test_geometry_counts_match_pysph_exactly():
    """PySPH's DamBreak3DGeometry(dx=0.02, nboundary_layers=1) prints 80,703 fluid,
    60,836 boundary and 1,512 obstacle particles."""
    scene, plan = _plan(0.02)
    assert scene.counts == {"fluid": 80_703, "boundary": 60_836, "obstacle": 1_512}
    by_phase = {b.phase: len(b.position_m) for b in plan.blocks}
    assert by_phase == {FLUID: 80_703, PLATE: 60_836 + 1_512}
    assert plan.initial_count() == 143_051
    # one lattice, no particle twice: integer lattice indices are unique
    xyz = np.concatenate([b.position_m for b in plan.blocks])
    idx = np.round((xyz - [-0.02, -0.52, -0.02]) / 0.02).astype(int)
    assert np.allclose(idx * 0.02 + [-0.02, -0.52, -0.02], xyz, atol=1e-9)
    assert len(np.unique(idx, axis=0)) == len(xyz)
    # the index ranges of the research notes (fluid i 2..62, j 2..50, k 2..28)
    fluid = idx[: scene.counts["fluid"]]
    assert fluid.min(axis=0).tolist() == [2, 2, 2] and fluid.max(axis=0).tolist() == [62, 50, 28]
    # physics as PySPH's EDACScheme: h = 1.3 dx, c0 = 10 sqrt(2 g 0.55)
    run = apply_overrides(RunOptions(), dam_break.run_options(0.02))
    assert run.resolved_kernel() == ("wendland_c2", 2.6)
    assert run.edac.sound_speed_m_s == pytest.approx(32.8497, rel=1e-5)


def test_geometry_matches_pysph_when_installed():
    geometry = pytest.importorskip("pysph.examples._db_geometry")
    pysph_arrays = geometry.DamBreak3DGeometry(dx=0.02, nboundary_layers=1, hdx=1.3).create_particles()
    ours = dam_break.DamBreakGeometry().particles(0.02)
    for pa in pysph_arrays:
        theirs = np.stack([pa.x, pa.y, pa.z], axis=1)
        mine = ours[pa.name]
        key = lambda a: np.lexsort(np.round(a / 0.02).astype(int).T)  # noqa: E731
        assert np.allclose(theirs[key(theirs)], mine[key(mine)], atol=1e-9), pa.name


def test_short_coarse_run_stays_finite(tmp_path):
    """A few steps at dx = 0.08 through the scene command: nothing lost, nothing NaN."""
    from taichi_mex.app.cli import main

    out = tmp_path / "db"
    code = main(["scene", "dam-break", "--dx", str(COARSE_DX_M), "--until", "0.002",
                 "--out", str(out), "--no-snapshots", "--quiet"])
    assert code == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["steps"] >= 4 and s["particles_lost"] == 0 and s["melt_outside_domain_max"] == 0
    assert s["particles_by_phase"]["fluid"] == 1080
    assert np.isfinite(s["front_x_m"]) and s["front_x_m"] < 1.3


def test_bench_without_pysph_prints_ours(capsys, tmp_path):
    path = tmp_path / "bench.json"
    assert peer.main(["--dx", str(COARSE_DX_M), "--steps", "3", "--no-pysph", "--json", str(path)]) == 0
    text = capsys.readouterr().out
    assert "taichi_mex" in text and "M particle-steps/s" in text
    result = json.loads(path.read_text())
    ours = result["ours"]
    assert result["pysph"] is None and ours["steps"] == 3 and ours["finite"]
    assert ours["particles"] == 4535 and ours["particle_steps_per_s"] > 0
    assert ours["dt_first_s"] == pytest.approx(peer.pysph_dt(COARSE_DX_M), rel=1e-3)
