"""taichi_mex: SPH simulation of material-extrusion bead deposition, driven by G-code."""

__version__ = "0.1.0"

from taichi_mex import bundled  # noqa: E402
from taichi_mex.options import Material, RunOptions  # noqa: E402

__all__ = ["Material", "RunOptions", "RunSpec", "Simulation", "bundled", "__version__"]


def __getattr__(name):
    # Simulation imports Taichi; post-processing (analysis, render) must not pay for it
    if name == "Simulation":
        from taichi_mex.sim.simulation import Simulation

        return Simulation
    if name == "RunSpec":
        from taichi_mex.spec import RunSpec

        return RunSpec
    raise AttributeError(f"module 'taichi_mex' has no attribute {name!r}")
