"""Thread shares (core/shares.py): every row once, cut at equal work, whatever the thread
count; the EDAC passes that loop over them give the same bits as loops over all particles."""

import numpy as np
import pytest

from taichi_mex import backend
from taichi_mex.backend import ti
from taichi_mex.core.shares import ThreadShares


@pytest.fixture(scope="module", autouse=True)
def _taichi():
    backend.init("cpu", "f32")


def _visit(shares: ThreadShares) -> np.ndarray:
    out = ti.field(ti.i32, shape=max(1, shares.span[None]))

    @ti.kernel
    def visit():
        for k in range(shares.span[None]):
            out[k] = shares.row(k)

    visit()
    return out.to_numpy()[:shares.span[None]]


@pytest.mark.parametrize("threads", [1, 2, 3, 7])
def test_every_row_once_and_shares_of_equal_work(threads):
    rng = np.random.default_rng(threads)
    n = 1000
    rows = rng.permutation(5000)[:n].astype(np.int32)
    weight = np.where(np.arange(n) < n // 4, 60, 1).astype(np.int32)  # the work in one corner
    shares = ThreadShares(5000, threads=threads)
    shares.rows.from_numpy(np.pad(rows, (0, 4000)))
    shares.weight.from_numpy(np.pad(weight, (0, 4000)))
    shares.split(n)
    seen = _visit(shares)
    assert shares.span[None] == threads * shares.share[None]
    assert sorted(seen[seen >= 0]) == sorted(rows)  # each row once, the rest padding
    bounds = shares.bounds.to_numpy()
    assert bounds[0] == 0 and bounds[-1] == n and np.all(np.diff(bounds) >= 0)
    work = [weight[bounds[t]:bounds[t + 1]].sum() for t in range(threads)]
    # a cut falls after the row whose work crosses the share: off by at most one row's work
    assert max(work) - weight.sum() / threads <= weight.max()
    # the loop index's chunk t (of span / threads) is exactly share t, in storage order
    for t in range(threads):
        chunk = seen[t * shares.share[None]:(t + 1) * shares.share[None]]
        assert list(chunk[chunk >= 0]) == list(rows[bounds[t]:bounds[t + 1]])


def test_no_rows_is_an_empty_loop():
    shares = ThreadShares(16, threads=2)
    shares.split(0)
    assert shares.span[None] == 0 and len(_visit(shares)) == 0
