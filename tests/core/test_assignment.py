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


def test_large_matrices_go_to_scipy_and_empty_ones_match_nothing():
    assert math.perm(8, 8) > MAX_ENUMERATED
    cost = np.random.default_rng(1).random((8, 8))
    np.testing.assert_array_equal(min_cost_assignment(cost)[1], linear_sum_assignment(cost)[1])
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
assert "scipy.optimize" not in sys.modules
"""
    run = subprocess.run([sys.executable, "-c", code], check=False, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
