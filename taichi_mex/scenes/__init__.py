"""Scenes: each sets up particles, domain, times and the physics it needs.

``SCENES`` maps the command-line name to a module-level ``cli`` spec: a function adding the
scene's own options to a parser, and one building ``(scene, run_defaults, material_overrides)``
from the parsed arguments. ``run_defaults`` are applied before the user's run options.
"""

from dataclasses import dataclass
from typing import Callable


@dataclass
class SceneCLI:
    name: str
    help: str
    add_arguments: Callable
    build: Callable


SCENES: dict[str, SceneCLI] = {}


def register(spec: SceneCLI) -> SceneCLI:
    SCENES[spec.name] = spec
    return spec


def load_all() -> dict[str, SceneCLI]:
    """Import the scene modules so that they register themselves."""
    from taichi_mex.scenes import collapse, hydrostatic, shear  # noqa: F401

    try:
        from taichi_mex.scenes import thermal_beam  # noqa: F401
    except ImportError:
        pass
    try:
        from taichi_mex.scenes import dam_break  # noqa: F401
    except ImportError:
        pass
    return SCENES
