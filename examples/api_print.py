"""The Python API in a few lines: simulate a G-code print and look at the particles.

    python examples/api_print.py [OUT_DIR]
"""

import sys

import numpy as np

from taichi_mex import Material, RunOptions, Simulation, bundled
from taichi_mex.scenes.print import PrintScene
from taichi_mex.core.state import FLUID

out = sys.argv[1] if len(sys.argv) > 1 else "api_print_out"

# the seed paper's baseline on its single bead, stopped early to keep the example short
scene = PrintScene(bundled.gcode_path("paper_bead"), until_s=0.36, nozzle_height="one_diameter",
                   nozzle_tip_outer_diameter_mm=None)
run = RunOptions(scheme="edac", spacing_mm=0.1, progress=True)
sim = Simulation(scene, run, Material(viscosity_pa_s=0.1), out_dir=out)
print(sim.describe_estimate())
summary = sim.run()

xyz = sim.state.numpy("position", FLUID)  # metres, one row per melt particle
rho = sim.state.numpy("density", FLUID)
print(f"{len(xyz)} melt particles, bead height {1e3 * np.ptp(xyz[:, 2]):.3f} mm, "
      f"density {rho.min():.0f}..{rho.max():.0f} kg/m^3")
print(f"deposited {summary['deposited_volume_mm3']:.4f} of {summary['commanded_volume_mm3']:.4f} mm^3")
