"""COCO keypoint annotations read back as the file holds them, with or without a non-person
annotation among them."""
import json

import numpy as np

from mvm.io.coco import read_coco_keypoints


def _document(rng, n, extra=()):
    kp = np.column_stack([rng.uniform(0, 640, (n * 17, 2)), rng.choice([0.0, 0.4, 1.0, 2.0], n * 17)])
    kp = kp.reshape(n, 17, 3)
    annotations = [{"id": 10 + i, "image_id": 1 + i % 2, "category_id": 1, "keypoints": kp[i].ravel().tolist()}
                   for i in range(n)]
    for i in range(0, n, 2):
        annotations[i]["score"] = 0.25 * (i % 5)
    images = [{"id": 1, "file_name": "a.jpg", "width": 640, "height": 480}, {"id": 2, "file_name": "b.jpg"}]
    return kp, {"images": images, "annotations": annotations + list(extra), "categories": []}


def test_annotations_read_as_the_file_holds_them(tmp_path):
    rng = np.random.default_rng(3)
    kp, doc = _document(rng, 7)
    expected = kp.copy()
    expected[..., 2] = np.minimum(expected[..., 2], 1.0)
    expected[expected[..., 2] == 0, :2] = 0.0
    plain = tmp_path / "plain.json"
    plain.write_text(json.dumps(doc))
    # a non-person annotation is skipped
    mixed = tmp_path / "mixed.json"
    mixed.write_text(json.dumps({**doc, "annotations": doc["annotations"] + [
        {"id": 99, "image_id": 1, "category_id": 3, "keypoints": [0] * 51}]}))
    a, b = read_coco_keypoints(plain), read_coco_keypoints(mixed)
    for coco in (a, b):
        np.testing.assert_array_equal(coco.keypoints, expected)
        np.testing.assert_array_equal(coco.ann_ids, 10 + np.arange(7))
        np.testing.assert_array_equal(coco.ann_image, np.arange(7) % 2)
    np.testing.assert_array_equal(a.score, b.score)
    present = expected[1, :, 2] > 0
    assert a.score[1] == expected[1, present, 2].mean()          # no score: the mean keypoint confidence
    assert a.score[2] == 0.5
