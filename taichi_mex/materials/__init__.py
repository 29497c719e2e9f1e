"""Materials by name: one TOML file per polymer in this folder, a value and a cited source
per property (``[sources]``). ``--material NAME`` picks a shipped one, ``--material FILE.toml``
a user's own in the same form (keys are the fields of :class:`~taichi_mex.options.Material`)."""

from __future__ import annotations

import tomllib
from importlib.resources import files
from pathlib import Path

from taichi_mex.errors import UserInputError


def _folder() -> Path:
    return Path(str(files("taichi_mex.materials")))


def known() -> list[str]:
    """Names of the shipped materials (lower case)."""
    return sorted(p.stem for p in _folder().glob("*.toml"))


def read(name_or_path: str) -> tuple[dict, dict]:
    """(property values, their sources) of a shipped material or a TOML file."""
    text = str(name_or_path)
    path = Path(text).expanduser()
    if text.lower().endswith(".toml") or path.is_file():
        if not path.is_file():
            raise UserInputError(f"Material file {path} does not exist.")
    else:
        if text.lower() not in known():
            raise UserInputError(f"Unknown material '{text}'; known: {', '.join(known())}, or a "
                                 "FILE.toml with the fields of taichi_mex.options.Material.")
        path = _folder() / f"{text.lower()}.toml"
    try:
        data = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise UserInputError(f"Cannot read material file {path}: {exc}.") from None
    sources = data.pop("sources", {})
    if not isinstance(sources, dict):
        raise UserInputError(f"{path}: [sources] must be a table of property = \"citation\".")
    return data, sources
