"""The GPU path: the same scenes on CUDA (or Vulkan) must agree with the CPU.

Skipped, with the reason printed by ``pytest -ra``, where Taichi finds no GPU. Where one
is found they run with the rest of the suite (``-m gpu`` selects only these).
"""

import numpy as np
import pytest

from taichi_mex import backend
from taichi_mex.app.cli import main
from taichi_mex.options import EDACOptions, Material, RunOptions
from taichi_mex.scenes.hydrostatic import HydrostaticScene
from taichi_mex.sim.simulation import Simulation

HAVE_GPU = backend.gpu_available()
needs_gpu = pytest.mark.skipif(not HAVE_GPU, reason="no GPU: Taichi found neither CUDA nor Vulkan "
                                                    "on this machine, GPU tests skipped")
WATER = Material(name="test fluid", density_kg_m3=1000.0, viscosity_pa_s=1.0)


def _hydrostatic(arch: str, scheme: str, tmp_path) -> dict:
    run = RunOptions(scheme=scheme, spacing_mm=1.0, arch=arch, edac=EDACOptions(sound_speed_m_s=4.9),
                     progress=False, snapshots=False)
    return Simulation(HydrostaticScene(width_mm=6, height_mm=12, until_s=0.1), run, WATER,
                      out_dir=tmp_path / f"{arch}_{scheme}").run()


@pytest.mark.gpu
@needs_gpu
@pytest.mark.parametrize("scheme", ["edac", "dfsph"])
def test_gpu_hydrostatic_agrees_with_cpu(scheme, tmp_path):
    """Same column on both: slab pressures within 2 % of rho g H of each other (the
    reductions are deterministic but float sums run in another order), nothing lost."""
    cpu = _hydrostatic("cpu", scheme, tmp_path)
    gpu = _hydrostatic("gpu", scheme, tmp_path)
    assert gpu["arch"] in ("cuda", "vulkan")
    assert gpu["particles_lost"] == 0 and np.isfinite(gpu["density_error_max"])
    assert abs(gpu["pressure_error_rel_mean"] - cpu["pressure_error_rel_mean"]) < 0.02
    assert gpu["particles_active"] == cpu["particles_active"]


@pytest.mark.gpu
@needs_gpu
def test_gpu_print_conserves_mass(tmp_path):
    args = ["--preset", "paper", "--resolution", "0.12", "--until", "0.36", "--arch", "gpu",
            "--out", str(tmp_path), "--quiet", "--no-snapshots"]
    from taichi_mex import bundled
    import json

    assert main([str(bundled.gcode_path("paper_bead"))] + args) == 0
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["arch"] in ("cuda", "vulkan")
    assert s["deposited_volume_mm3"] == pytest.approx(s["released_volume_mm3"], rel=1e-6)


@pytest.mark.skipif(HAVE_GPU, reason="this machine has a GPU: the no-GPU message is not reachable")
def test_arch_gpu_without_gpu_says_so(tmp_path, capsys):
    """No traceback: a one-paragraph message and a non-zero exit."""
    rc = main(["--arch", "gpu", "--until", "0.32", "--out", str(tmp_path), "--quiet"])
    err = capsys.readouterr().err
    assert rc != 0 and "No GPU backend" in err and "Traceback" not in err
