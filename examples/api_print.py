"""The Python API in a few lines: describe a run, simulate it, look at the particles.

    python examples/api_print.py [OUT_DIR]
"""

import sys

import numpy as np

from taichi_mex import RunSpec, Simulation
from taichi_mex.core.state import FLUID

out = sys.argv[1] if len(sys.argv) > 1 else "api_print_out"

# the seed paper's baseline on its single bead, stopped early to keep the example short;
# changes are dotted paths (scene.*, run.*, material.*) or the flat names sweeps use
spec = RunSpec.create("print", preset="paper", changes={"scene.until_s": 0.36, "run.spacing_mm": 0.1})
sim = Simulation.from_spec(spec, out_dir=out)   # writes OUT_DIR/config.json when it runs
print(sim.describe_estimate())
summary = sim.run()

xyz = sim.state.numpy("position", FLUID)  # metres, one row per melt particle
rho = sim.state.numpy("density", FLUID)
print(f"{len(xyz)} melt particles, bead height {1e3 * np.ptp(xyz[:, 2]):.3f} mm, "
      f"density {rho.min():.0f}..{rho.max():.0f} kg/m^3")
print(f"deposited {summary['deposited_volume_mm3']:.4f} of {summary['commanded_volume_mm3']:.4f} mm^3")
print(f"re-run it with: python -m taichi_mex --config {out}/config.json --out {out}_again")
