"""Moved: options now lives in ``taichi_mex.options`` (the package layout of
2026-12). This name stays so that scripts written before it keep working, and says so."""

import warnings

from taichi_mex.options import *  # noqa: F401,F403

warnings.warn("taichi_mex.config moved to taichi_mex.options; import that instead",
              DeprecationWarning, stacklevel=2)
