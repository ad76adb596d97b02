"""CMU Panoptic 3D bodies: the joints19 -> COCO-17 mapping, centimetres -> metres, clear errors."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mvm.core.keypoints import INDEX
from mvm.errors import InputError
from mvm.io.panoptic_bodies import read_panoptic_coco19, read_panoptic_ids

from helpers import SHARED_DATA  # noqa: E402

PANOPTIC = SHARED_DATA / "panoptic" / "160906_band1" / "hdPose3d_stage1_coco19"


def _panoptic_file(path: Path, bodies) -> Path:
    path.write_text(json.dumps({"version": 0.7, "bodies": bodies}))
    return path


def test_panoptic_reader_converts_and_maps(tmp_path):
    # joint k of joints19 at (k, 100 + k, -k) cm, confidence 0.5; joint 8 (left ankle) not reconstructed
    joints = []
    for k in range(19):
        joints += [k, 100 + k, -k, -1 if k == 8 else 0.5]
    poses = read_panoptic_coco19(_panoptic_file(tmp_path / "b.json", [{"id": 7, "joints19": joints}]))
    assert poses.shape == (1, 17, 3)
    coco_from_panoptic = {"nose": 1, "left_eye": 15, "right_eye": 17, "left_ear": 16, "right_ear": 18,
                          "left_shoulder": 3, "right_shoulder": 9, "left_elbow": 4, "right_elbow": 10,
                          "left_wrist": 5, "right_wrist": 11, "left_hip": 6, "right_hip": 12,
                          "left_knee": 7, "right_knee": 13, "right_ankle": 14}
    for name, k in coco_from_panoptic.items():
        np.testing.assert_allclose(poses[0, INDEX[name]], [k / 100, 1 + k / 100, -k / 100])
    assert np.isnan(poses[0, INDEX["left_ankle"]]).all()
    assert read_panoptic_ids(tmp_path / "b.json") == [7]


def test_panoptic_reader_errors(tmp_path):
    with pytest.raises(InputError, match=r"bodies\[0\].joints19: expected 76 numbers"):
        read_panoptic_coco19(_panoptic_file(tmp_path / "short.json", [{"id": 0, "joints19": [1, 2, 3]}]))
    with pytest.raises(InputError, match="bodies"):
        read_panoptic_coco19(_panoptic_file(tmp_path / "none.json", None))
    (tmp_path / "broken.json").write_text("{")
    with pytest.raises(InputError, match="not valid JSON"):
        read_panoptic_coco19(tmp_path / "broken.json")


def test_panoptic_real_values():
    path = PANOPTIC / "body3DScene_00000168.json"
    if not path.is_file():
        pytest.skip(f"the real Panoptic data ({path}) is not in this checkout")
    poses = read_panoptic_coco19(path)
    assert poses.shape == (3, 17, 3)
    # body 0: nose (104.413, -117.401, -25.8053) cm; its left ankle has confidence -1
    np.testing.assert_allclose(poses[0, INDEX["nose"]], [1.04413, -1.17401, -0.258053])
    np.testing.assert_allclose(poses[0, INDEX["right_ankle"]], [0.698839, -0.0969057, 0.0289286])
    assert np.isnan(poses[0, INDEX["left_ankle"]]).all()
    assert read_panoptic_ids(path) == [0, 1, 2]
