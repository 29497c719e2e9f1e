import importlib.resources
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture
def write_gcode(tmp_path):
    """Write G-code text to a file in the test's folder and return its path."""

    def _write(text: str, name: str = "test.gcode") -> Path:
        path = tmp_path / name
        path.write_text(text)
        return path

    return _write


def pygcd_example(name: str) -> Path:
    """A slicer file shipped in pyGCodeDecode's wheel."""
    return Path(str(importlib.resources.files("pyGCodeDecode"))) / "examples" / "data" / name
