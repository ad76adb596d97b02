"""The real Panoptic sample: real cameras (with their lens distortion) and real 3D poses."""

import numpy as np
import pytest

from mvm.core.config import Config
from mvm.eval.panoptic import evaluate, load_sample, spread_cameras

from helpers import SHARED_DATA

SEQUENCE = SHARED_DATA / "panoptic" / "160906_band1"
pytestmark = pytest.mark.skipif(not SEQUENCE.is_dir(), reason=f"Panoptic sample absent ({SEQUENCE})")


def test_panoptic_five_cameras():
    sample = load_sample(SEQUENCE)
    assert len(sample.calibration.cameras) == 31 and len(sample.poses) == 20
    index = spread_cameras(sample.calibration.cameras, 5)
    assert len(np.unique(index)) == 5
    result = evaluate(sample, 5, Config(refine=False), seeds=1)
    assert result["found"] >= 0.95
    assert result["mpjpe_mm"] < 30.0
    assert result["AP@50"] > 0.9
