"""The motion-capture field's metrics: PCP (Shelf/Campus) and AP (Panoptic)."""
import numpy as np
import pytest

from mvm.metrics.mocap_scores import COCO_PCP_LIMBS, average_precision, limbs_correct, pcp


def test_pcp_definition():
    truth = np.zeros((1, 17, 3))
    truth[0, :, 2] = np.arange(17) * 0.1                                # every limb has a known length
    est = truth.copy()
    # left upper arm (5 -> 7), true length 0.2: move both ends by 0.1 (mean = half the length: correct)
    est[0, 5, 0] += 0.1
    est[0, 7, 0] += 0.1
    assert limbs_correct(est, truth)[0, 0]
    est[0, 7, 0] += 0.01                                               # now beyond half the length
    ok = limbs_correct(est, truth)[0]
    assert not ok[0]
    names = list(COCO_PCP_LIMBS)
    result = pcp([est], [truth], [np.array([7])])
    expected = ok.mean()
    assert result["actor"][7] == pytest.approx(expected)
    assert not result["per_actor"][7]["left_upper_arm"] and result["per_actor"][7]["torso"]
    assert "torso" in names and "head" in names
    assert pcp([np.zeros((0, 17, 3))], [truth])["average"] == 0.0      # nothing found: all wrong


def test_average_precision():
    truth = np.zeros((2, 17, 3))
    truth[1] += 5.0
    good = truth[0] + [0.02, 0, 0]                                     # 20 mm error
    far = truth[1] + [0.1, 0, 0]                                       # 100 mm error
    ap = average_precision([np.stack([good, far])], [np.array([0.9, 0.8])], [truth])
    assert ap["AP@25"] == pytest.approx(0.5)                           # one of two people
    assert ap["AP@125"] == pytest.approx(1.0)
    duplicate = average_precision([np.stack([good, good])], [np.array([0.9, 0.8])], [truth])
    assert duplicate["AP@150"] == pytest.approx(0.5)                   # a duplicate is a false positive
