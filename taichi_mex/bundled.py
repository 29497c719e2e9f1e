"""The G-code files that ship with taichi_mex (the repository's ``gcode/`` folder), and the
example prints that ship with pyGCodeDecode (``pygcodedecode:benchy``: a real slicer's part,
used by the window benchmarks)."""

from __future__ import annotations

import importlib.resources
from pathlib import Path

DEFAULT_GCODE = "single_bead.gcode"
#: prefix of a name that refers to pyGCodeDecode's example data
PYGCD_PREFIX = "pygcodedecode:"


def gcode_dir() -> Path:
    """Folder of the bundled G-code, installed (package data) or in a source checkout."""
    installed = Path(str(importlib.resources.files("taichi_mex"))) / "gcode"
    if (installed / DEFAULT_GCODE).is_file():
        return installed
    return Path(__file__).resolve().parent.parent / "gcode"


def gcode_path(name: str = DEFAULT_GCODE) -> Path:
    """Path of a bundled G-code file by name (``'block_3x3'`` or ``'block_3x3.gcode'``)."""
    if not name.endswith(".gcode"):
        name += ".gcode"
    return gcode_dir() / name


def bundled_names() -> list[str]:
    return sorted(p.name for p in gcode_dir().glob("*.gcode"))


def pygcd_example_dir() -> Path:
    return Path(str(importlib.resources.files("pyGCodeDecode"))) / "examples" / "data"


def pygcd_example(name: str) -> Path:
    """Path of one of pyGCodeDecode's example G-code files (``'benchy'`` or ``'benchy.gcode'``)."""
    return pygcd_example_dir() / (name if name.endswith(".gcode") else name + ".gcode")


def resolve_gcode(value, base_dir=None) -> Path:
    """A path (relative to ``base_dir``, else the working folder) or a bundled name
    (``'block_3x3'``) -> the absolute path of an existing file."""
    from taichi_mex.errors import UserInputError

    text = str(value)
    if text.startswith(PYGCD_PREFIX):
        name = text[len(PYGCD_PREFIX):]
        path = pygcd_example(name)
        if Path(name).name == name and path.is_file():  # a name, not a path out of the folder
            return path
        known = sorted(p.name for p in pygcd_example_dir().glob("*.gcode"))
        raise UserInputError(f"G-code '{text}': pyGCodeDecode has no example of that name; it has "
                             + ", ".join(PYGCD_PREFIX + n.removesuffix(".gcode") for n in known) + ".")
    names = bundled_names()
    plain = text if text.endswith(".gcode") else text + ".gcode"
    path = Path(text).expanduser()
    if not path.is_absolute() and base_dir is not None:
        path = Path(base_dir) / path
    if path.is_file():
        return path.resolve()
    if "/" not in text and plain in names:
        return gcode_path(plain)
    raise UserInputError(f"G-code '{text}' is neither a file ({path} does not exist) nor a "
                         f"bundled name ({', '.join(n.removesuffix('.gcode') for n in names)}), nor one of "
                         f"pyGCodeDecode's examples ({PYGCD_PREFIX}NAME, e.g. {PYGCD_PREFIX}benchy).")
