"""Wall time per phase of a step (the pattern of NVIDIA Warp's ScopedTimer): off by default,
since an honest split has to wait for the device at each phase boundary."""

from __future__ import annotations

import time
from contextlib import contextmanager, nullcontext

from taichi_mex.backend import ti


class PhaseTimer:
    def __init__(self, enabled: bool = False):
        self.enabled = enabled
        self.seconds: dict[str, float] = {}

    def phase(self, name: str):
        return self._timed(name) if self.enabled else nullcontext()

    @contextmanager
    def _timed(self, name: str):
        ti.sync()
        t0 = time.perf_counter()
        try:
            yield
        finally:
            ti.sync()
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - t0
