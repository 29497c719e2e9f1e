from pathlib import Path

import pytest

from taichi_mex.bundled import pygcd_example  # noqa: F401  (tests import it from here)

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture
def write_gcode(tmp_path):
    """Write G-code text to a file in the test's folder and return its path."""

    def _write(text: str, name: str = "test.gcode") -> Path:
        path = tmp_path / name
        path.write_text(text)
        return path

    return _write


#: test tiers. Unit tests (every file not named here) take seconds; the validation tier runs
#: short simulations against analytic or reference results and is part of the default run
#: (python -m pytest, ~10 minutes on 2 cores); slow cases are marked slow and run with -m slow.
#:   python -m pytest -m "not validation and not slow"     # unit tier, about a minute
#:   python -m pytest -m validation                        # validation tier
VALIDATION_FILES = {"test_dfsph.py", "test_edac.py", "test_thermal.py", "test_outputs.py",
                    "test_print.py", "test_stability.py", "test_dam_break.py", "test_pairing.py",
                    "test_idle.py", "test_stokes.py", "test_extension.py", "test_die_swell.py"}


def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.path.name in VALIDATION_FILES:
            item.add_marker(pytest.mark.validation)
