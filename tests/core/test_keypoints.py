"""Body proportions: bone lengths and the metric scale s* they give."""
import numpy as np
import pytest

from mvm.core.keypoints import BONES, MEAN_BONE_LENGTHS_M, bone_lengths, optimal_scale


def test_bone_lengths_by_hand():
    X = np.zeros((2, 17, 3))
    X[0, 7] = [0.0, 0.3, 0.4]                    # left elbow 0.5 from the left shoulder (joint 5)
    X[1, 5] = np.nan
    lengths = bone_lengths(X)
    assert lengths.shape == (2, len(BONES))
    assert lengths[0, BONES.index((5, 7))] == pytest.approx(0.5)
    assert lengths[0, BONES.index((7, 9))] == pytest.approx(0.5)
    assert np.isnan(lengths[1, [BONES.index(b) for b in BONES if 5 in b]]).all()
    assert (lengths[1, [BONES.index(b) for b in BONES if 5 not in b]] == 0).all()


def test_scale_calibration_closed_form():
    rng = np.random.default_rng(4)
    l = rng.uniform(0.1, 0.5, 12)
    s = optimal_scale(l)
    expected = (MEAN_BONE_LENGTHS_M * l).sum() / (l * l).sum()
    assert s == pytest.approx(expected)
    # s* minimizes Σ ½ (s l − l̄)²: the derivative vanishes there
    assert ((s * l - MEAN_BONE_LENGTHS_M) * l).sum() == pytest.approx(0.0, abs=1e-12)
    l[3] = np.nan
    ok = np.isfinite(l)
    assert optimal_scale(l) == pytest.approx((MEAN_BONE_LENGTHS_M[ok] * l[ok]).sum() / (l[ok] ** 2).sum())


def test_scale_is_batched_and_undefined_without_bones():
    rng = np.random.default_rng(5)
    l = rng.uniform(0.1, 0.5, (4, 12))
    l[1, :3] = np.nan
    l[2] = np.nan
    s = optimal_scale(l)
    assert s.shape == (4,) and np.isnan(s[2])
    for i in (0, 1, 3):
        assert s[i] == pytest.approx(float(optimal_scale(l[i])))
    assert float(optimal_scale(MEAN_BONE_LENGTHS_M / 3.0)) == pytest.approx(3.0)
