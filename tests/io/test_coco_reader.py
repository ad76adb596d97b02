"""The one COCO reader of io/: data sets, results files and the format of a pose source. Every
bad file gives one InputError line naming the file and the field."""
from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest

from mvm.errors import InputError
from mvm.io.coco import annotation_record, empty_dataset, read_coco_keypoints
from mvm.io.coco_dataset import read_coco_dataset
from mvm.io.coco_results import read_coco_results, results_frame_index, results_image_index
from mvm.io.pose_format import pose_format

KP = [10.0, 20.0, 2] * 17


def _dataset(**changes) -> dict:
    """Two images, three person annotations (one a crowd without keypoints)."""
    doc = {"images": [{"id": 1, "file_name": "a.jpg"}, {"id": 2, "file_name": "b.jpg"}],
           "annotations": [{"id": 1, "image_id": 1, "category_id": 1, "keypoints": list(KP)},
                           {"id": 2, "image_id": 2, "category_id": 1, "keypoints": list(KP)},
                           {"id": 3, "image_id": 2, "category_id": 1, "iscrowd": 1, "bbox": [0, 0, 5, 5]}],
           "categories": [{"id": 1, "name": "person"}]}
    for where, value in changes.items():
        kind, i, key = where.split("__")
        doc[kind][int(i)][key] = value
    return doc


def _one_line(read, path, field: str, problem: str) -> None:
    with pytest.raises(InputError) as info:
        read(path)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: {field}: "), message
    assert problem in message, message


def _write(tmp_path, doc, name="set.json"):
    path = tmp_path / name
    path.write_text(json.dumps(doc) if not isinstance(doc, str) else doc)
    return path


# --- data sets: what read_annotations (training) now checks too ----------------------------------

@pytest.mark.parametrize("changes, field, problem", [
    ({"images__1__id": 1}, "images[1].id", "duplicate image id 1"),
    ({"annotations__1__id": 1}, "annotations[1].id", "duplicate annotation id 1"),
    ({"annotations__1__image_id": 9}, "annotations[1].image_id", "no image with id 9"),
    ({"annotations__0__keypoints": KP[:-3]}, "annotations[0].keypoints", "expected 51 numbers"),
    ({"annotations__0__keypoints": KP[:4] + ["x"] + KP[5:]}, "annotations[0].keypoints[4]",
     "expected a number, got str"),
    ({"annotations__0__keypoints": KP[:4] + [10 ** 400] + KP[5:]}, "annotations[0].keypoints[4]", "number too large"),
    ({"annotations__0__score": "high"}, "annotations[0].score", "expected a number, got str"),
    ({"images__0__file_name": "/etc/passwd"}, "images[0].file_name", "absolute path '/etc/passwd' is not allowed"),
    ({"images__0__file_name": "C:\\x.jpg"}, "images[0].file_name", "absolute path"),
    ({"annotations__2__iscrowd": "yes"}, "annotations[2].iscrowd", "expected 0 or 1, got 'yes'"),
    ({"annotations__2__bbox": [0, 0, "w", 5]}, "annotations[2].bbox[2]", "expected a number, got str"),
    ({"annotations__2__bbox": [0, 0, 5]}, "annotations[2].bbox", "expected 4 numbers"),
    ({"annotations__1__keypoint_depths": [1.0] * 16}, "annotations[1].keypoint_depths", "expected 17 numbers, got 16"),
    ({"annotations__1__keypoint_depths": [1.0] * 16 + [-2]}, "annotations[1].keypoint_depths[16]", "negative depth"),
    ({"annotations__1__keypoint_depths": [1.0] * 16 + [float("nan")]}, "annotations[1].keypoint_depths[16]",
     "not a finite number"),
    ({"annotations__1__keypoint_depths": [1.0] * 17, "annotations__1__has_3d": [1] * 16 + [7]},
     "annotations[1].has_3d", "expected 17 flags 0 or 1"),
    ({"annotations__1__keypoint_flags": ["observed"] * 16 + ["guessed"]}, "annotations[1].keypoint_flags",
     "unknown flag 'guessed'"),
    ({"annotations__1__keypoint_flags": ["observed"] * 16}, "annotations[1].keypoint_flags", "a list of 17 names"),
])
def test_bad_data_set_is_one_line_for_training_too(tmp_path, changes, field, problem):
    from mvm.net.data import read_annotations

    path = _write(tmp_path, _dataset(**changes))
    _one_line(read_coco_dataset, path, field, problem)
    _one_line(read_annotations, path, field, problem)


def test_data_set_names_may_climb_above_the_file_but_scene_poses_may_not(tmp_path):
    """A supervision set exported with --link none names its frames relative to itself."""
    from mvm.net.data import read_annotations

    path = _write(tmp_path, _dataset(images__0__file_name="../frames/a.jpg"))
    assert read_annotations(path).paths[0] == tmp_path / "../frames/a.jpg"
    _one_line(read_coco_keypoints, path, "images[0].file_name", "leads outside")


def test_data_set_fields_read_back_as_written(tmp_path):
    """The writers (io/coco.py) and the data set reader agree: depths where has_3d and the
    keypoint is present, flags, crowds and boxes, and the training view of them."""
    from mvm.core.completion import INFERRED, MISSING, OBSERVED
    from mvm.net.data import read_annotations

    kp = np.zeros((17, 3))
    kp[:, 0], kp[:, 1], kp[:, 2] = np.arange(17) + 5.0, np.arange(17) * 2 + 5.0, 2
    kp[3] = 0
    depths = np.linspace(0.5, 1.5, 17)
    flags = np.full(17, OBSERVED)
    flags[5] = INFERRED
    doc = empty_dataset("test")
    doc["images"] = [{"id": 7, "file_name": "x.jpg"}, {"id": 8, "file_name": "y.jpg"}]
    doc["annotations"] = [annotation_record(1, 8, kp, depths, person_id=0, flags=flags),
                          {"id": 2, "image_id": 8, "category_id": 1, "iscrowd": 1, "bbox": [1, 2, 3, 4]}]
    data = read_coco_dataset(_write(tmp_path, doc))
    want = depths.copy()
    want[3] = np.nan
    np.testing.assert_allclose(data.depths[0], want, atol=1e-5)
    assert np.isnan(data.depths[1]).all()
    assert data.flags[0, 5] == INFERRED and data.flags[0, 3] == MISSING and data.flags[0, 0] == OBSERVED
    assert (data.flags[1] == MISSING).all()
    assert data.crowd.tolist() == [False, True]
    np.testing.assert_allclose(data.boxes[1], [1, 2, 4, 6])
    assert data.people.ann_image.tolist() == [1, 1] and data.people.image_ids.tolist() == [7, 8]
    ann = read_annotations(tmp_path / "set.json", people_only=True)
    assert ann.image_ids.tolist() == [8] and len(ann.keypoints[0]) == 1
    np.testing.assert_allclose(ann.ignore[0], [[1, 2, 4, 6]])
    np.testing.assert_allclose(ann.depths[0][0], want, atol=1e-5)


def test_the_writers_need_not_the_network_package():
    """The simulator writes its data sets with io/coco.py's writers, without mvm.net."""
    code = "import sys, mvm.io.coco, mvm.io.coco_dataset; print(any(m.startswith('mvm.net') for m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


# --- results files ----------------------------------------------------------------------------

def _results(**changes) -> list:
    results = [{"image_id": 1, "category_id": 1, "keypoints": list(KP), "score": 0.5} for _ in range(3)]
    for where, value in changes.items():
        k, key = where.split("__")
        results[int(k)][key] = value
    return results


@pytest.mark.parametrize("changes, field, problem", [
    ({"1__score": "high"}, "[1].score", "expected a number, got str"),
    ({"1__score": 10 ** 400}, "[1].score", "number too large"),
    ({"1__score": -0.5}, "[1].score", "negative score"),
    ({"2__keypoints": KP[:-1]}, "[2].keypoints", "expected 51 numbers (17 keypoints × x, y, v), got 50"),
    ({"2__keypoints": KP[:7] + [None] + KP[8:]}, "[2].keypoints[7]", "expected a number, got NoneType"),
    ({"2__keypoints": KP[:7] + [float("inf")] + KP[8:]}, "[2].keypoints[7]", "not a finite number"),
    ({"2__keypoints": KP[:2] + [-1] + KP[3:]}, "[2].keypoints", "negative keypoint confidence"),
    ({"0__image_id": 1.5}, "[0].image_id", "expected a file name or an integer, got 1.5"),
    ({"0__image_id": True}, "[0].image_id", "expected a file name or an integer"),
    ({"0__image_id": 2 ** 70}, "[0].image_id", "integer out of the 64-bit range"),
    ({"0__category_id": "person"}, "[0].category_id", "expected an integer, got str"),
])
def test_bad_results_file_is_one_line(tmp_path, changes, field, problem):
    path = _write(tmp_path, _results(**changes), "results.json")
    _one_line(read_coco_results, path, field, problem)


def test_results_not_a_list_and_a_missing_score(tmp_path):
    with pytest.raises(InputError, match=r"r\.json: expected a JSON list of results$"):
        read_coco_results(_write(tmp_path, {"a": 1}, "r.json"))
    path = _write(tmp_path, [{"image_id": 1, "keypoints": KP}], "s.json")
    assert np.isnan(read_coco_results(path).score).all()
    _one_line(lambda p: read_coco_results(p, require_score=True), path, "[0].score", "missing")


def test_results_keep_the_keypoints_as_given_and_match_images(tmp_path):
    """Evaluation needs the detections as given (pycocotools reads every coordinate); an
    image the ground truth lacks is one line naming the entry and the id."""
    kp = list(KP)
    kp[3:6] = [33.0, 44.0, 0.0]                              # a joint of confidence 0 keeps its place
    results = [{"image_id": 5, "keypoints": kp, "score": 0.9}, {"image_id": 1, "category_id": 2, "keypoints": []},
               {"image_id": "b.jpg", "keypoints": KP, "score": 0.3}, {"image_id": 9, "keypoints": KP, "score": 0.1}]
    path = _write(tmp_path, results, "r.json")
    read = read_coco_results(path)
    assert read.image_ids == (5, "b.jpg", 9) and read.entries.tolist() == [0, 2, 3]
    np.testing.assert_array_equal(read.keypoints[0].reshape(-1), kp)
    known = dataclasses.replace(read, image_ids=read.image_ids[:2], entries=read.entries[:2])
    assert results_image_index(known, path, [5, 6], ["a.jpg", "b.jpg"]).tolist() == [0, 1]
    _one_line(lambda p: results_image_index(read, p, [5, 6], ["a.jpg", "b.jpg"]), path, "[3].image_id",
              "no image with id 9 in the ground truth")


def test_unknown_image_in_evaluated_detections_is_one_line(tmp_path):
    """Before, pycocotools stopped on an AssertionError."""
    evaluate = pytest.importorskip("mvm.net.evaluate", reason="the network package needs torch")
    truth = _write(tmp_path, _dataset())
    path = _write(tmp_path, _results(**{"2__image_id": 9}), "r.json")
    _one_line(lambda p: evaluate.evaluate_detections(truth, p), path, "[2].image_id", "no image with id 9")


def test_integer_image_ids_of_a_scene_are_1_based_frame_positions(tmp_path):
    """The documented rule of ``mvm detect --import``: an integer is the frame's 1-based
    position in the scene's frame list, a string its file name or stem."""
    names = ["f_000010.jpg", "f_000020.jpg", "f_000030.jpg"]
    results = [{"image_id": i, "keypoints": KP, "score": 0.5} for i in (1, 3, 0, 4, 10, 20)]
    results += [{"image_id": n, "keypoints": KP, "score": 0.5} for n in ("f_000020.jpg", "f_000030", "nope.jpg")]
    read = read_coco_results(_write(tmp_path, results, "r.json"))
    assert results_frame_index(read, names).tolist() == [0, 2, -1, -1, -1, -1, 1, 2, -1]


# --- the format of a pose source ----------------------------------------------------------------

def test_pose_format_of_files_and_folders(tmp_path):
    assert pose_format(_write(tmp_path, "\n  [ ]", "r.json")) == ("coco-results", [])
    assert pose_format(_write(tmp_path, _dataset(), "d.json")) == ("coco", [])
    openpose = tmp_path / "op"
    openpose.mkdir()
    for n in (12, 3):
        _write(openpose, {"people": []}, f"cam_{n:06d}_keypoints.json")
    fmt, files = pose_format(openpose)
    assert fmt == "openpose" and [n for n, _ in files] == [3, 12]
    pifpaf = tmp_path / "pp"
    pifpaf.mkdir()
    _write(pifpaf, [], "000001.jpg.predictions.json")
    assert pose_format(pifpaf)[0] == "openpifpaf"


def test_bad_pose_sources_are_one_line(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError, match=r"empty: no \.json pose files$"):
        pose_format(empty)
    odd = tmp_path / "odd"
    odd.mkdir()
    _write(odd, {"persons": []}, "000001.json")
    with pytest.raises(InputError, match=r"000001\.json: neither OpenPose"):
        pose_format(odd)
    with pytest.raises(InputError, match=r"missing\.json: file or directory not found$"):
        pose_format(tmp_path / "missing.json")


def test_a_rig_camera_given_a_results_list_is_one_line(tmp_path):
    from mvm.rig.rigdir import _source_format

    path = _write(tmp_path, _results(), "cam_1.json")
    with pytest.raises(InputError, match=r"cam_1\.json: a COCO results list"):
        _source_format(path, tmp_path)


def _same(a, b) -> None:
    for x, y in zip(a, b):
        if x is None or y is None:
            assert x is y
        elif isinstance(x, list):
            assert len(x) == len(y) and all((u is None and v is None) or np.array_equal(u, v) for u, v in zip(x, y))
        else:
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_data_set_checked_at_once_as_one_by_one():
    """The all-at-once reading of a data set gives exactly what the per-annotation reading
    gives, and hands every annotation with a problem to it (which names the problem)."""
    from mvm.io.coco_dataset import _dataset_at_once, _dataset_one_by_one

    rng = np.random.default_rng(5)
    annotations = _dataset()["annotations"] + [
        {"id": 4, "image_id": 1, "category_id": 1, "keypoints": [float(v) for v in rng.uniform(0, 2, 51)],
         "bbox": [3, 4, 0, 5], "keypoint_depths": rng.uniform(0, 2, 17).tolist(), "has_3d": [1, 0] * 8 + [True],
         "keypoint_flags": ["observed", "inferred"] * 8 + ["missing"]},
        {"id": 5, "image_id": 2, "category_id": 1, "keypoints": list(KP), "keypoint_depths": [0.5] * 17,
         "bbox": [1.5, 2, 3, 4], "iscrowd": False},
        {"id": 6, "image_id": 2, "category_id": 2}]
    index = {1: 0, 2: 1}
    fast = _dataset_at_once(annotations, index)
    assert fast is not None and fast[8] is not None and np.isfinite(fast[7]).sum() > 0
    _same(fast, _dataset_one_by_one(annotations, "x.json", index))
    bad = [lambda a: a[2].update(iscrowd=2), lambda a: a[2].update(iscrowd="1"), lambda a: a[0].update(bbox=[1, 2]),
           lambda a: a[0].update(bbox=[1, 2, "3", 4]), lambda a: a[3].update(keypoint_depths=None),
           lambda a: a[3]["keypoint_depths"].__setitem__(0, -1.0), lambda a: a[3]["has_3d"].__setitem__(0, 2),
           lambda a: a[3].update(has_3d=None), lambda a: a[3]["keypoint_flags"].__setitem__(0, "seen"),
           lambda a: a[3]["keypoint_flags"].pop(), lambda a: a[1].update(id=1), lambda a: a[1].update(image_id=3)]
    for spoil in bad:
        spoiled = json.loads(json.dumps(annotations))
        spoil(spoiled)
        assert _dataset_at_once(spoiled, index) is None, spoil
        with pytest.raises(InputError):
            _dataset_one_by_one(spoiled, "x.json", index)


def test_the_collector_pauses_while_a_pose_file_is_read_and_resumes_after(tmp_path, monkeypatch):
    """The reader parses with the garbage collector paused (no full collection over the
    document's containers) and leaves it as it found it, after a good file and a refused one."""
    import gc

    good, bad = tmp_path / "good.json", tmp_path / "bad.json"
    for path, doc in ((good, _dataset()), (bad, _dataset(annotations__0__keypoints=[1.0]))):
        doc["annotations"] = doc["annotations"][:2]                        # the two with keypoints
        path.write_text(json.dumps(doc))
    seen = []
    real = np.array

    def spy(*args, **kwargs):
        seen.append(gc.isenabled())
        return real(*args, **kwargs)

    monkeypatch.setattr("mvm.io.coco.np.array", spy)
    assert gc.isenabled()
    assert len(read_coco_keypoints(good).keypoints) == 2
    assert seen and not any(seen)                       # every array made with the collector paused
    assert gc.isenabled()
    with pytest.raises(InputError):
        read_coco_keypoints(bad)
    assert gc.isenabled()
    gc.disable()
    try:
        read_coco_keypoints(good)
        assert not gc.isenabled()                       # a caller's pause stays
    finally:
        gc.enable()
