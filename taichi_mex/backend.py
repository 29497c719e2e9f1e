"""The one module that imports taichi: architecture, precision and initialisation.

Every other module does ``from .backend import ti``; nothing initialises Taichi at import
time. A move to a Taichi fork (as Genesis did) changes this file only.

Taichi keeps fields alive until it is reset, so a process runs one simulation at a time:
``init`` resets Taichi and invalidates the fields of any earlier simulation.
"""


import contextlib
import io
import os

os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "false")
import taichi as ti  # noqa: E402

from taichi_mex.errors import UserInputError  # noqa: E402

from taichi_mex.options import ARCHES, PRECISIONS  # noqa: E402

_current: dict = {}


def init(arch: str = "cpu", precision: str = "f32", threads: int | None = None,
         debug: bool = False) -> str:
    """(Re)initialise Taichi; return the architecture actually used ('cpu', 'cuda', 'vulkan')."""
    if arch not in ARCHES:
        raise UserInputError(f"Unknown arch '{arch}'; choose one of {', '.join(ARCHES)}.")
    if precision not in PRECISIONS:
        raise UserInputError(f"Unknown precision '{precision}'; choose f32 or f64.")
    fp = ti.f64 if precision == "f64" else ti.f32
    kwargs = dict(default_fp=fp, default_ip=ti.i32, debug=debug, random_seed=0,
                  log_level=ti.WARN, offline_cache=True)
    if threads:
        kwargs["cpu_max_num_threads"] = int(threads)
    if _current:
        ti.reset()
    used = "cpu"
    with contextlib.redirect_stdout(io.StringIO()):  # Taichi prints "Starting on arch=..."
        if arch == "gpu":
            used = _init_gpu(precision, kwargs)
        else:
            ti.init(arch=ti.cpu, **kwargs)
    _current.update(arch=used, precision=precision,
                    threads=int(ti.lang.impl.current_cfg().cpu_max_num_threads))
    return used


def _init_gpu(precision: str, kwargs: dict) -> str:
    for name, target in (("cuda", ti.cuda), ("vulkan", ti.vulkan)):
        try:
            if name == "vulkan" and precision == "f64":
                continue  # Taichi's Vulkan backend has no f64 arithmetic
            # a missing driver is expected here: keep Taichi's own warnings about it quiet,
            # the message below says what matters
            ti.init(arch=target, **{**kwargs, "log_level": ti.ERROR})
            ti.set_logging_level(ti.WARN)
        except Exception:  # noqa: BLE001 - taichi raises assorted errors when a backend is absent
            ti.reset()
            continue
        if ti.lang.impl.current_cfg().arch == target:
            return name
        ti.reset()
    raise UserInputError("No GPU backend is available (Taichi found neither CUDA nor Vulkan). "
                         "Run with --arch cpu, or install a CUDA driver.")


def gpu_available() -> bool:
    """True when Taichi can start CUDA or Vulkan here (used to skip GPU tests)."""
    if os.environ.get("TAICHI_MEX_NO_GPU"):
        return False
    try:
        init("gpu")
        return True
    except UserInputError:
        return False


def current() -> dict:
    """{'arch': ..., 'precision': ..., 'threads': CPU threads} of the live Taichi runtime
    (empty before init)."""
    return dict(_current)


def real_np_dtype():
    import numpy as np

    return np.float64 if _current.get("precision") == "f64" else np.float32


__all__ = ["ti", "init", "current", "gpu_available", "real_np_dtype", "ARCHES", "PRECISIONS"]
