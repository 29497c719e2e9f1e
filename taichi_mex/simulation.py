"""Moved: the run loop now lives in ``taichi_mex.sim.simulation`` (the package layout of
2026-12). This name stays so that scripts written before it keep working, and says so."""

import warnings

from taichi_mex.sim.simulation import *  # noqa: F401,F403

warnings.warn("taichi_mex.simulation moved to taichi_mex.sim.simulation; import that instead",
              DeprecationWarning, stacklevel=2)
