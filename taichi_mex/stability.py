"""Moved: the stability matrix is ``python -m taichi_mex stability`` (module
``taichi_mex.app.stability``); ``python -m taichi_mex.stability`` still runs it, and says so."""

import sys
import warnings

from taichi_mex.app.stability import main

if __name__ == "__main__":
    warnings.warn("python -m taichi_mex.stability moved to python -m taichi_mex stability",
                  DeprecationWarning, stacklevel=1)
    sys.exit(main(sys.argv[1:]))
