"""The scene registry. A scene module declares its options as a dataclass of :func:`~taichi_mex.options.opt` fields
(units in the help, a check each, flags for the command line) and registers a
:class:`SceneEntry`: the options class, how to build the scene from them, and the run and
material defaults the scene implies (applied before the user's own choices).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable


def _no_defaults(_options) -> dict:
    return {}


@dataclass(frozen=True)
class SceneEntry:
    name: str
    help: str
    #: the scene's options dataclass
    options: type
    #: options -> scene object
    build: Callable
    #: options -> {"run": {...}, "material": {...}}: defaults this scene implies
    defaults: Callable = _no_defaults


SCENES: dict[str, SceneEntry] = {}


def register(entry: SceneEntry) -> SceneEntry:
    SCENES[entry.name] = entry
    return entry
