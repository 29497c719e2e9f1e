"""Stability at the extremes (taichi_mex/stability.py): every fast case either finishes with
finite values, compression below 5 % and the commanded mass deposited, or is refused before
it runs with a message that says what to change. `python -m pytest -m slow` adds the rest;
`python -m taichi_mex.app.stability` prints the whole table."""

import pytest

from taichi_mex.app.stability import CASES, MAX_COMPRESSION, run_case

REFUSED = {"4 per D, layer 0.25 D": "Use --resolution", "EDAC at 1000 Pa s": "--scheme dfsph"}


@pytest.mark.parametrize("case", [pytest.param(c, marks=pytest.mark.slow) if c.slow else c
                                  for c in CASES], ids=[c.name for c in CASES])
def test_stability_case(case, tmp_path):
    row = run_case(case, tmp_path)
    if case.name in REFUSED:
        assert row["status"] == "refused", row
        assert REFUSED[case.name] in row["message"]
        assert row["wall_time_s"] < 30  # refused up front, not after running
        return
    assert row["status"] == "ok", row
    assert row["compression_error_max"] <= MAX_COMPRESSION
    assert row["deposited_mm3"] > 0
