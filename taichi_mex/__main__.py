import sys

from taichi_mex.app.cli import main

sys.exit(main())
