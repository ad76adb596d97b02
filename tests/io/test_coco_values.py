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


def _same_columns(a, b):
    for x, y in zip(a, b):
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
        else:
            assert len(x) == len(y)
            for u, v in zip(x, y):
                if u is None or v is None:
                    assert u is v
                else:
                    np.testing.assert_array_equal(u, v)


def test_annotations_checked_at_once_as_one_by_one():
    """The all-at-once reading gives exactly what the per-annotation reading gives (scores
    given or defaulted, flags 2, absent joints, non-persons, descriptors), and hands every
    annotation with a problem, or a mix of descriptors, to the per-annotation reading."""
    from mvm.io.coco import _annotations_one_by_one, annotations_at_once

    rng = np.random.default_rng(11)
    index = {1: 0, 2: 1}
    _, doc = _document(rng, 9, extra=[{"id": 99, "image_id": 2, "category_id": 3, "keypoints": "none"}])
    annotations = doc["annotations"]
    annotations[3]["score"] = 7                                    # an integer, clipped to 1
    annotations[4]["keypoints"][2::3] = [0.0] * 17                 # no joint: score 0
    fast = annotations_at_once(annotations, index)
    assert fast is not None
    _same_columns(fast, _annotations_one_by_one(annotations, "x.json", index))
    described = [dict(a, appearance=rng.normal(size=4).tolist()) for a in annotations]
    fast = annotations_at_once(described, index)
    assert fast is not None and fast[4][0].shape == (4,)
    _same_columns(fast, _annotations_one_by_one(described, "x.json", index))
    bad = [
        lambda a: a[2].update(score=None), lambda a: a[2].update(score=-1.0), lambda a: a[2].update(id=True),
        lambda a: a[5].update(id=a[6]["id"]), lambda a: a[1].update(image_id=7),
        lambda a: a[0]["keypoints"].__setitem__(5, float("nan")), lambda a: a[0]["keypoints"].__setitem__(5, "1"),
        lambda a: a[0]["keypoints"].__setitem__(2, -0.5), lambda a: a[0]["keypoints"].pop(),
        lambda a: a[3].update(appearance=[1.0]), lambda a: a.append(7), lambda a: a[0].update(score=10 ** 400),
    ]
    for spoil in bad:
        spoiled = json.loads(json.dumps(annotations))
        spoil(spoiled)
        assert annotations_at_once(spoiled, index) is None, spoil
