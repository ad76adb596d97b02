"""min_cost_assignment: scipy's optimum on small matrices, without importing scipy."""
import math
import subprocess
import sys

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from mvm.core.assignment import MAX_ENUMERATED, min_cost_assignment


@pytest.mark.parametrize("shape", [(1, 1), (1, 4), (4, 1), (2, 2), (2, 3), (3, 2), (3, 5), (5, 3), (4, 4), (6, 6),
                                   (7, 7), (3, 9)])
def test_same_matching_as_scipy(shape):
    rng = np.random.default_rng(sum(shape))
    for _ in range(20):
        cost = rng.random(shape)
        cost[rng.random(shape) < 0.3] = 1e6                       # the padding of pairs beyond the gate
        rows, cols = min_cost_assignment(cost)
        expected = linear_sum_assignment(cost)
        np.testing.assert_array_equal(rows, expected[0])
        np.testing.assert_array_equal(cols, expected[1])


@pytest.mark.parametrize("shape", [(8, 8), (8, 12), (12, 8), (20, 20), (30, 45), (45, 30)])
def test_large_matrices_by_augmenting_paths_match_scipy(shape):
    assert math.perm(max(shape), min(shape)) > MAX_ENUMERATED
    rng = np.random.default_rng(sum(shape))
    for _ in range(10):
        cost = rng.random(shape)
        cost[rng.random(shape) < 0.4] = 1e6
        rows, cols = min_cost_assignment(cost)
        expected = linear_sum_assignment(cost)
        np.testing.assert_array_equal(rows, expected[0])
        np.testing.assert_array_equal(cols, expected[1])
        ties = np.round(cost * 3)                               # many optima: the same least sum
        rows, cols = min_cost_assignment(ties)
        assert len(np.unique(cols)) == len(cols) == min(shape) and np.all(np.diff(rows) > 0)
        assert ties[rows, cols].sum() == ties[linear_sum_assignment(ties)].sum()


def test_empty_matrices_match_nothing():
    assert [len(a) for a in min_cost_assignment(np.zeros((0, 3)))] == [0, 0]
    with pytest.raises(ValueError, match=r"expected a \(n, m\) matrix"):
        min_cost_assignment(np.zeros(3))


def test_a_clash_in_a_view_imports_no_scipy():
    code = """
import sys
import numpy as np
from mvm.core.association import assign_per_frame
# two poses of one view both nearest to person 0: a clash, solved as an assignment
out = assign_per_frame(np.array([0.05, 0.08, 0.06, 0.2]), np.array([0, 0, 1, 1]), np.array([0, 1, 0, 1]),
                       np.zeros(4, dtype=int), 2, 0.15)
assert out.tolist() == [1, 0], out
from mvm.core.assignment import min_cost_assignment
min_cost_assignment(np.random.default_rng(0).random((12, 12)))      # beyond enumeration
assert "scipy" not in sys.modules
"""
    run = subprocess.run([sys.executable, "-c", code], check=False, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
