"""Moved: mesostructure analysis now lives in ``taichi_mex.post.analysis`` (the package layout of
2026-12). This name stays so that scripts written before it keep working, and says so."""

import warnings

from taichi_mex.post.analysis import *  # noqa: F401,F403

warnings.warn("taichi_mex.analysis moved to taichi_mex.post.analysis; import that instead",
              DeprecationWarning, stacklevel=2)
