"""Metrics of 3D poses: the similarity (Procrustes) alignment, PA-MPJPE and the per-person errors."""
import numpy as np
import pytest

from mvm.metrics.poses import pa_mpjpe, person_errors, pose_errors, procrustes_align, similarity_transform


def _rotation(rng):
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def test_similarity_transform_recovers_scale_rotation_translation():
    rng = np.random.default_rng(0)
    source = rng.normal(size=(4, 12, 3))
    R = np.stack([_rotation(rng) for _ in range(4)])
    s, t = rng.uniform(0.5, 2.0, 4), rng.normal(size=(4, 3))
    target = s[:, None, None] * np.einsum("nij,nkj->nki", R, source) + t[:, None]
    target[1, 3] = np.nan                                                      # not in the fit
    found_s, found_R, found_t = similarity_transform(source, target)
    np.testing.assert_allclose(found_s, s, rtol=1e-10)
    np.testing.assert_allclose(found_R, R, atol=1e-10)
    np.testing.assert_allclose(found_t, t, atol=1e-10)
    one = similarity_transform(source[0], target[0])                            # one point set
    assert one[0] == pytest.approx(s[0]) and np.allclose(one[1], R[0]) and np.allclose(one[2], t[0])
    assert similarity_transform(source[0], target[0], scale=False)[0] == 1.0
    # the mask chooses the points of the fit: a gross outlier left out does not move it
    moved = target[0].copy()
    moved[0] += 10.0
    mask = np.ones(12, bool)
    mask[0] = False
    aligned = procrustes_align(source[0], moved, mask)
    np.testing.assert_allclose(aligned[1:], target[0, 1:], atol=1e-10)
    with pytest.raises(ValueError, match="similarity_transform"):
        similarity_transform(source[0], target[0, :5])


def test_pa_mpjpe_removes_similarity_transforms():
    rng = np.random.default_rng(0)
    gt = rng.normal(size=(5, 14, 3))
    pred = np.stack([1.7 * g @ _rotation(rng).T + rng.normal(size=3) for g in gt])
    np.testing.assert_allclose(pa_mpjpe(pred, gt), 0.0, atol=1e-9)
    noisy = pred.copy()
    noisy[0, 3] += 0.5
    e = pa_mpjpe(noisy, gt)
    assert e[0] > 0.01 and np.allclose(e[1:], 0.0, atol=1e-9)
    # a mirror image is not a rotation: it is not aligned away
    assert pa_mpjpe(gt * np.array([-1, 1, 1]), gt).mean() > 0.1


def test_pa_mpjpe_ignores_missing_joints_and_needs_three():
    rng = np.random.default_rng(2)
    gt = rng.normal(size=(3, 17, 3))
    pred = 0.8 * gt @ _rotation(rng).T + 1.0
    pred[0, :5] = np.nan                                                       # missing in the estimate
    gt[1, 2] = np.nan                                                          # missing in the truth
    pred[2, 3:] = np.nan                                                       # three joints left
    pred[2, 0] += 0.1
    e = pa_mpjpe(pred, gt)
    assert e[0] == pytest.approx(0.0, abs=1e-9) and e[1] == pytest.approx(0.0, abs=1e-9)
    assert e[2] > 0.0
    pred[2, 2] = np.nan                                                        # two joints: not scored
    assert np.isnan(pa_mpjpe(pred, gt)[2])


def test_person_errors_of_matched_pairs():
    rng = np.random.default_rng(4)
    truth = rng.normal(size=(3, 17, 3))
    estimate = truth[[2, 0, 1]] + 0.01                                         # shifted by (0.01, 0.01, 0.01)
    estimate[1, 4] += 0.3
    estimate[2, 2:] = np.nan                                                   # two joints: not evaluated
    mpjpe, pa = person_errors(estimate, truth, [(0, 2), (1, 0), (2, 1)])
    shift = 0.01 * np.sqrt(3)
    assert mpjpe[0] == pytest.approx(shift) and pa[0] == pytest.approx(0.0, abs=1e-9)
    expected = (16 * shift + np.linalg.norm(estimate[1, 4] - truth[0, 4])) / 17
    assert len(mpjpe) == 2 and mpjpe[1] == pytest.approx(expected) and pa[1] > 0.0
    summary = pose_errors(estimate, truth, [(0, 2), (1, 0), (2, 1)])
    assert summary["evaluated_persons"] == 2 and summary["mpjpe"] == pytest.approx(mpjpe.mean())
    assert person_errors(estimate, truth, [])[0].shape == (0,)
    assert np.isnan(pose_errors(estimate, truth, [])["mpjpe"])
