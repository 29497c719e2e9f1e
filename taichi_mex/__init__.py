"""taichi_mex: SPH simulation of material-extrusion bead deposition, driven by G-code."""

__version__ = "0.1.0"

from . import bundled  # noqa: E402
from .config import Material, RunOptions  # noqa: E402
from .simulation import Simulation  # noqa: E402

__all__ = ["Material", "RunOptions", "Simulation", "bundled", "__version__"]
