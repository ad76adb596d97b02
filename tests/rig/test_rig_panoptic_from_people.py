"""Synchronizing and calibrating from the people on the real Panoptic sample: real cameras and
real 3D poses, detections simulated with the detector's errors."""
import numpy as np
import pytest

from mvm.eval.panoptic import load_sample
from mvm.eval.rig_from_people import calibration_check, sync_check

from helpers import SHARED_DATA

SEQUENCE = SHARED_DATA / "panoptic" / "160906_band1"
pytestmark = pytest.mark.skipif(not SEQUENCE.is_dir(), reason=f"Panoptic sample absent ({SEQUENCE})")


@pytest.mark.parametrize("seed", [0, 1])
def test_panoptic_offsets_recovered_exactly(seed):
    offsets = np.array([0, 3, -2, 2, -3])                      # several frames each way (the sample has 20)
    result = sync_check(load_sample(SEQUENCE), 5, offsets, seed=seed)
    assert result["found_offsets"] == result["true_offsets"] == (offsets - offsets[0]).tolist()
    assert not any(result["ambiguous"])
    assert result["pcp_found_offsets"] == result["pcp_true_offsets"] > result["pcp_unsynchronized"]


def test_panoptic_calibration_from_people():
    result = calibration_check(load_sample(SEQUENCE), 5)
    assert result["mean_centre_error_m"] < 0.05
    assert abs(result["pcp_estimated_calibration"] - result["pcp_true_calibration"]) <= 0.01
    assert abs(result["scale_error"]) < 0.1                   # metres from the mean adult bone lengths


@pytest.mark.slow
def test_panoptic_focal_lengths_refined():
    """Focal lengths given 5 % off (alternately up and down): refined to within 1.5 %, the camera
    centres back within 5 cm (about 11 cm without refining them)."""
    result = calibration_check(load_sample(SEQUENCE), 5, focal_error=0.05, refine_focal=True)
    assert max(abs(e) for e in result["focal_error_found"]) < 0.015
    assert result["mean_centre_error_m"] < 0.05
    assert abs(result["pcp_estimated_calibration"] - result["pcp_true_calibration"]) <= 0.01
