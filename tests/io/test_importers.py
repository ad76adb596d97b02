"""OpenPose and OpenPifPaf per-frame JSON importers."""
import json

import numpy as np
import pytest

from mvm.errors import InputError
from mvm.io.openpifpaf import read_openpifpaf_dir, read_openpifpaf_frame
from mvm.io.openpose import frame_number, read_openpose_dir, read_openpose_frame

# OpenPose part names in BODY_25 and COCO-18 order; the COCO-17 names they map to.
BODY25 = ["nose", "neck", "r_sho", "r_elb", "r_wri", "l_sho", "l_elb", "l_wri", "mid_hip", "r_hip", "r_knee",
          "r_ank", "l_hip", "l_knee", "l_ank", "r_eye", "l_eye", "r_ear", "l_ear", "l_btoe", "l_stoe", "l_heel",
          "r_btoe", "r_stoe", "r_heel"]
COCO18 = ["nose", "neck", "r_sho", "r_elb", "r_wri", "l_sho", "l_elb", "l_wri", "r_hip", "r_knee", "r_ank",
          "l_hip", "l_knee", "l_ank", "r_eye", "l_eye", "r_ear", "l_ear"]
COCO17 = ["nose", "l_eye", "r_eye", "l_ear", "r_ear", "l_sho", "r_sho", "l_elb", "r_elb", "l_wri", "r_wri",
          "l_hip", "r_hip", "l_knee", "r_knee", "l_ank", "r_ank"]


def _person(names):
    """Keypoints whose x encodes the part: x = 10 * index in COCO17 (+1), y = 2x; neck etc. x = 999."""
    values = []
    for n in names:
        x = 10.0 * (COCO17.index(n) + 1) if n in COCO17 else 999.0
        values += [x, 2 * x, 0.8]
    return values


@pytest.mark.parametrize("layout", [BODY25, COCO18])
def test_openpose_layouts_map_to_coco17(tmp_path, layout):
    person = _person(layout)
    person[3 * layout.index("l_knee") + 2] = 0.0                # a missing joint: 0, 0, 0
    person[3 * layout.index("l_knee")] = person[3 * layout.index("l_knee") + 1] = 0.0
    path = tmp_path / "cam1_000000000042_keypoints.json"
    path.write_text(json.dumps({"version": 1.3, "people": [{"person_id": [-1], "pose_keypoints_2d": person}] * 2}))
    kp = read_openpose_frame(path)
    assert kp.shape == (2, 17, 3)
    expected = 10.0 * (np.arange(17) + 1)
    expected[COCO17.index("l_knee")] = 0
    np.testing.assert_allclose(kp[0, :, 0], expected)
    np.testing.assert_allclose(kp[0, :, 1], 2 * expected)
    assert kp[0, COCO17.index("l_knee"), 2] == 0 and kp[0, 0, 2] == 0.8
    assert frame_number(path) == 42


def test_openpose_dir_sorted_by_number_and_errors(tmp_path):
    for f in (10, 2, 1):
        (tmp_path / f"vid_{f}_keypoints.json").write_text(json.dumps({"people": [{"pose_keypoints_2d": [0.0] * 75}]}))
    assert list(read_openpose_dir(tmp_path)) == [1, 2, 10]
    (tmp_path / "vid_3_keypoints.json").write_text(json.dumps({"people": [{"pose_keypoints_2d": [0.0] * 70}]}))
    with pytest.raises(InputError, match=r"people\[0\]\.pose_keypoints_2d: expected 75"):
        read_openpose_dir(tmp_path)


def test_openpifpaf_frame(tmp_path):
    kp = np.arange(51, dtype=float).reshape(17, 3)
    kp[:, 2] = 0.5
    kp[3] = 0
    items = [{"keypoints": kp.reshape(-1).tolist(), "bbox": [0, 0, 10, 10], "score": 0.7, "category_id": 1},
             {"keypoints": kp.reshape(-1).tolist(), "bbox": [0, 0, 1, 1], "score": 0.2, "category_id": 2}]
    path = tmp_path / "000007.png.predictions.json"
    path.write_text(json.dumps(items))
    keypoints, scores = read_openpifpaf_frame(path)
    assert keypoints.shape == (1, 17, 3) and scores.tolist() == [0.7]
    np.testing.assert_allclose(keypoints[0], kp)
    assert list(read_openpifpaf_dir(tmp_path)) == [7]
    path.write_text(json.dumps([{"keypoints": [1, 2, 3]}]))
    with pytest.raises(InputError, match=r"\[0\]\.keypoints: expected 51 numbers, got 3"):
        read_openpifpaf_frame(path)
